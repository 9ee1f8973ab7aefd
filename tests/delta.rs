//! The Delta Lake table over the committed shards (`<dataset>/_delta_log/`), read by independent readers
//! (tests/python/delta_peer.py: the `deltalake` package, Polars, DuckDB through deltalake) in a folder and
//! on a local S3 server (moto), against the rows `pointreggpt query` returns; publishing twice adds nothing;
//! `verify --repair` withdraws a corrupted shard from the table while the version before still reads;
//! the log rebuilds from the manifest; concurrent publishers add each shard exactly once; bad logs are
//! refused naming the file. Tests fail (never skip) when a reader or moto is missing.

mod support;

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::delta::{publish, LOG_DIR};
use pointreggpt::shards::PairRow;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use support::store::{Moto, ENV};
use support::{bin, python, synthetic_config};

/// The columns compared between readers (scalars of every kind, and two per-point list columns).
const SQL_ROWS: &str = "select pair_key, unit_index, seed, status, overlap_source, overlap_target, target_view, \
                        target_known_share, array_length(target_points) n_target_points from pairs";

/// Environment of a command: the moto server's variables (none for a folder), never the metadata service.
fn env_of(endpoint: Option<&str>) -> Vec<(&'static str, String)> {
    let mut vars = endpoint.map(Moto::vars).unwrap_or_default();
    vars.push(("AWS_EC2_METADATA_DISABLED", "true".into()));
    vars
}

