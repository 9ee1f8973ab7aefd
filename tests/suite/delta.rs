//! The Delta Lake table over the committed shards (`<dataset>/_delta_log/`), read by independent readers
//! (tests/python/delta_peer.py: the `deltalake` package, Polars, DuckDB through deltalake) in a folder, on a
//! local S3 server (moto) and on a local Azurite, against the rows `pointreggpt query` returns: the same
//! row count from every reader (a file listed twice would add rows; a planted one is caught) and the same
//! values, point lists value by value. Publishing twice adds nothing; `verify --repair` withdraws a
//! corrupted shard from the table while the version before still reads; the log rebuilds from the
//! manifest; publishers that provably raced (a commit lost to another) add each shard exactly once; bad
//! logs are refused naming the file. Tests fail (never skip) when a reader, moto or Azurite is missing.

use crate::support;

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::delta::{publish, LOG_DIR};
use pointreggpt::shards::PairRow;
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use crate::support::azure::Azurite;
use crate::support::store::{Moto, ENV};
use crate::support::synthetic_config;

/// The columns compared between readers: scalars of every kind, and both per-point list columns whole.
const SQL_ROWS: &str = "select pair_key, unit_index, seed, status, overlap_source, overlap_target, target_view, \
                        target_known_share, source_points, target_points from pairs";

/// Where a dataset lives, as the environment of the processes that write and read it.
type Env = Vec<(&'static str, String)>;

/// A folder: no store variables (and never the metadata service).
fn folder() -> Env {
    vec![("AWS_EC2_METADATA_DISABLED", "true".into())]
}

/// The moto server at `endpoint`.
fn s3(endpoint: &str) -> Env {
    let mut vars = Moto::vars(endpoint);
    vars.extend(folder());
    vars
}

/// The Azurite at `endpoint` (object_store's emulator mode).
fn azure(endpoint: &str) -> Env {
    let mut vars = Azurite::vars(endpoint);
    vars.extend(folder());
    vars
}

/// `c` with no `AZURE_*` variable it inherited (support::command already drops the `AWS_*` ones) and `env`.
fn pointed<'a>(c: &'a mut Command, env: &Env) -> &'a mut Command {
    for (k, _) in std::env::vars_os() {
        if k.to_string_lossy().starts_with("AZURE_") {
            c.env_remove(&k);
        }
    }
    c.envs(env.iter().cloned())
}

