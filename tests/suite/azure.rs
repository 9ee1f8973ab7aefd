//! Datasets on Azure Blob storage (`az://`), against a real Azurite started by each test (npm's
//! `azurite`, in memory, on 127.0.0.1): a build to `az://` equals the same build to a folder (content hash
//! for content hash) and queries and pyarrow agree; SIGKILLs mid-build then a resume; two writers racing
//! on the same shards; `verify --repair` of a corrupted shard, an orphan object and a dead writer's block
//! upload, next to a live writer whose blocks, blobs and records it leaves alone; large shards in blocks;
//! bad containers and an unreachable server, refused before any frame is read or blob written. Clients run in object_store's
//! emulator mode (the development account, `AZURITE_BLOB_STORAGE_URL`), never against a cloud endpoint.
//! Tests fail (never skip) when Azurite cannot start.

use crate::support;

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::store::open_store;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::MutexGuard;
use std::time::{Duration, Instant};
use crate::support::azure::Azurite;
use crate::support::azure::ENV;
use crate::support::{bin, digests, python, synthetic_config};

/// One test's Azure world: an Azurite with one container, a temporary folder, and the lock of the
/// process environment (the tests point object_store's emulator variables at their own server).
struct World {
    az: Azurite,
    dir: tempfile::TempDir,
    _env: MutexGuard<'static, ()>,
}

impl World {
    fn new(container: &str) -> World {
        let _env = ENV.lock().unwrap_or_else(|e| e.into_inner());
        let az = Azurite::start();
        eprintln!("Azurite listening on {} after {:.2} s", az.endpoint(), az.startup.as_secs_f64());
        az.set_env();
        peer(&az.endpoint(), &["create-container", &az.endpoint(), container]);
        World { az, dir: tempfile::tempdir().unwrap(), _env }
    }

    fn endpoint(&self) -> String {
        self.az.endpoint()
    }

    /// Writes `config` and builds it into a local folder: the config's path, the folder and its content
    /// digests, the reference a build on Azure must equal.
    fn reference_build(&self, config: String) -> (PathBuf, PathBuf, BTreeMap<u64, String>) {
        let path = self.dir.path().join("c.toml");
        std::fs::write(&path, config).unwrap();
        let local = self.dir.path().join("ref");
        ok(build(&self.endpoint(), &path, local.to_str().unwrap()).output().unwrap());
        let reference = digests(local.to_str().unwrap());
        (path, local, reference)
    }
}

/// Content digests of the committed pairs of `dataset` (folder or URL; for a URL, the process
/// environment must point at its server).

/// `pointreggpt --threads 2 <args>` pointed at the Azurite behind `endpoint` only.
fn run(endpoint: &str, args: &[&str]) -> Command {
    let mut c = bin();
    c.args(["--threads", "2"]).args(args).stdout(Stdio::piped()).stderr(Stdio::piped());
    Azurite::apply(&mut c, endpoint);
    c
}