fn ok(c: &mut Command) -> String {
    let o = c.stdout(Stdio::piped()).stderr(Stdio::piped()).output().unwrap();
    assert!(o.status.success(), "{c:?}\n{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `pointreggpt <args>` pointed at `endpoint`'s store.
fn cli(endpoint: Option<&str>, args: &[&str]) -> Command {
    let mut c = bin();
    c.args(["--threads", "2"]).args(args).envs(env_of(endpoint));
    c
}

/// A build of `config` into `out` (no progress bars).
fn build(endpoint: Option<&str>, config: &Path, out: &str, extra: &[&str]) -> String {
    ok(cli(endpoint, &["build", config.to_str().unwrap(), "--out", out, "--no-progress"]).args(extra))
}

/// A reader of tests/python/delta_peer.py; its JSON answer.
fn peer(endpoint: Option<&str>, args: &[&str]) -> Value {
    let script = format!("{}/tests/python/delta_peer.py", env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(python()).arg(script).args(args).envs(env_of(endpoint)).output().unwrap();
    assert!(
        o.status.success(),
        "delta_peer.py {args:?}: {} (scripts/install-test-deps.sh installs deltalake and polars)",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// Float32 list values as float32 (the readers print them in float32 or float64 digits).
fn normalized(mut rows: BTreeMap<String, Value>) -> BTreeMap<String, Value> {
    for row in rows.values_mut() {
        if let Some(Value::Array(share)) = row.get_mut("target_known_share") {
            for v in share.iter_mut() {
                *v = serde_json::json!(v.as_f64().unwrap() as f32);
            }
        }
    }
    rows
}

/// The rows `pointreggpt query` returns, by pair key.
fn query_rows(endpoint: Option<&str>, dataset: &str) -> BTreeMap<String, Value> {
    let text = ok(&mut cli(endpoint, &["query", dataset, SQL_ROWS, "--format", "json"]));
    let rows = text.lines().map(|l| serde_json::from_str::<Value>(l).unwrap()).map(|r| (r["pair_key"].as_str().unwrap().to_string(), r));
    normalized(rows.collect())
}

/// The rows a peer command returns, by pair key.
fn peer_rows(endpoint: Option<&str>, args: &[&str]) -> BTreeMap<String, Value> {
    normalized(serde_json::from_value(peer(endpoint, args)).unwrap())
}

/// The commits of a local log, parsed here (not by the crate): version → actions.
fn local_log(dataset: &Path) -> BTreeMap<u64, Vec<Value>> {
    std::fs::read_dir(dataset.join(LOG_DIR))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .map(|p| {
            let version = p.file_stem().unwrap().to_str().unwrap().parse().unwrap();
            let text = std::fs::read_to_string(&p).unwrap();
            (version, text.lines().map(|l| serde_json::from_str(l).unwrap()).collect())
        })
        .collect()
}

/// Replays `log` as a Delta reader does; panics when a version is missing, a file is added while active
/// (a shard published twice) or removed while inactive. Returns the active paths.
fn replay_once_each(log: &BTreeMap<u64, Vec<Value>>) -> BTreeSet<String> {
    assert_eq!(log.keys().copied().collect::<Vec<_>>(), (0..log.len() as u64).collect::<Vec<_>>(), "versions 0..n without gaps");
    let mut active = BTreeSet::new();
    for (version, actions) in log {
        for a in actions {
            if let Some(path) = a["add"]["path"].as_str() {
                assert!(active.insert(path.to_string()), "version {version} adds {path} again");
            }
            if let Some(path) = a["remove"]["path"].as_str() {
                assert!(active.remove(path), "version {version} removes {path}, which is not in the table");
            }
        }
    }
    active
}

/// The commits of a log on an object store, listed and read through the dataset's store, parsed here.
fn store_log(url: &str) -> BTreeMap<u64, Vec<Value>> {
    let store = pointreggpt::shards::store::open_store(Path::new(url)).unwrap();
    store
        .list(LOG_DIR)
        .unwrap()
        .into_iter()
        .map(|l| {
            let version = l.name.strip_suffix(".json").unwrap().parse().unwrap();
            let text = store.read_text(&format!("{LOG_DIR}/{}", l.name)).unwrap().unwrap();
            (version, text.lines().map(|l| serde_json::from_str(l).unwrap()).collect())
        })
        .collect()
}

/// The shard files the manifest of `dataset` names, as table paths.
fn committed_paths(dataset: &str) -> BTreeSet<String> {
    Dataset::open(dataset).unwrap().committed("pairs").unwrap().values().map(|e| format!("shards/{}", e.file)).collect()
}

fn write_config(dir: &Path, scenes: u32, frames: usize) -> PathBuf {
    let path = dir.join("c.toml");
    std::fs::write(&path, synthetic_config(scenes, frames, 2, 1, 160, 120, 2)).unwrap();
    path
}

#[test]
fn two_workers_publish_a_table_that_deltalake_polars_and_duckdb_read_as_query_does() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 16);
    let ds = dir.path().join("ds");
    let out = ds.to_str().unwrap();
    // Two workers at once, each publishing at its end.
    let workers: Vec<_> = (0..2)
        .map(|i| {
            let mut c = cli(None, &["build", config.to_str().unwrap(), "--out", out, "--no-progress", "--worker", &i.to_string(), "--workers", "2"]);
            c.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap()
        })
        .collect();
    for w in workers {
        let o = w.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stdout).contains("delta: "), "{}", String::from_utf8_lossy(&o.stdout));
    }
    let log = local_log(&ds);
    assert!((1..=2).contains(&log.len()), "one version per worker at most: {log:?}");
    assert_eq!(replay_once_each(&log), committed_paths(out), "every committed shard, each added once");

    let reference = query_rows(None, out);
    assert_eq!(reference.len(), 8);
    assert_eq!(peer_rows(None, &["rows", out]), reference, "deltalake");
    assert_eq!(peer_rows(None, &["polars", out]), reference, "polars");
    let sql = "select status, count(*) n, round(sum(overlap_source), 9) s, max(unit_index) u from pairs group by status order by status";
    let duck = peer(None, &["duckdb", out, sql]);
    let ours: Vec<Value> = ok(&mut cli(None, &["query", out, sql, "--format", "json"]))
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .map(|r| serde_json::json!([r["status"], r["n"], r["s"], r["u"]]))
        .collect();
    assert_eq!(duck, Value::Array(ours), "duckdb over deltalake's dataset");

    // What a Spark-style reader takes from the log: the types, no nullable column, and per-file row counts.
    let info = peer(None, &["info", out]);
    let expected = [
        ("unit_index", "long"), ("pair_key", "string"), ("sample_index", "integer"), ("seed", "long"), ("width", "integer"),
        ("height", "integer"), ("pose_draws", "integer"), ("status", "string"), ("overlap_source", "double"), ("overlap_target", "double"),
        ("source_intrinsics", "array<double>"), ("t_target_from_source", "array<double>"), ("source_points", "array<array<float>>"),
        ("target_points", "array<array<float>>"), ("target_known_share", "array<float>"), ("target_view", "array<byte>"),
        ("source_depth_png", "binary"), ("timings", "array<struct<stage: string, ms: double>>"),
    ];
    for (column, t) in expected {
        assert_eq!(info["schema"][column], t, "{column}");
    }
    assert_eq!(info["schema"].as_object().unwrap().len(), 30);
    assert_eq!(info["nullable"], serde_json::json!([]));
    let manifest = Dataset::open(out).unwrap().committed("pairs").unwrap();
    let files: BTreeMap<String, u64> = manifest.values().map(|e| (format!("shards/{}", e.file), e.rows)).collect();
    assert_eq!(serde_json::from_value::<BTreeMap<String, u64>>(info["files"].clone()).unwrap(), files);

    // Publishing again adds nothing: same version, no new commit file.
    let again = ok(&mut cli(None, &["publish", out]));
    assert!(again.contains("up to date at version"), "{again}");
    assert_eq!(local_log(&ds).len(), log.len());
    assert_eq!(peer(None, &["info", out])["version"], info["version"]);
}

#[test]
fn repair_withdraws_a_corrupted_shard_from_the_table_and_the_version_before_still_reads() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 12);
    let ds = dir.path().join("ds");
    let out = ds.to_str().unwrap();
    assert!(build(None, &config, out, &[]).contains("delta: committed version 0 (+3 shards"));
    let before = query_rows(None, out);
    assert_eq!(before.len(), 6);

    // One byte of shard 1's footer changes: another blake3, still a Parquet file with the same rows.
    peer(None, &["corrupt", out, "shards/pairs-000001.parquet"]);
    let said = ok(&mut cli(None, &["verify", "--repair", out]));
    assert!(said.contains("withdrew 1 manifest entries") && said.contains("delta: committed version 1 (+0 shards, -1 shards)"), "{said}");
    let after = query_rows(None, out);
    assert_eq!(after.len(), 4);
    assert_eq!(peer_rows(None, &["rows", out]), after, "the table omits the withdrawn shard");
    assert_eq!(peer_rows(None, &["polars", out]), after);
    assert_eq!(peer_rows(None, &["rows", out, "0"]), before, "time travel: version 0 still reads every row");
    let log = local_log(&ds);
    let removed: Vec<&Value> = log[&1].iter().filter_map(|a| a.get("remove")).collect();
    assert_eq!(removed.len(), 1);
    assert_eq!((removed[0]["path"].as_str(), removed[0]["tags"]["shard"].as_str()), (Some("shards/pairs-000001.parquet"), Some("1")));
    let v = ok(&mut cli(None, &["verify", out]));
    assert!(v.contains("delta: version 1 lists exactly the committed shards"), "{v}");

    // The resumed build redoes the shard and publishes it again.
    assert!(build(None, &config, out, &[]).contains("delta: committed version 2 (+1 shards, -0 shards)"));
    assert_eq!(peer_rows(None, &["rows", out]), query_rows(None, out));
    assert_eq!(query_rows(None, out).len(), 6);

    // The log rebuilds from the manifest: delete it, publish, the same table at version 0.
    std::fs::remove_dir_all(ds.join(LOG_DIR)).unwrap();
    let v = ok(&mut cli(None, &["verify", out]));
    assert!(!v.contains("delta:"), "no log, nothing said: {v}");
    assert!(ok(&mut cli(None, &["publish", out])).contains("committed version 0 (+3 shards, -0 shards)"));
    assert_eq!(peer_rows(None, &["rows", out]), query_rows(None, out));
    assert_eq!(replay_once_each(&local_log(&ds)), committed_paths(out));
}