fn ok(c: &mut Command) -> String {
    let o = c.stdout(Stdio::piped()).stderr(Stdio::piped()).output().unwrap();
    assert!(o.status.success(), "{c:?}\n{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `pointreggpt <args>` pointed at `env`'s store.
fn cli(env: &Env, args: &[&str]) -> Command {
    let mut c = support::bin();
    c.args(["--threads", "2"]).args(args);
    pointed(&mut c, env);
    c
}

/// A build of `config` into `out` (no progress bars).
fn build(env: &Env, config: &Path, out: &str, extra: &[&str]) -> String {
    ok(cli(env, &["build", config.to_str().unwrap(), "--out", out, "--no-progress"]).args(extra))
}

/// A command of a peer script in tests/python; its JSON answer.
fn script(env: &Env, name: &str, args: &[&str]) -> Value {
    let path = format!("{}/tests/python/{name}", env!("CARGO_MANIFEST_DIR"));
    let o = pointed(support::python_command().arg(path).args(args), env).output().unwrap();
    assert!(
        o.status.success(),
        "{name} {args:?}: {} (scripts/install-test-deps.sh installs deltalake, polars and azure-storage-blob)",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = String::from_utf8_lossy(&o.stdout);
    serde_json::from_str(&text).unwrap_or(Value::String(text.trim().to_string()))
}

/// A reader of tests/python/delta_peer.py; its JSON answer.
fn peer(env: &Env, args: &[&str]) -> Value {
    script(env, "delta_peer.py", args)
}

/// Values as float32 (the readers print float32 in float32 or float64 digits), through nested lists.
fn as_f32(v: &mut Value) {
    match v {
        Value::Array(items) => items.iter_mut().for_each(as_f32),
        Value::Number(n) => *v = serde_json::json!(n.as_f64().unwrap() as f32),
        _ => {}
    }
}

/// `who`'s rows by pair key, float32 columns as float32; panics when a pair is read twice.
fn keyed(who: &str, rows: Vec<Value>) -> BTreeMap<String, Value> {
    let mut out = BTreeMap::new();
    for mut row in rows {
        for column in ["target_known_share", "source_points", "target_points"] {
            as_f32(row.get_mut(column).unwrap_or_else(|| panic!("{who}: no {column}")));
        }
        let key = row["pair_key"].as_str().unwrap().to_string();
        assert!(out.insert(key.clone(), row).is_none(), "{who}: pair {key} read twice");
    }
    out
}

/// The rows `pointreggpt query` returns, by pair key.
fn query_rows(env: &Env, dataset: &str) -> BTreeMap<String, Value> {
    let text = ok(&mut cli(env, &["query", dataset, SQL_ROWS, "--format", "json"]));
    keyed("query", text.lines().map(|l| serde_json::from_str::<Value>(l).unwrap()).collect())
}

/// The rows a peer command returns (as many as it read), by pair key.
fn peer_rows(env: &Env, args: &[&str]) -> BTreeMap<String, Value> {
    let rows: Vec<Value> = serde_json::from_value(peer(env, args)).unwrap();
    let n = rows.len();
    let keyed = keyed(args[0], rows);
    assert_eq!(keyed.len(), n);
    keyed
}

/// Every reader returns exactly the rows `pointreggpt query` returns: the same number (`count(*)` of
/// query, rows of deltalake and of Polars) and the same values, point lists value by value. Returns the
/// number.
fn readers_agree(env: &Env, dataset: &str) -> usize {
    let count = ok(&mut cli(env, &["query", dataset, "select count(*) n from pairs", "--format", "json"]));
    let n = serde_json::from_str::<Value>(count.trim()).unwrap()["n"].as_u64().unwrap() as usize;
    let reference = query_rows(env, dataset);
    assert_eq!(reference.len(), n, "query's rows against its count(*)");
    for reader in ["rows", "polars"] {
        let rows: Vec<Value> = serde_json::from_value(peer(env, &[reader, dataset])).unwrap();
        assert_eq!(rows.len(), n, "{reader}: row count against query's");
        same_rows(reader, &keyed(reader, rows), &reference);
    }
    n
}

/// `got` holds the pairs, columns and values of `want` (named at the first difference: the point lists
/// are too long to print whole).
fn same_rows(who: &str, got: &BTreeMap<String, Value>, want: &BTreeMap<String, Value>) {
    assert_eq!(got.keys().collect::<Vec<_>>(), want.keys().collect::<Vec<_>>(), "{who}: other pairs than query's");
    for (key, row) in want {
        let (g, w) = (got[key].as_object().unwrap(), row.as_object().unwrap());
        assert_eq!(g.keys().collect::<Vec<_>>(), w.keys().collect::<Vec<_>>(), "{who}: pair {key}, other columns");
        for (column, v) in w {
            assert!(g[column] == *v, "{who}: pair {key}, column {column} differs from query's");
        }
    }
}

/// Runs `race` (attempt number → what it made, commits its publishers lost) until its publishers
/// provably raced, at most `attempts` times: publishers that ran one after another would pass every
/// other check.
fn until_raced<T>(what: &str, attempts: u32, mut race: impl FnMut(u32) -> (T, u32)) -> T {
    for attempt in 0..attempts {
        let (made, lost) = race(attempt);
        if lost > 0 {
            eprintln!("{what}: raced at attempt {attempt}, {lost} commits lost to other publishers");
            return made;
        }
        eprintln!("{what}: attempt {attempt} did not race; again on a fresh table");
    }
    panic!("{what}: the publishers never raced in {attempts} attempts")
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
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 16);
    let ds = dir.path().join("ds");
    let out = ds.to_str().unwrap();
    let env = folder();
    // Two workers at once, each publishing at its end.
    let workers: Vec<_> = (0..2)
        .map(|i| {
            let mut c = cli(&env, &["build", config.to_str().unwrap(), "--out", out, "--no-progress", "--worker", &i.to_string(), "--workers", "2"]);
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
    assert_eq!(readers_agree(&env, out), 8, "deltalake and Polars");

    let sql = "select status, count(*) n, round(sum(overlap_source), 9) s, max(unit_index) u from pairs group by status order by status";
    let duck = peer(&env, &["duckdb", out, sql]);
    let ours: Vec<Value> = ok(&mut cli(&env, &["query", out, sql, "--format", "json"]))
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .map(|r| serde_json::json!([r["status"], r["n"], r["s"], r["u"]]))
        .collect();
    assert_eq!(duck, Value::Array(ours), "duckdb over deltalake's dataset");

    // What a Spark-style reader takes from the log: the types, no nullable column, and per-file row counts.
    let info = peer(&env, &["info", out]);
    let expected = [
        ("unit_index", "long"), ("pair_key", "string"), ("sample_index", "integer"), ("seed", "long"), ("width", "integer"),
        ("height", "integer"), ("pose_draws", "integer"), ("status", "string"), ("overlap_source", "double"), ("overlap_target", "double"),
        ("source_intrinsics", "array<double>"), ("t_target_from_source", "array<double>"), ("source_points", "array<array<float>>"),
        ("target_points", "array<array<float>>"), ("target_known_share", "array<float>"), ("target_view", "array<byte>"),
        ("scene_frames", "integer"), ("target_scene_share", "array<float>"),
        ("source_depth_png", "binary"), ("timings", "array<struct<stage: string, ms: double>>"),
    ];
    for (column, t) in expected {
        assert_eq!(info["schema"][column], t, "{column}");
    }
    assert_eq!(info["schema"].as_object().unwrap().len(), 32);
    assert_eq!(info["nullable"], serde_json::json!([]));
    let manifest = Dataset::open(out).unwrap().committed("pairs").unwrap();
    let files: BTreeMap<String, u64> = manifest.values().map(|e| (format!("shards/{}", e.file), e.rows)).collect();
    assert_eq!(serde_json::from_value::<BTreeMap<String, u64>>(info["files"].clone()).unwrap(), files);

    // Publishing again adds nothing: same version, no new commit file.
    let again = ok(&mut cli(&env, &["publish", out]));
    assert!(again.contains("up to date at version"), "{again}");
    assert_eq!(local_log(&ds).len(), log.len());
    assert_eq!(peer(&env, &["info", out])["version"], info["version"]);
}

#[test]
fn repair_withdraws_a_corrupted_shard_from_the_table_and_the_version_before_still_reads() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 12);
    let ds = dir.path().join("ds");
    let out = ds.to_str().unwrap();
    let env = folder();
    assert!(build(&env, &config, out, &[]).contains("delta: committed version 0 (+3 shards"));
    let before = query_rows(&env, out);
    assert_eq!(readers_agree(&env, out), 6);

    // One byte of shard 1's footer changes: another blake3, still a Parquet file with the same rows.
    peer(&env, &["corrupt", out, "shards/pairs-000001.parquet"]);
    let said = ok(&mut cli(&env, &["verify", "--repair", out]));
    assert!(said.contains("withdrew 1 manifest entries") && said.contains("delta: committed version 1 (+0 shards, -1 shards)"), "{said}");
    assert_eq!(readers_agree(&env, out), 4, "the table omits the withdrawn shard");
    same_rows("deltalake at version 0", &peer_rows(&env, &["rows", out, "0"]), &before);
    let log = local_log(&ds);
    let removed: Vec<&Value> = log[&1].iter().filter_map(|a| a.get("remove")).collect();
    assert_eq!(removed.len(), 1);
    assert_eq!((removed[0]["path"].as_str(), removed[0]["tags"]["shard"].as_str()), (Some("shards/pairs-000001.parquet"), Some("1")));
    let v = ok(&mut cli(&env, &["verify", out]));
    assert!(v.contains("delta: version 1 lists exactly the committed shards"), "{v}");

    // The resumed build redoes the shard and publishes it again.
    assert!(build(&env, &config, out, &[]).contains("delta: committed version 2 (+1 shards, -0 shards)"));
    assert_eq!(readers_agree(&env, out), 6);

    // The log rebuilds from the manifest: delete it, publish, the same table at version 0.
    std::fs::remove_dir_all(ds.join(LOG_DIR)).unwrap();
    let v = ok(&mut cli(&env, &["verify", out]));
    assert!(!v.contains("delta:"), "no log, nothing said: {v}");
    assert!(ok(&mut cli(&env, &["publish", out])).contains("committed version 0 (+3 shards, -0 shards)"));
    assert_eq!(readers_agree(&env, out), 6);
    assert_eq!(replay_once_each(&local_log(&ds)), committed_paths(out));
}

#[test]
fn a_shard_file_listed_twice_is_caught_by_the_row_counts_and_publish_withdraws_it() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 12);
    let ds = dir.path().join("ds");
    let out = ds.to_str().unwrap();
    let env = folder();
    build(&env, &config, out, &[]);
    assert_eq!(readers_agree(&env, out), 6);

    // A foreign writer lists a byte copy of shard 1 under another name: its two rows are in the table twice.
    std::fs::create_dir_all(ds.join("planted")).unwrap();
    std::fs::copy(ds.join("shards/pairs-000001.parquet"), ds.join("planted/pairs-000001.parquet")).unwrap();
    let log = local_log(&ds);
    let mut add = log[&0].iter().find(|a| a["add"]["path"] == "shards/pairs-000001.parquet").unwrap().clone();
    add["add"]["path"] = "planted/pairs-000001.parquet".into();
    let commit = format!("{}\n{}\n", serde_json::json!({"commitInfo": {"timestamp": 1, "operation": "WRITE"}}), add);
    std::fs::write(ds.join(LOG_DIR).join("00000000000000000001.json"), commit).unwrap();
    assert_eq!(replay_once_each(&local_log(&ds)).len(), 4, "no path is added twice: only the rows tell");

    // Every row still carries a key query knows, with the same values: only the counts differ.
    let caught = std::panic::catch_unwind(|| readers_agree(&env, out)).expect_err("a table with 8 rows passed as query's 6");
    let message = caught.downcast_ref::<String>().cloned().unwrap_or_default();
    assert!(message.contains("row count against query's") && message.contains("left: 8") && message.contains("right: 6"), "{message}");
    let v = ok(&mut cli(&env, &["verify", out]));
    assert!(v.contains("delta: version 1 lacks 0 committed shards and lists 1 withdrawn ones"), "{v}");
    assert!(ok(&mut cli(&env, &["publish", out])).contains("committed version 2 (+0 shards, -1 shards)"));
    assert_eq!(readers_agree(&env, out), 6);
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
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let env = folder();
    let ds = until_raced("8 threads x 4 shards", 6, |attempt| {
        let ds = dir.path().join(format!("threads-{attempt}"));
        let conflicts = commit_and_publish_concurrently(ds.to_str().unwrap(), 8, 4);
        (ds, conflicts)
    });
    let log = local_log(&ds);
    assert_eq!(replay_once_each(&log), committed_paths(ds.to_str().unwrap()));
    assert!(log.len() <= 32, "{} versions for 32 shards", log.len());
    let info = peer(&env, &["info", ds.to_str().unwrap()]);
    assert_eq!(info["version"], log.len() as u64 - 1);
    assert_eq!(info["files"].as_object().unwrap().len(), 32);
    assert_eq!(readers_agree(&env, ds.to_str().unwrap()), 64);

    // Eight processes publishing a dataset without a log at once: one writes version 0, the others find it
    // current, at least one after losing the race to create it. Processes start up at different speeds
    // (libtorch is loaded first), so about one attempt in three races: up to 20 attempts.
    until_raced("8 publish processes", 20, |attempt| {
        let copy = dir.path().join(format!("procs-{attempt}"));
        let d = Dataset::create_or_open(&copy, "seed = 1\n", "h1").unwrap();
        for s in 0..5 {
            d.commit_pairs(s, s * 2, 2, &rows(s * 2, 2)).unwrap();
        }
        let procs: Vec<_> = (0..8).map(|_| cli(&env, &["publish", copy.to_str().unwrap()]).stdout(Stdio::piped()).spawn().unwrap()).collect();
        let said: Vec<String> = procs.into_iter().map(|p| String::from_utf8(p.wait_with_output().unwrap().stdout).unwrap()).collect();
        assert_eq!(said.iter().filter(|s| s.contains("committed version 0 (+5 shards")).count(), 1, "{said:?}");
        assert_eq!(said.iter().filter(|s| s.contains("up to date at version 0")).count(), 7, "{said:?}");
        assert_eq!(local_log(&copy).len(), 1);
        assert_eq!(readers_agree(&env, copy.to_str().unwrap()), 10);
        ((), said.iter().filter(|s| s.contains("commits lost to other publishers first")).count() as u32)
    });
}