fn build(endpoint: &str, config: &Path, out: &str) -> Command {
    run(endpoint, &["build", config.to_str().unwrap(), "--out", out, "--no-progress"])
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A Python peer from tests/python/az_peer.py (azure-storage-blob, pyarrow).
fn peer(endpoint: &str, args: &[&str]) -> String {
    let script = format!("{}/tests/python/az_peer.py", env!("CARGO_MANIFEST_DIR"));
    let mut c = Command::new(python());
    c.arg(script).args(args);
    let o = Azurite::apply(&mut c, endpoint).output().unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    assert!(
        o.status.success(),
        "az_peer.py {args:?}: {}\n(scripts/install-test-deps.sh installs azure-storage-blob)",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).trim().to_string()
}

/// The committed blobs under `prefix` with their size and ETag, listed by azure-storage-blob.
fn objects(endpoint: &str, container: &str, prefix: &str) -> BTreeMap<String, (u64, String)> {
    serde_json::from_str(&peer(endpoint, &["objects", endpoint, container, prefix])).unwrap()
}

/// Blob names that hold only uncommitted blocks (an unfinished block upload) in `container`.
fn uncommitted(endpoint: &str, container: &str) -> Vec<String> {
    serde_json::from_str(&peer(endpoint, &["uncommitted", endpoint, container])).unwrap()
}

/// Committed pairs of `url` (0 before the dataset exists).
fn committed(url: &str) -> usize {
    Dataset::open(url).and_then(|d| d.committed("pairs")).map(|c| c.len()).unwrap_or(0)
}

/// After `verify --repair`: every blob under shards/ is named by a manifest entry, no upload record and
/// no uncommitted block upload is left, and verify is clean.
fn assert_clean(endpoint: &str, container: &str, prefix: &str) {
    let url = format!("az://{container}/{prefix}");
    ok(run(endpoint, &["verify", "--repair", &url]).output().unwrap());
    let ds = Dataset::open(&url).unwrap();
    let report = ds.verify().unwrap();
    assert!(
        report.is_ok() && report.orphans.is_empty() && report.stale_temps.is_empty() && report.other_temps.is_empty(),
        "{report}"
    );
    let listed = objects(endpoint, container, prefix);
    let files: Vec<&String> = listed.keys().filter(|k| k.starts_with("shards/")).collect();
    let named: Vec<String> = ds.committed("pairs").unwrap().values().map(|e| format!("shards/{}", e.file)).collect();
    assert_eq!(files, named.iter().collect::<Vec<_>>(), "one blob per committed shard, nothing else");
    assert!(!listed.keys().any(|k| k.starts_with(".tmp/")), "upload records left: {listed:?}");
    assert_eq!(uncommitted(endpoint, container), Vec::<String>::new(), "no unfinished block upload");
}

#[test]
fn a_build_on_azure_equals_the_build_in_a_folder_and_queries_and_pyarrow_agree() {
    let _timing = crate::support::timed();
    let w = World::new("data");
    let ep = w.endpoint();
    let (config, local, reference) = w.reference_build(synthetic_config(2, 12, 2, 1, 320, 240, 2));
    assert_eq!(reference.len(), 12);
    let url = "az://data/runs/demo";
    let t = Instant::now();
    let summary = ok(build(&ep, &config, url).output().unwrap());
    eprintln!("build into {url}: {:.1} s", t.elapsed().as_secs_f64());
    assert!(
        summary.contains("6 committed now") && summary.contains("pointreggpt query az://data/runs/demo"),
        "{summary}"
    );
    assert_eq!(digests(url), reference, "same rows, content hash for content hash");
    // Run again: a resume with nothing left to do.
    let again = ok(build(&ep, &config, url).output().unwrap());
    assert!(again.contains("6 shards already committed, 0 committed now"), "{again}");
    // Another config on the same prefix is refused, naming the URL and the key.
    let o = build(&ep, &config, url).args(["--set", "seed=12"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("az://data/runs/demo") && err.contains("seed: 11 → 12"), "{err}");
    // Shard blobs have unique names.
    let keys = objects(&ep, "data", "runs/demo");
    assert!(
        keys.keys().any(|k| k.starts_with("shards/pairs-000000-")) && keys.contains_key("dataset.toml"),
        "{keys:?}"
    );

    for sql in [
        "select status, count(*) n, round(sum(overlap_source), 9) s, max(overlap_target) m from pairs group by status order by status",
        "select pair_key, array_length(source_points) n from pairs where status = 'ok' order by pair_key",
        "select shard, rows, units from manifest order by shard",
    ] {
        let a = ok(run(&ep, &["query", local.to_str().unwrap(), sql, "--format", "csv"]).output().unwrap());
        let b = ok(run(&ep, &["query", url, sql, "--format", "csv"]).output().unwrap());
        assert_eq!(a, b, "{sql}");
        assert!(a.lines().count() > 1, "{sql}: {a}");
    }
    // pyarrow reads the blobs that the manifest names (downloaded with azure-storage-blob); the S3
    // peer's reader of a folder gives the same rows.
    let from_az: serde_json::Value = serde_json::from_str(&peer(&ep, &["rows-az", &ep, "data", "runs/demo"])).unwrap();
    let script = format!("{}/tests/python/s3_peer.py", env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(python()).arg(script).args(["rows-local", local.to_str().unwrap()]).output().unwrap();
    let from_folder: serde_json::Value = serde_json::from_str(&ok(o)).unwrap();
    assert_eq!(from_az, from_folder);
    assert_eq!(from_az.as_object().unwrap().len(), 12);
    // export reads the store too.
    let out = w.dir.path().join("ply");
    let said = ok(run(
        &ep,
        &["export", url, "--format", "ply", "--out", out.to_str().unwrap(), "--limit", "2", "--no-progress"],
    )
    .output()
    .unwrap());
    assert!(said.contains("wrote 2 pairs"), "{said}");
    assert_clean(&ep, "data", "runs/demo");
}

/// A counter of the manifest objects under `url` (0 before the dataset exists), on one store client.
fn manifest_counter(url: &str) -> impl Fn() -> usize {
    let store = open_store(Path::new(url)).unwrap();
    move || store.list("manifest").map(|l| l.len()).unwrap_or(0)
}

#[test]
fn sigkills_during_an_azure_build_then_resume_give_the_same_dataset_and_repair_leaves_nothing() {
    let _timing = crate::support::timed();
    use std::os::unix::process::ExitStatusExt;
    const KILLS: usize = 3;
    let w = World::new("kills");
    let ep = w.endpoint();
    let (config, _, reference) = w.reference_build(synthetic_config(2, 40, 2, 1, 320, 240, 2));
    let total = 20;
    let mut rng = pointreggpt::rng::Rng::new(28);
    let mut tries = Vec::new();
    // Each setup (a fresh prefix) needs KILLS SIGKILLs in a row that land mid-build: the killed run
    // committed shards of its own, and not all of them. A kill that came too late (the build had
    // finished) does not count: the setup is retried.
    for attempt in 0..4 {
        let prefix = format!("ds{attempt}");
        let url = format!("az://kills/{prefix}");
        let manifest_objects = manifest_counter(&url);
        let mut log = Vec::new();
        for _ in 0..KILLS {
            let before = committed(&url);
            let mut child = build(&ep, &config, &url).spawn().unwrap();
            // Wait until this run committed a shard of its own, then kill within 0..150 ms.
            let t0 = Instant::now();
            while manifest_objects() <= before && child.try_wait().unwrap().is_none() {
                assert!(t0.elapsed() < Duration::from_secs(120), "no shard committed in 2 minutes");
                std::thread::sleep(Duration::from_millis(5));
            }
            std::thread::sleep(Duration::from_millis(rng.below(150)));
            let _ = child.kill();
            let status = child.wait().unwrap();
            let after = committed(&url);
            log.push((before, after, status.signal()));
            for (k, d) in digests(&url) {
                assert_eq!(Some(&d), reference.get(&k), "unit {k} differs after a kill");
            }
            if !(status.signal() == Some(9) && after > before && after < total) {
                break;
            }
        }
        let landed = log.iter().filter(|(b, a, s)| *s == Some(9) && a > b && *a < total).count();
        tries.push(log.clone());
        if landed < KILLS {
            continue;
        }
        let left = log.last().unwrap().1;
        let summary = ok(build(&ep, &config, &url).output().unwrap());
        assert!(
            summary.contains(&format!("{left} shards already committed, {} committed now", total - left)),
            "{summary}"
        );
        assert_eq!(digests(&url), reference, "the resumed dataset equals the uninterrupted one");
        assert_clean(&ep, "kills", &prefix);
        eprintln!("{KILLS} kills landed mid-build (committed before, after, signal): {tries:?}");
        return;
    }
    panic!("no setup had {KILLS} kills land mid-build: {tries:?}");
}

#[test]
fn two_writers_racing_on_the_same_azure_shards_leave_one_blob_per_shard() {
    let _timing = crate::support::timed();
    let w = World::new("race");
    let ep = w.endpoint();
    let (config, local, reference) = w.reference_build(synthetic_config(1, 16, 2, 1, 320, 240, 2));
    // Both processes own every shard (one worker each), so each shard is written twice; a setup in
    // which no writer lost a create-only put did not race and is retried on a fresh prefix.
    let mut losses = Vec::new();
    for attempt in 0..3 {
        let prefix = format!("ds{attempt}");
        let url = format!("az://race/{prefix}");
        let a = build(&ep, &config, &url).spawn().unwrap();
        let b = build(&ep, &config, &url).spawn().unwrap();
        let (oa, ob) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
        let lost = [&oa, &ob]
            .iter()
            .map(|o| String::from_utf8_lossy(&o.stderr).matches("committed it first").count())
            .sum::<usize>();
        ok(oa);
        ok(ob);
        assert_eq!(digests(&url), reference);
        assert_clean(&ep, "race", &prefix);
        losses.push(lost);
        if lost > 0 {
            break;
        }
    }
    assert!(losses.last().is_some_and(|l| *l > 0), "no writer lost a race in {} setups", losses.len());
    eprintln!("create-only puts lost per setup: {losses:?}");

    // Two workers splitting the shards (k mod 2) into one prefix, at the same time.
    let workers: Vec<_> = (0..2)
        .map(|i| {
            build(&ep, &config, "az://race/split").args(["--worker", &i.to_string(), "--workers", "2"]).spawn().unwrap()
        })
        .collect();
    for worker in workers {
        assert!(ok(worker.wait_with_output().unwrap()).contains("2 committed now"));
    }
    assert_eq!(digests("az://race/split"), reference);

    // Eight threads committing one shard at once: one blob, one entry, the same for everyone.
    let ds = Dataset::create_or_open("az://race/threads", "seed = 1\n", "h1").unwrap();
    let rows = Dataset::open(local.to_str().unwrap()).unwrap().read_pairs().unwrap()[..2].to_vec();
    let entries: Vec<_> = std::thread::scope(|s| {
        let h: Vec<_> = (0..8).map(|_| s.spawn(|| ds.commit_pairs(0, 0, 2, &rows).unwrap())).collect();
        h.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(entries.iter().all(|e| *e == entries[0]), "every writer returns the winning entry");
    let shards: Vec<String> =
        objects(&ep, "race", "threads").into_keys().filter(|k| k.starts_with("shards/")).collect();
    assert_eq!(shards, [format!("shards/{}", entries[0].file)]);
    assert_eq!(ds.read_pairs().unwrap(), rows);

    // An entry whose blob is gone: verify reports it, and the next commit replaces the entry with a
    // conditional put on Azurite's ETag (If-Match) instead of adopting it.
    peer(&ep, &["delete", &ep, "race", &format!("threads/shards/{}", entries[0].file)]);
    assert!(!ds.verify().unwrap().is_ok());
    let again = ds.commit_pairs(0, 0, 2, &rows).unwrap();
    assert_ne!(again.file, entries[0].file);
    assert_eq!(ds.read_pairs().unwrap(), rows);
    assert!(ds.verify().unwrap().is_ok());
}

#[test]
fn verify_repair_on_azure_withdraws_a_corrupted_shard_and_removes_orphans_and_dead_uploads() {
    let _timing = crate::support::timed();
    let w = World::new("repair");
    let ep = w.endpoint();
    let (config, _, reference) = w.reference_build(synthetic_config(2, 12, 2, 1, 320, 240, 2));
    let url = "az://repair/ds";
    ok(build(&ep, &config, url).output().unwrap());
    let entries = Dataset::open(url).unwrap().committed("pairs").unwrap();
    let bad = entries.values().nth(2).unwrap().file.clone();
    // One byte of a committed shard flipped (same size: only the hash tells), a blob that no entry and
    // no record names (a writer that lost a race and could not delete it), and a writer that died mid
    // block upload (a pid above Linux's pid_max, so never running) with its record.
    peer(&ep, &["corrupt", &ep, "repair", &format!("ds/shards/{bad}")]);
    peer(&ep, &["put", &ep, "repair", "ds/shards/pairs-000001-0123456789abcdef.parquet", "not parquet"]);
    let record =
        format!("{}~{}~pairs-000004-deaddeaddeaddead.parquet~1.tmp", pointreggpt::atomic::hostname(), 4_194_304 + 7);
    peer(&ep, &["abandon", &ep, "repair", "ds", &record, "pairs-000004-deaddeaddeaddead.parquet"]);
    assert_eq!(uncommitted(&ep, "repair"), ["ds/shards/pairs-000004-deaddeaddeaddead.parquet"]);

    let o = run(&ep, &["verify", url]).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(!o.status.success() && text.contains(&bad) && text.contains("verify: FAILED"), "{text}");
    let report = Dataset::open(url).unwrap().verify().unwrap();
    assert_eq!((report.problems.len(), report.orphans.len(), report.stale_temps.len()), (1, 1, 1), "{report}");

    let said = ok(run(&ep, &["verify", "--repair", url]).output().unwrap());
    assert!(said.contains("withdrew 1 manifest entries"), "{said}");
    assert_eq!(uncommitted(&ep, "repair"), Vec::<String>::new(), "the dead writer's blocks are dropped");
    let listed = objects(&ep, "repair", "ds");
    assert!(
        !listed.keys().any(|k| k.contains("0123456789abcdef") || k.contains(&bad) || k.starts_with(".tmp/")),
        "{listed:?}"
    );
    assert_eq!(committed(url), 5);
    // The next build redoes exactly the withdrawn shard.
    let summary = ok(build(&ep, &config, url).output().unwrap());
    assert!(summary.contains("5 shards already committed, 1 committed now"), "{summary}");
    assert_eq!(digests(url), reference);
    assert_clean(&ep, "repair", "ds");
}

#[test]
fn large_shards_go_up_in_blocks_and_read_back_whole() {
    let _timing = crate::support::timed();
    use pointreggpt::shards::store::object::ObjectDatasetStore;
    let w = World::new("big");
    let ep = w.endpoint();
    let (_, local, _) = w.reference_build(synthetic_config(2, 12, 2, 1, 320, 240, 12));
    let rows = Dataset::open(local.to_str().unwrap()).unwrap().read_pairs().unwrap();
    let url = "az://big/ds";
    let ds = Dataset::create_or_open(url, "seed = 1\n", "h1").unwrap();
    let batch = pointreggpt::shards::pairs_to_batch(&rows).unwrap();
    let mut draft =
        Dataset::open(local.to_str().unwrap()).unwrap().committed("pairs").unwrap().into_values().next().unwrap();
    (draft.file, draft.bytes, draft.blake3, draft.config_hash) = (String::new(), 0, String::new(), "h1".into());
    // Parts of 1 MiB (Azure blocks have no minimum size): Put Block per part, then Put Block List.
    let store = ObjectDatasetStore::open(url, &url::Url::parse(url).unwrap()).unwrap();
    let entry = store.commit_object_with(draft, &batch, 1 << 20, pointreggpt::shards::ROW_GROUP_ROWS).unwrap();
    assert!(entry.bytes > 3 << 20, "{} bytes", entry.bytes);
    let blocks: u64 = peer(&ep, &["blocks", &ep, "big", &format!("ds/shards/{}", entry.file)]).parse().unwrap();
    assert_eq!(blocks, entry.bytes.div_ceil(1 << 20), "{} bytes", entry.bytes);
    assert_eq!(objects(&ep, "big", "ds")[&format!("shards/{}", entry.file)].0, entry.bytes);
    assert_eq!(ds.read_pairs().unwrap(), rows);
    assert!(ds.verify().unwrap().is_ok());
    assert_clean(&ep, "big", "ds");
}

/// Every blob name of `container` (uncommitted block uploads included), and the container names.
fn everything(endpoint: &str, container: &str) -> (String, String) {
    (peer(endpoint, &["names", endpoint, container]), peer(endpoint, &["containers", endpoint]))
}

#[test]
fn a_missing_container_and_an_unreachable_azurite_fail_clearly_before_any_work() {
    let _timing = crate::support::timed();
    let w = World::new("present");
    let ep = w.endpoint();
    let config = w.dir.path().join("c.toml");
    std::fs::write(&config, synthetic_config(1, 4, 2, 1, 160, 120, 2)).unwrap();
    let trap = support::strict_trap(w.dir.path());
    // The trap works: on a reachable container the strict build fails on the truncated frame.
    let o = build(&ep, &trap, "az://present/probe").arg("--strict").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("frame-000000.depth.png"), "the strict build did not stop at the bad frame: {err}");
    peer(&ep, &["delete", &ep, "present", "probe/dataset.toml"]);
    let empty = (String::from("[]"), String::from(r#"["present"]"#));
    assert_eq!(everything(&ep, "present"), empty, "the probe left blobs");

    // Each bad URL: the command fails naming the URL and the reason, without reading any frame (the
    // strict build would stop at the truncated one), without writing any blob or block to the server,
    // without creating a container, and without leaving anything in its working folder.
    let fails = |endpoint: &str, out: &str, wants: &[&str]| {
        let t = Instant::now();
        let cwd = tempfile::tempdir().unwrap();
        let o = build(endpoint, &trap, out).arg("--strict").current_dir(cwd.path()).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{out}: {err}");
        assert!(!err.contains("depth.png"), "{out}: the build read a frame before failing: {err}");
        assert!(!String::from_utf8_lossy(&o.stdout).contains("units in"), "{out}: the build started");
        for w in wants {
            assert!(err.contains(w), "{out}: `{w}` not in: {err}");
        }
        let left: Vec<_> = std::fs::read_dir(cwd.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert!(left.is_empty(), "{out}: left {left:?} in the working folder");
        assert_eq!(everything(&ep, "present"), empty, "{out}: blobs were written or a container created");
        eprintln!("{out}: failed in {:.1} s: {}", t.elapsed().as_secs_f64(), err.trim());
    };
    fails(&ep, "az://missing/ds", &["az://missing/ds", "ContainerNotFound", "does the bucket exist"]);
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    fails(&format!("http://127.0.0.1:{closed}"), "az://present/ds", &["az://present/ds", "cannot reach the store"]);
    // The container that exists works.
    assert!(ok(build(&ep, &config, "az://present/ds").output().unwrap()).contains("1 committed now"));
}

#[test]
fn repair_on_azure_leaves_live_writers_alone_and_removes_stale_records_and_planted_orphans() {
    let _timing = crate::support::timed();
    use crate::support::repair::{Planted, Running};
    let w = World::new("repair");
    let e = w.endpoint();
    let config = w.dir.path().join("c.toml");
    std::fs::write(&config, synthetic_config(1, 8, 2, 1, 160, 120, 1)).unwrap();
    let url = "az://repair/ds";
    ok(build(&e, &config, url).output().unwrap());
    let committed = digests(url);
    assert_eq!(committed.len(), 4);
    let before = objects(&e, "repair", "ds");
    let shard = before.keys().find(|k| k.starts_with("shards/")).unwrap().clone();
    let record = |object: &str| serde_json::json!({ "object": object, "upload_id": "" }).to_string();
    let put = |key: &str, text: &str| peer(&e, &["put", &e, "repair", &format!("ds/{key}"), text]);
    let copy = |object: &str| peer(&e, &["copy", &e, "repair", &format!("ds/{shard}"), &format!("ds/shards/{object}")]);

    // The scenario of tests/support/repair.rs, planted in Azure's terms: the live writer's unfinished
    // upload is a blob with uncommitted blocks only; every other writer has put its whole blob.
    let mut writer = Running::start();
    let p = Planted::new(writer.0.id());
    peer(&e, &["abandon", &e, "repair", "ds", &p.live_upload_record, p.live_upload]);
    p.plant(|record_name, object| drop(put(&format!(".tmp/{record_name}"), &record(object))), |object| drop(copy(object)));
    let live_upload = vec![format!("ds/shards/{}", p.live_upload)];
    assert_eq!(uncommitted(&e, "repair"), live_upload);

    p.assert_listed(&ok(run(&e, &["verify", url]).output().unwrap()));
    let repaired = ok(run(&e, &["verify", "--repair", url]).output().unwrap());
    assert_eq!(uncommitted(&e, "repair"), live_upload, "repair dropped a live writer's block upload:\n{repaired}");
    p.assert_repaired(&before, &objects(&e, "repair", "ds"), &repaired);
    assert_eq!(digests(url), committed);
    assert!(Dataset::open(url).unwrap().verify().unwrap().is_ok());

    // The writer dies: now its records are stale, and repair drops its blocks and removes its blobs.
    writer.0.kill().unwrap();
    writer.0.wait().unwrap();
    peer(&e, &["delete", &e, "repair", &format!("ds/.tmp/{}", p.remote_record)]);
    assert_clean(&e, "repair", "ds");
    assert_eq!(digests(url), committed);
    assert!(!objects(&e, "repair", "ds").contains_key(&format!("shards/{}", p.remote)), "an unnamed blob stayed");
}