/// `n` rows of units `first..first + n` for a hand-made dataset (config hash `h1`).
fn rows(first: u64, n: u64) -> Vec<PairRow> {
    (first..first + n)
        .map(|u| PairRow { unit_index: u, pair_key: format!("k#{u}"), seed: u * 7, config_hash: "h1".into(), ..Default::default() })
        .collect()
}

/// `threads` workers commit `per` shards each (shards k with k mod threads = i) into `url`, publishing after
/// every commit; returns the publishers' conflict counts.
fn commit_and_publish_concurrently(url: &str, threads: u64, per: u64) -> u32 {
    let ds = Dataset::create_or_open(url, "seed = 1\n", "h1").unwrap();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|i| {
                let ds = ds.clone();
                s.spawn(move || {
                    let mut conflicts = 0;
                    for j in 0..per {
                        let shard = j * threads + i;
                        ds.commit_pairs(shard, shard * 2, 2, &rows(shard * 2, 2)).unwrap();
                        conflicts += publish(&ds).unwrap().conflicts;
                    }
                    conflicts
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).sum()
    })
}

#[test]
fn concurrent_publishers_add_each_shard_once() {
    let dir = tempfile::tempdir().unwrap();
    let ds = dir.path().join("threads");
    let conflicts = commit_and_publish_concurrently(ds.to_str().unwrap(), 8, 4);
    let log = local_log(&ds);
    assert_eq!(replay_once_each(&log), committed_paths(ds.to_str().unwrap()));
    assert!(log.len() <= 32, "{} versions for 32 shards", log.len());
    eprintln!("8 threads x 4 shards: {} versions, {conflicts} lost races", log.len());
    let info = peer(None, &["info", ds.to_str().unwrap()]);
    assert_eq!(info["version"], log.len() as u64 - 1);
    assert_eq!(info["files"].as_object().unwrap().len(), 32);
    assert_eq!(peer(None, &["rows", ds.to_str().unwrap()]).as_object().unwrap().len(), 64);

    // Four processes publishing a dataset without a log at once: one writes version 0, the others find it current.
    let copy = dir.path().join("procs");
    let d = Dataset::create_or_open(&copy, "seed = 1\n", "h1").unwrap();
    for s in 0..5 {
        d.commit_pairs(s, s * 2, 2, &rows(s * 2, 2)).unwrap();
    }
    let procs: Vec<_> = (0..4).map(|_| cli(None, &["publish", copy.to_str().unwrap()]).stdout(Stdio::piped()).spawn().unwrap()).collect();
    let said: Vec<String> = procs.into_iter().map(|p| String::from_utf8(p.wait_with_output().unwrap().stdout).unwrap()).collect();
    assert_eq!(said.iter().filter(|s| s.contains("committed version 0 (+5 shards")).count(), 1, "{said:?}");
    assert_eq!(said.iter().filter(|s| s.contains("up to date at version 0")).count(), 3, "{said:?}");
    assert_eq!(local_log(&copy).len(), 1);
}