#[test]
fn bad_logs_and_datasets_are_refused_naming_the_file() {
    let _timing = crate::support::timed();
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
    std::fs::write(&toml, std::fs::read_to_string(&toml).unwrap().replace(&format!("\"{}\"", pointreggpt::shards::SCHEMA_VERSION), "\"pairs/1\"")).unwrap();
    let e = err(&Dataset::open(&root).unwrap());
    assert!(e.contains("dataset.toml") && e.contains("pairs/1") && e.contains("unsigned"), "{e}");
}

#[test]
fn on_s3_the_table_reads_as_query_does_and_repair_withdraws_the_corrupted_shard() {
    let _timing = crate::support::timed();
    let _env = ENV.lock().unwrap_or_else(|e| e.into_inner());
    let moto = Moto::start();
    moto.set_env();
    moto.create_bucket("lake");
    let env = s3(&moto.endpoint());
    on_a_store(&env, "s3://lake", |url, shard| {
        peer(&env, &["corrupt", url, &format!("shards/{shard}")]);
    });
}

#[test]
fn on_azure_the_table_reads_as_query_does_and_repair_withdraws_the_corrupted_shard() {
    let _timing = crate::support::timed();
    let _env = crate::support::azure::ENV.lock().unwrap_or_else(|e| e.into_inner());
    let az = Azurite::start();
    az.set_env();
    let env = azure(&az.endpoint());
    script(&env, "az_peer.py", &["create-container", &az.endpoint(), "lake"]);
    on_a_store(&env, "az://lake", |url, shard| {
        let blob = format!("{}/shards/{shard}", url.strip_prefix("az://lake/").unwrap());
        script(&env, "az_peer.py", &["corrupt", &az.endpoint(), "lake", &blob]);
    });
}

/// The table on an object store (`root`: `s3://lake` or `az://lake`, its server in this process's
/// environment and in `env`): built and published, read by deltalake and Polars as query reads it; a
/// shard corrupted by `corrupt(url, shard file)` is withdrawn by `verify --repair` while version 0 still
/// lists it; the resume publishes it again; publishers that raced on the store add each shard once.
fn on_a_store(env: &Env, root: &str, corrupt: impl Fn(&str, &str)) {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), 1, 12);
    let url = &format!("{root}/runs/ds");
    assert!(build(env, &config, url, &[]).contains("delta: committed version 0 (+3 shards"));
    assert_eq!(readers_agree(env, url), 6);
    assert!(ok(&mut cli(env, &["publish", url])).contains("up to date at version 0"));
    let info = peer(env, &["info", url]);
    assert_eq!(info["version"], 0);
    let files: BTreeSet<String> = info["files"].as_object().unwrap().keys().cloned().collect();
    assert_eq!(files, committed_paths(url));

    // Corrupt shard 1's object; repair withdraws it (and deletes the object) and publishes the remove.
    let shard1 = Dataset::open(url).unwrap().committed("pairs").unwrap()[&1].file.clone();
    corrupt(url, &shard1);
    let said = ok(&mut cli(env, &["verify", "--repair", url]));
    assert!(said.contains("delta: committed version 1 (+0 shards, -1 shards)"), "{said}");
    assert_eq!(readers_agree(env, url), 4);
    let v0 = peer(env, &["info", url, "0"]);
    assert!(v0["files"].as_object().unwrap().contains_key(&format!("shards/{shard1}")), "version 0 still lists the withdrawn object");
    assert!(build(env, &config, url, &[]).contains("delta: committed version 2 (+1 shards, -0 shards)"));
    assert_eq!(readers_agree(env, url), 6);

    // Concurrent publishers on the store: create-only puts of the commit files.
    let threads = until_raced(&format!("4 threads x 2 shards on {root}"), 6, |attempt| {
        let threads = format!("{root}/threads-{attempt}");
        let conflicts = commit_and_publish_concurrently(&threads, 4, 2);
        (threads, conflicts)
    });
    assert_eq!(replay_once_each(&store_log(&threads)), committed_paths(&threads));
    let info = peer(env, &["info", &threads]);
    let files: BTreeSet<String> = info["files"].as_object().unwrap().keys().cloned().collect();
    assert_eq!(files, committed_paths(&threads));
    assert_eq!(readers_agree(env, &threads), 16);
    assert_eq!(info["history"].as_u64().unwrap(), info["version"].as_u64().unwrap() + 1);
}