#[test]
fn bad_logs_and_datasets_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("ds");
    let ds = Dataset::create_or_open(&root, "seed = 1\n", "h1").unwrap();
    ds.commit_pairs(0, 0, 2, &rows(0, 2)).unwrap();
    publish(&ds).unwrap();
    let log = root.join(LOG_DIR);
    let err = |ds: &Dataset| publish(ds).unwrap_err().to_string();

    // A torn line, a gap in the versions, another dataset's log.
    let v1 = log.join("00000000000000000001.json");
    std::fs::write(&v1, "{\"add\": {\"path\": \n").unwrap();
    let e = err(&ds);
    assert!(e.contains("00000000000000000001.json") && e.contains("line 1"), "{e}");
    std::fs::remove_file(&v1).unwrap();
    std::fs::write(log.join("00000000000000000002.json"), "{\"commitInfo\": {\"timestamp\": 1}}\n").unwrap();
    let e = err(&ds);
    assert!(e.contains("00000000000000000002.json") && e.contains("gap"), "{e}");
    std::fs::remove_file(log.join("00000000000000000002.json")).unwrap();
    let other = Dataset::create_or_open(dir.path().join("other"), "seed = 2\n", "h2").unwrap();
    std::fs::create_dir_all(dir.path().join("other").join(LOG_DIR)).unwrap();
    std::fs::copy(log.join("00000000000000000000.json"), dir.path().join("other").join(LOG_DIR).join("00000000000000000000.json")).unwrap();
    let e = err(&other);
    assert!(e.contains("other") && e.contains(LOG_DIR) && e.contains("another table id") && e.contains("delete the _delta_log"), "{e}");
    assert_eq!(publish(&ds).unwrap().committed, false, "the intact log is current");

    // A version-1 dataset (unsigned integers) is not published, naming its dataset.toml and a column.
    let toml = root.join("dataset.toml");
    std::fs::write(&toml, std::fs::read_to_string(&toml).unwrap().replace("\"pairs/2\"", "\"pairs/1\"")).unwrap();
    let e = err(&Dataset::open(&root).unwrap());
    assert!(e.contains("dataset.toml") && e.contains("pairs/1") && e.contains("unsigned"), "{e}");
}

#[test]
fn on_s3_the_table_reads_as_query_does_and_repair_withdraws_the_corrupted_shard() {
    let _env = ENV.lock().unwrap_or_else(|e| e.into_inner());
    let moto = Moto::start();
    moto.set_env();
    moto.create_bucket("lake");
    let endpoint = moto.endpoint();
    let e = Some(endpoint.as_str());
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 12);
    let url = "s3://lake/runs/ds";
    assert!(build(e, &config, url, &[]).contains("delta: committed version 0 (+3 shards"));
    let before = query_rows(e, url);
    assert_eq!(before.len(), 6);
    assert_eq!(peer_rows(e, &["rows", url]), before, "deltalake on S3");
    assert_eq!(peer_rows(e, &["polars", url]), before, "polars on S3");
    assert!(ok(&mut cli(e, &["publish", url])).contains("up to date at version 0"));
    let info = peer(e, &["info", url]);
    assert_eq!(info["version"], 0);
    let files: BTreeSet<String> = info["files"].as_object().unwrap().keys().cloned().collect();
    assert_eq!(files, committed_paths(url));

    // Corrupt shard 1's object; repair withdraws it (and deletes the object) and publishes the remove.
    let shard1 = Dataset::open(url).unwrap().committed("pairs").unwrap()[&1].file.clone();
    peer(e, &["corrupt", url, &format!("shards/{shard1}")]);
    let said = ok(&mut cli(e, &["verify", "--repair", url]));
    assert!(said.contains("delta: committed version 1 (+0 shards, -1 shards)"), "{said}");
    let after = query_rows(e, url);
    assert_eq!(after.len(), 4);
    assert_eq!(peer_rows(e, &["rows", url]), after);
    let v0 = peer(e, &["info", url, "0"]);
    assert!(v0["files"].as_object().unwrap().contains_key(&format!("shards/{shard1}")), "version 0 still lists the withdrawn object");
    assert!(build(e, &config, url, &[]).contains("delta: committed version 2 (+1 shards, -0 shards)"));
    assert_eq!(peer_rows(e, &["rows", url]), query_rows(e, url));

    // Concurrent publishers on the store: create-only puts of the commit files.
    commit_and_publish_concurrently("s3://lake/threads", 4, 2);
    assert_eq!(replay_once_each(&store_log("s3://lake/threads")), committed_paths("s3://lake/threads"));
    let info = peer(e, &["info", "s3://lake/threads"]);
    let files: BTreeSet<String> = info["files"].as_object().unwrap().keys().cloned().collect();
    assert_eq!(files, committed_paths("s3://lake/threads"));
    assert_eq!(peer(e, &["rows", "s3://lake/threads"]).as_object().unwrap().len(), 16);
    assert_eq!(info["history"].as_u64().unwrap(), info["version"].as_u64().unwrap() + 1);
}
