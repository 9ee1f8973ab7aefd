//! Datasets on object storage, against a real S3 server started by each test (moto, from PyPI): a build
//! to `s3://` equals the same build to a folder, SIGKILLs and resume, two racing writers, queries and
//! pyarrow reading the committed objects, bad URLs, a store that goes away mid-build, multipart uploads
//! and their repair. Tests fail (never skip) when moto cannot start.

use crate::support;

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::store::open_store;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};
use std::path::PathBuf;
use std::sync::MutexGuard;
use crate::support::store::{Moto, Proxy, ENV};
use crate::support::{bin, digests, strict_trap, synthetic_config, synthetic_labels_config};

/// One test's S3 world: a moto server with one bucket and a temporary folder, under the lock of the
/// process environment (the tests point the AWS variables at their own server).
struct World {
    moto: Moto,
    dir: tempfile::TempDir,
    _env: MutexGuard<'static, ()>,
}

impl World {
    fn new(bucket: &str) -> World {
        let _env = ENV.lock().unwrap_or_else(|e| e.into_inner());
        let moto = Moto::start();
        moto.set_env();
        moto.create_bucket(bucket);
        World { moto, dir: tempfile::tempdir().unwrap(), _env }
    }

    /// Writes `config` as a build config and builds it into a local folder: the config's path, the
    /// folder and its content digests, the reference a build on the store must equal.
    fn reference_build(&self, config: String) -> (PathBuf, PathBuf, BTreeMap<u64, String>) {
        let path = self.dir.path().join("c.toml");
        std::fs::write(&path, config).unwrap();
        let local = self.dir.path().join("ref");
        ok(build(&self.moto.endpoint(), &path, local.to_str().unwrap()).output().unwrap());
        let reference = digests(local.to_str().unwrap());
        (path, local, reference)
    }
}

/// Content digests of the committed pairs of `dataset` (folder or URL; for a URL, the environment
/// must point at its server).

/// `pointreggpt <args>` with the store environment of `endpoint`.
fn run(endpoint: &str, args: &[&str]) -> Command {
    let mut c = bin();
    c.args(["--threads", "2"]).args(args).envs(Moto::vars(endpoint)).stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

fn build(endpoint: &str, config: &Path, out: &str) -> Command {
    run(endpoint, &["build", config.to_str().unwrap(), "--out", out, "--no-progress"])
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A Python peer from tests/python/s3_peer.py.
fn peer(endpoint: &str, args: &[&str]) -> String {
    let script = format!("{}/tests/python/s3_peer.py", env!("CARGO_MANIFEST_DIR"));
    let o = support::python_command().arg(script).args(args).envs(Moto::vars(endpoint)).output().unwrap();
    assert!(o.status.success(), "s3_peer.py {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).trim().to_string()
}

/// Object keys under `prefix` with their sizes, listed by boto3.
fn objects(endpoint: &str, bucket: &str, prefix: &str) -> BTreeMap<String, (u64, String)> {
    serde_json::from_str(&peer(endpoint, &["objects", endpoint, bucket, prefix])).unwrap()
}

/// After `verify --repair`: every object under shards/ is named by a manifest entry, no upload record
/// and no incomplete multipart upload is left, and verify is clean.
fn assert_clean(endpoint: &str, bucket: &str, prefix: &str) {
    ok(run(endpoint, &["verify", "--repair", &format!("s3://{bucket}/{prefix}")]).output().unwrap());
    let ds = Dataset::open(format!("s3://{bucket}/{prefix}")).unwrap();
    let report = ds.verify().unwrap();
    assert!(report.is_ok() && report.orphans.is_empty() && report.stale_temps.is_empty() && report.other_temps.is_empty(), "{report}");
    let files: Vec<String> = objects(endpoint, bucket, prefix).into_keys().filter(|k| k.starts_with("shards/")).collect();
    let named: Vec<String> = ds.committed("pairs").unwrap().values().map(|e| format!("shards/{}", e.file)).collect();
    assert_eq!(files, named, "one object per committed shard, nothing else");
    assert_eq!(peer(endpoint, &["uploads", endpoint, bucket]), "0", "no incomplete multipart upload");
}

#[test]
fn a_build_on_s3_equals_the_build_in_a_folder_and_queries_and_pyarrow_agree() {
    let _timing = crate::support::timed();
    let w = World::new("data");
    let moto = &w.moto;
    let (config, local, reference) = w.reference_build(synthetic_config(2, 12, 2, 1, 320, 240, 2));
    let url = "s3://data/runs/demo";
    let summary = ok(build(&moto.endpoint(), &config, url).output().unwrap());
    assert!(summary.contains("6 committed now") && summary.contains("pointreggpt query s3://data/runs/demo"), "{summary}");
    assert_eq!(reference.len(), 12);
    assert_eq!(digests(url), reference, "same rows, content hash for content hash");
    // Another config on the same prefix is refused, naming the URL and the key.
    let o = build(&moto.endpoint(), &config, url).args(["--set", "seed=12"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("s3://data/runs/demo") && err.contains("seed: 11 → 12"), "{err}");
    // Shard objects have unique names; the local layout is unchanged.
    let keys = objects(&moto.endpoint(), "data", "runs/demo");
    assert!(keys.keys().any(|k| k.starts_with("shards/pairs-000000-")), "{keys:?}");
    assert!(local.join("shards/pairs-000000.parquet").is_file());

    for sql in [
        "select status, count(*) n, round(sum(overlap_source), 9) s, max(overlap_target) m from pairs group by status order by status",
        "select pair_key, array_length(source_points) n from pairs where status = 'ok' order by pair_key",
        "select shard, rows, units from manifest order by shard",
    ] {
        let a = ok(run(&moto.endpoint(), &["query", local.to_str().unwrap(), sql, "--format", "csv"]).output().unwrap());
        let b = ok(run(&moto.endpoint(), &["query", url, sql, "--format", "csv"]).output().unwrap());
        assert_eq!(a, b, "{sql}");
        assert!(a.lines().count() > 1, "{sql}: {a}");
    }
    // pyarrow reads the committed objects from the server; the same script reads the folder.
    let from_s3: serde_json::Value = serde_json::from_str(&peer(&moto.endpoint(), &["rows-s3", &moto.endpoint(), "data", "runs/demo"])).unwrap();
    let from_folder: serde_json::Value = serde_json::from_str(&peer(&moto.endpoint(), &["rows-local", local.to_str().unwrap()])).unwrap();
    assert_eq!(from_s3, from_folder);
    let rows = Dataset::open(url).unwrap().read_pairs().unwrap();
    assert_eq!(from_s3.as_object().unwrap().len(), rows.len());
    for r in &rows {
        let v = &from_s3[&r.pair_key];
        assert_eq!((v[0].as_str().unwrap(), v[2].as_u64().unwrap() as usize), (r.status.as_str(), r.source_points.len()));
    }
    // export, stats and preview read the store too: the files they write from the URL are the files
    // they write from the folder, byte for byte.
    let out = w.dir.path().join("ply");
    let said = ok(run(&moto.endpoint(), &["export", url, "--format", "ply", "--out", out.to_str().unwrap(), "--limit", "2", "--no-progress"]).output().unwrap());
    assert!(said.contains("wrote 2 pairs"), "{said}");
    for (command, extra, expect) in [("stats", vec!["--per-scene"], 2), ("preview", vec!["--limit", "3"], 3)] {
        let outputs: Vec<BTreeMap<String, Vec<u8>>> = [local.to_str().unwrap(), url]
            .into_iter()
            .enumerate()
            .map(|(k, dataset)| {
                let out = w.dir.path().join(format!("{command}-{k}"));
                ok(run(&moto.endpoint(), &[&[command, dataset, "--out", out.to_str().unwrap(), "--no-progress"], &extra[..]].concat()).output().unwrap());
                std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().path()).map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap())).collect()
            })
            .collect();
        assert_eq!(outputs[0].len(), expect, "{command}: {:?}", outputs[0].keys());
        assert!(outputs[0].values().all(|b| b.len() > 100), "{command}: an empty file");
        assert_eq!(outputs[1].keys().collect::<Vec<_>>(), outputs[0].keys().collect::<Vec<_>>(), "{command}: other files from the URL");
        for (name, bytes) in &outputs[0] {
            assert!(outputs[1][name] == *bytes, "{command}: {name} differs between the folder and the URL");
        }
    }
    assert_clean(&moto.endpoint(), "data", "runs/demo");
}

/// A counter of the manifest objects under `url` (0 before the dataset exists), on one store client.
fn manifest_counter(url: &str) -> impl Fn() -> usize {
    let store = open_store(Path::new(url)).unwrap();
    move || store.list("manifest").map(|l| l.len()).unwrap_or(0)
}

#[test]
fn sigkills_during_an_s3_build_then_resume_give_the_same_dataset_and_repair_leaves_nothing() {
    let _timing = crate::support::timed();
    use std::os::unix::process::ExitStatusExt;
    let w = World::new("kills");
    let moto = &w.moto;
    let (config, _, reference) = w.reference_build(synthetic_config(2, 40, 2, 1, 320, 240, 2));
    let url = "s3://kills/ds";
    let manifest_objects = manifest_counter(url);
    let (total, mut log) = (20, Vec::new());
    let mut rng = pointreggpt::rng::Rng::new(18);
    for i in 0..8 {
        let mut child = build(&moto.endpoint(), &config, url).spawn().unwrap();
        if i % 2 == 0 {
            // Wait until this run committed a shard of its own, then kill within 0..150 ms: mid-build.
            let (before, t0) = (manifest_objects(), Instant::now());
            while manifest_objects() == before && child.try_wait().unwrap().is_none() {
                assert!(t0.elapsed() < Duration::from_secs(120), "no shard committed in 2 minutes");
                std::thread::sleep(Duration::from_millis(5));
            }
            std::thread::sleep(Duration::from_millis(rng.below(150)));
        } else {
            std::thread::sleep(Duration::from_millis(rng.uniform_range(50.0, 1500.0) as u64));
        }
        let _ = child.kill();
        let status = child.wait().unwrap();
        let committed = Dataset::open(url).and_then(|d| d.committed("pairs")).map(|c| c.len()).unwrap_or(0);
        log.push((i, status.signal() == Some(9), committed));
        if committed > 0 {
            for (k, d) in digests(url) {
                assert_eq!(Some(&d), reference.get(&k), "unit {k} differs after a kill");
            }
        }
    }
    let mid = log.iter().filter(|(_, killed, c)| *killed && *c > 0 && *c < total).count();
    assert!(mid > 0, "no kill landed mid-build: {log:?}");
    ok(build(&moto.endpoint(), &config, url).output().unwrap());
    assert_eq!(digests(url), reference, "the resumed dataset equals the uninterrupted one");
    assert_clean(&moto.endpoint(), "kills", "ds");
    eprintln!("{mid} of 8 kills landed mid-build: {log:?}");
}

#[test]
fn two_writers_racing_on_the_same_shards_leave_one_object_per_shard() {
    let _timing = crate::support::timed();
    let w = World::new("race");
    let moto = &w.moto;
    let (config, local, reference) = w.reference_build(synthetic_config(1, 16, 2, 1, 320, 240, 2));
    let url = "s3://race/ds";
    // Both processes own every shard (one worker each), so each shard is written twice.
    let a = build(&moto.endpoint(), &config, url).spawn().unwrap();
    let b = build(&moto.endpoint(), &config, url).spawn().unwrap();
    let (oa, ob) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let lost = [&oa, &ob].iter().map(|o| String::from_utf8_lossy(&o.stderr).matches("committed it first").count()).sum::<usize>();
    ok(oa);
    ok(ob);
    assert!(lost > 0, "no writer lost a race");
    assert_eq!(digests(url), reference);
    assert_clean(&moto.endpoint(), "race", "ds");

    // Two workers splitting the shards (k mod 2) into one prefix, at the same time.
    let workers: Vec<_> = (0..2)
        .map(|i| build(&moto.endpoint(), &config, "s3://race/split").args(["--worker", &i.to_string(), "--workers", "2"]).spawn().unwrap())
        .collect();
    for worker in workers {
        assert!(ok(worker.wait_with_output().unwrap()).contains("2 committed now"));
    }
    assert_eq!(digests("s3://race/split"), reference);

    // Eight threads committing one shard at once: one object, one entry, the same for everyone.
    let ds = Dataset::create_or_open("s3://race/threads", "seed = 1\n", "h1").unwrap();
    let rows = Dataset::open(local.to_str().unwrap()).unwrap().read_pairs().unwrap()[..2].to_vec();
    let entries: Vec<_> = std::thread::scope(|s| {
        let h: Vec<_> = (0..8).map(|_| s.spawn(|| ds.commit_pairs(0, 0, 2, &rows).unwrap())).collect();
        h.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(entries.iter().all(|e| *e == entries[0]), "every writer returns the winning entry");
    let shards: Vec<String> = objects(&moto.endpoint(), "race", "threads").into_keys().filter(|k| k.starts_with("shards/")).collect();
    assert_eq!(shards, [format!("shards/{}", entries[0].file)]);
    assert_eq!(ds.read_pairs().unwrap(), rows);

    // An entry whose object is gone: verify reports it, and the next commit replaces the entry (a
    // conditional put on its ETag) instead of adopting it.
    peer(&moto.endpoint(), &["delete", &moto.endpoint(), "race", &format!("threads/shards/{}", entries[0].file)]);
    assert!(!ds.verify().unwrap().is_ok());
    let again = ds.commit_pairs(0, 0, 2, &rows).unwrap();
    assert_ne!(again.file, entries[0].file);
    assert_eq!(ds.read_pairs().unwrap(), rows);
    assert!(ds.verify().unwrap().is_ok());
}

#[test]
fn bad_urls_fail_clearly_before_any_work() {
    let _timing = crate::support::timed();
    let w = World::new("present");
    let moto = &w.moto;
    let config = w.dir.path().join("c.toml");
    std::fs::write(&config, synthetic_config(1, 4, 2, 1, 160, 120, 2)).unwrap();
    let trap = strict_trap(w.dir.path());
    // The trap works: on a reachable store the strict build fails on the truncated frame.
    let o = build(&moto.endpoint(), &trap, "s3://present/probe").arg("--strict").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("frame-000000.depth.png"), "the strict build did not stop at the bad frame: {err}");
    peer(&moto.endpoint(), &["delete", &moto.endpoint(), "present", "probe/dataset.toml"]);
    assert_eq!(peer(&moto.endpoint(), &["keys", &moto.endpoint(), "present"]), "[]", "the probe left objects");

    // Each bad URL: the command fails naming the URL and the reason, without reading any frame (the
    // strict build would stop at the truncated one), without writing any object or upload to the
    // server, without creating a bucket, and without leaving anything in its working folder.
    let fails = |endpoint: &str, extra: &[(&str, &str)], out: &str, wants: &[&str]| {
        let t = Instant::now();
        let cwd = tempfile::tempdir().unwrap();
        let o = build(endpoint, &trap, out).arg("--strict").envs(extra.iter().copied()).current_dir(cwd.path()).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{out}: {err}");
        assert!(!err.contains("depth.png"), "{out}: the build read a frame before failing: {err}");
        for w in wants {
            assert!(err.contains(w), "{out}: `{w}` not in: {err}");
        }
        let left: Vec<_> = std::fs::read_dir(cwd.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert!(left.is_empty(), "{out}: left {left:?} in the working folder");
        eprintln!("{out}: failed in {:.1} s: {}", t.elapsed().as_secs_f64(), err.trim());
    };
    let nothing_written = |what: &str| {
        assert_eq!(peer(&moto.endpoint(), &["keys", &moto.endpoint(), "present"]), "[]", "{what}: objects were written");
        assert_eq!(peer(&moto.endpoint(), &["uploads", &moto.endpoint(), "present"]), "0", "{what}: an upload was started");
        assert_eq!(peer(&moto.endpoint(), &["buckets", &moto.endpoint()]), r#"["present"]"#, "{what}: a bucket was created");
    };
    fails(&moto.endpoint(), &[], "ftp://host/data", &["ftp://host/data", "unknown URL scheme", "s3://"]);
    nothing_written("ftp://host/data");
    fails(&moto.endpoint(), &[], "s3://missing-bucket/ds", &["s3://missing-bucket/ds", "does the bucket exist"]);
    nothing_written("s3://missing-bucket/ds");
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    fails(&format!("http://127.0.0.1:{closed}"), &[], "s3://present/ds", &["s3://present/ds", "cannot reach the store"]);
    nothing_written("an unreachable endpoint");
    // A profile in the AWS files (no key, no endpoint in the environment): its endpoint_url can only come
    // from the config file, so the build reaching moto shows the files were read.
    let (creds, conf) = (w.dir.path().join("credentials"), w.dir.path().join("config"));
    std::fs::write(&creds, "[builder]\naws_access_key_id = testing\naws_secret_access_key = testing\n").unwrap();
    std::fs::write(&conf, format!("[profile builder]\nregion = us-east-1\nendpoint_url = {}\n", moto.endpoint())).unwrap();
    let o = build(&moto.endpoint(), &config, "s3://present/profile")
        .env_remove("AWS_ACCESS_KEY_ID")
        .env_remove("AWS_SECRET_ACCESS_KEY")
        .env_remove("AWS_ENDPOINT_URL")
        .env_remove("AWS_REGION")
        .env("AWS_SHARED_CREDENTIALS_FILE", &creds)
        .env("AWS_CONFIG_FILE", &conf)
        .env("AWS_PROFILE", "builder")
        .output()
        .unwrap();
    assert!(ok(o).contains("1 committed now"));
    // Wrong credentials: with moto's authentication on, a key IAM never made is refused.
    moto.require_auth();
    fails(&moto.endpoint(), &[("AWS_ACCESS_KEY_ID", "AKIAIOSFODNN7EXAMPLE")], "s3://present/ds", &["s3://present/ds", "InvalidAccessKeyId", "credentials were refused"]);
    moto.end_auth();
    assert_eq!(objects(&moto.endpoint(), "present", "ds").len(), 0, "refused credentials: objects were written");
    assert_eq!(peer(&moto.endpoint(), &["uploads", &moto.endpoint(), "present"]), "0", "refused credentials: an upload was started");
}

#[test]
fn without_credentials_and_with_the_metadata_service_off_no_metadata_address_is_asked() {
    let _timing = crate::support::timed();
    use crate::support::store::MetadataTrap;
    let w = World::new("creds");
    let moto = &w.moto;
    let config = w.dir.path().join("c.toml");
    std::fs::write(&config, synthetic_config(1, 4, 2, 1, 160, 120, 2)).unwrap();
    let trap = MetadataTrap::start();
    // No key and no profile: the client's last resort is the instance metadata service, here the trap.
    let attempt = |metadata_disabled: &str| {
        let o = build(&moto.endpoint(), &config, "s3://creds/ds")
            .env_remove("AWS_ACCESS_KEY_ID")
            .env_remove("AWS_SECRET_ACCESS_KEY")
            .env("AWS_METADATA_ENDPOINT", trap.endpoint())
            .env("AWS_EC2_METADATA_DISABLED", metadata_disabled)
            .output()
            .unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    // The control: with the service allowed, the client asks the trap (so the trap would see it).
    let (done, err) = attempt("false");
    assert!(!done && trap.calls() > 0, "the client never asked the metadata address ({} calls): {err}", trap.calls());
    let before = trap.calls();
    // The tests' setting (support::ISOLATED_AWS): the command fails naming the URL and the cause,
    // and never calls the metadata address.
    let (done, err) = attempt("true");
    assert!(!done, "a build without credentials succeeded");
    assert_eq!(trap.calls(), before, "the metadata address was asked although AWS_EC2_METADATA_DISABLED=true: {err}");
    assert!(err.contains("s3://creds/ds") && err.contains("no AWS credentials") && err.contains("AWS_EC2_METADATA_DISABLED"), "{err}");
    assert_eq!(peer(&moto.endpoint(), &["keys", &moto.endpoint(), "creds"]), "[]");
}

#[test]
fn a_store_that_goes_away_mid_build_keeps_every_committed_shard_and_the_build_fails() {
    let _timing = crate::support::timed();
    let w = World::new("flaky");
    let moto = &w.moto;
    let (config, _, reference) = w.reference_build(synthetic_config(2, 40, 2, 1, 320, 240, 2));
    let url = "s3://flaky/ds";
    let proxy = Proxy::start(moto.port);
    let manifest_objects = manifest_counter(url);
    let child = build(&proxy.endpoint(), &config, url).spawn().unwrap();
    let t0 = Instant::now();
    while manifest_objects() < 2 {
        assert!(t0.elapsed() < Duration::from_secs(120), "no shard committed in 2 minutes");
        std::thread::sleep(Duration::from_millis(5));
    }
    proxy.stop();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "the build cannot finish without its store");
    assert!(err.contains("s3://flaky/ds"), "{err}");
    let partial = digests(url);
    assert!(!partial.is_empty() && partial.len() < reference.len(), "{} of {}", partial.len(), reference.len());
    assert!(partial.iter().all(|(k, d)| reference.get(k) == Some(d)), "committed shards are intact");
    assert!(Dataset::open(url).unwrap().verify().unwrap().is_ok());
    ok(build(&moto.endpoint(), &config, url).output().unwrap());
    assert_eq!(digests(url), reference);
    assert_clean(&moto.endpoint(), "flaky", "ds");
}

#[test]
fn a_store_that_fails_for_a_few_seconds_mid_build_is_retried_and_the_build_completes() {
    let _timing = crate::support::timed();
    use std::sync::atomic::Ordering;
    use crate::support::store::HttpProxy;
    let w = World::new("outage");
    let moto = &w.moto;
    let (config, _, reference) = w.reference_build(synthetic_config(2, 40, 2, 1, 320, 240, 2));
    let total = reference.len().div_ceil(2);
    // A store that never answers but 503: a command retries for the whole window it is given
    // (POINTREGGPT_STORE_RETRY_SECONDS, 10 s here), then fails naming the URL; waits are capped at 5 s.
    let failing = HttpProxy::start(moto.port);
    failing.set_failing(true);
    let t = Instant::now();
    let o = run(&failing.endpoint(), &["verify", "s3://outage/nothing"]).env("POINTREGGPT_STORE_RETRY_SECONDS", "10").output().unwrap();
    let (took, err) = (t.elapsed().as_secs_f64(), String::from_utf8_lossy(&o.stderr));
    eprintln!("a store down for good: failed after {took:.1} s and {} requests: {}", failing.refused.load(Ordering::SeqCst), err.trim());
    assert!(!o.status.success() && err.contains("s3://outage/nothing") && err.contains("503"), "{err}");
    assert!((10.0..18.0).contains(&took), "gave up after {took:.1} s, not after the 10 s retry window: {err}");
    // Retry the setup when the outage did not hit a running build (it finished first, or sent no
    // request while the proxy failed); each attempt builds into a fresh prefix.
    for attempt in 0..3 {
        let url = format!("s3://outage/ds{attempt}");
        let proxy = HttpProxy::start(moto.port);
        let manifest_objects = manifest_counter(&url);
        // The README's default retry window (30 s): no POINTREGGPT_STORE_RETRY_SECONDS.
        let mut child = build(&proxy.endpoint(), &config, &url).env_remove("POINTREGGPT_STORE_RETRY_SECONDS").spawn().unwrap();
        let t0 = Instant::now();
        while manifest_objects() < 2 && child.try_wait().unwrap().is_none() {
            assert!(t0.elapsed() < Duration::from_secs(120), "no shard committed in 2 minutes");
            std::thread::sleep(Duration::from_millis(5));
        }
        // Every request fails with 503 for 8 s. (object_store's own retry settings, 10 retries with a
        // backoff that does not grow, gave up after 1.7-5.5 s in 80 % of draws, 8 s in 4 %.)
        proxy.set_failing(true);
        let committed_at_start = manifest_objects();
        let running_at_start = child.try_wait().unwrap().is_none();
        std::thread::sleep(Duration::from_secs(8));
        let running_at_end = child.try_wait().unwrap().is_none();
        let committed_at_end = manifest_objects();
        proxy.set_failing(false);
        let refused = proxy.refused.load(Ordering::SeqCst);
        let o = child.wait_with_output().unwrap();
        let hit = running_at_start && running_at_end && refused > 0 && committed_at_start < total;
        eprintln!(
            "attempt {attempt}: {refused} requests refused during the outage, {committed_at_start} -> {committed_at_end} of {total} \
             shards committed across it, running at its start {running_at_start} and end {running_at_end}"
        );
        if !hit {
            ok(o);
            continue;
        }
        let out = ok(o);
        assert!(out.contains(&format!("{total} committed now")), "{out}");
        assert_eq!(digests(&url), reference, "the build that rode out the outage equals the uninterrupted one");
        assert!(proxy.forwarded.load(Ordering::SeqCst) > refused, "requests went through after the outage");
        assert_clean(&moto.endpoint(), "outage", &format!("ds{attempt}"));
        return;
    }
    panic!("in 3 attempts the outage never hit a running build");
}

#[test]
fn repair_leaves_live_writers_alone_and_removes_stale_records_and_planted_orphans() {
    let _timing = crate::support::timed();
    use crate::support::repair::{Planted, Running};
    let w = World::new("repair");
    let moto = &w.moto;
    let e = moto.endpoint();
    let config = w.dir.path().join("c.toml");
    std::fs::write(&config, synthetic_config(1, 8, 2, 1, 160, 120, 1)).unwrap();
    let url = "s3://repair/ds";
    ok(build(&e, &config, url).output().unwrap());
    let committed = digests(url);
    assert_eq!(committed.len(), 4);
    let before = objects(&e, "repair", "ds");
    let shard = before.keys().find(|k| k.starts_with("shards/")).unwrap().clone();
    let put = |key: &str, text: &str| {
        let file = w.dir.path().join("body");
        std::fs::write(&file, text).unwrap();
        peer(&e, &["put", &e, "repair", &format!("ds/{key}"), file.to_str().unwrap()]);
    };
    let record = |object: &str| serde_json::json!({ "object": object, "upload_id": null }).to_string();
    let copy = |object: &str| peer(&e, &["copy", &e, "repair", &format!("ds/{shard}"), &format!("ds/shards/{object}")]);

    // The scenario of tests/support/repair.rs, planted in S3's terms: the live writer's unfinished
    // upload is a multipart upload; every other writer has put its whole object.
    let mut writer = Running::start();
    let p = Planted::new(writer.0.id());
    peer(&e, &["abandon", &e, "repair", "ds", &p.live_upload_record, p.live_upload]);
    p.plant(|record_name, object| put(&format!(".tmp/{record_name}"), &record(object)), |object| drop(copy(object)));
    assert_eq!(peer(&e, &["uploads", &e, "repair"]), "1");

    p.assert_listed(&ok(run(&e, &["verify", url]).output().unwrap()));
    let repaired = ok(run(&e, &["verify", "--repair", url]).output().unwrap());
    assert_eq!(peer(&e, &["uploads", &e, "repair"]), "1", "repair aborted a live writer's multipart upload:\n{repaired}");
    p.assert_repaired(&before, &objects(&e, "repair", "ds"), &repaired);
    assert_eq!(digests(url), committed);
    assert!(Dataset::open(url).unwrap().verify().unwrap().is_ok());

    // The writer dies: now its records are stale, and repair aborts its upload and removes its objects.
    writer.0.kill().unwrap();
    writer.0.wait().unwrap();
    peer(&e, &["delete", &e, "repair", &format!("ds/.tmp/{}", p.remote_record)]);
    assert_clean(&e, "repair", "ds");
    assert_eq!(digests(url), committed);
    assert!(!objects(&e, "repair", "ds").contains_key(&format!("shards/{}", p.remote)), "an unnamed object stayed");
}

#[test]
fn large_shards_go_up_in_parts_and_abandoned_uploads_are_aborted_by_repair() {
    let _timing = crate::support::timed();
    use pointreggpt::shards::store::object::ObjectDatasetStore;
    let w = World::new("big");
    let moto = &w.moto;
    let url = "s3://big/ds";
    let ds = Dataset::create_or_open(url, "seed = 1\n", "h1").unwrap();
    // 40 rows of two 40k-point clouds of noise: ~19 MB of Parquet, four parts of 5 MiB.
    let mut rng = pointreggpt::rng::Rng::new(3);
    let rows: Vec<pointreggpt::shards::PairRow> = (0..40)
        .map(|i| {
            let mut cloud = || (0..40_000).map(|_| pointreggpt::geometry::Point::new(rng.uniform() as f32, rng.uniform() as f32, rng.uniform() as f32)).collect();
            pointreggpt::shards::PairRow { unit_index: i, pair_key: format!("k#{i}"), source_points: cloud(), target_points: cloud(), config_hash: "h1".into(), ..Default::default() }
        })
        .collect();
    let batch = pointreggpt::shards::pairs_to_batch(&rows).unwrap();
    let draft = pointreggpt::shards::ManifestEntry {
        table: "pairs".into(),
        shard: 0,
        first_unit: 0,
        units: 40,
        rows: 40,
        rows_by_status: [("ok".to_string(), 40)].into(),
        file: String::new(),
        bytes: 0,
        blake3: String::new(),
        schema_version: pointreggpt::shards::SCHEMA_VERSION.into(),
        config_hash: "h1".into(),
        code_version: "test".into(),
        worker: "test".into(),
        created: "2025-01-01T00:00:00Z".into(),
    };
    let store = ObjectDatasetStore::open(url, &url::Url::parse(url).unwrap()).unwrap();
    let entry = store.commit_object_with(draft, &batch, 5 << 20, pointreggpt::shards::ROW_GROUP_ROWS).unwrap();
    let listed = objects(&moto.endpoint(), "big", "ds");
    let (size, etag) = &listed[&format!("shards/{}", entry.file)];
    assert_eq!(*size, entry.bytes);
    assert!(entry.bytes > 15 << 20 && etag.ends_with(&format!("-{}", entry.bytes.div_ceil(5 << 20))), "multipart ETag {etag}, {} bytes", entry.bytes);
    assert_eq!(ds.read_pairs().unwrap(), rows);
    assert!(ds.verify().unwrap().is_ok());

    // A writer that died mid-upload (a pid that never runs): one part sent, its record left behind.
    let host = pointreggpt::atomic::hostname();
    let object = "pairs-000001-dead.parquet";
    let record = format!("{host}~{}~{object}~1.tmp", 4_194_304 + 7);
    peer(&moto.endpoint(), &["abandon", &moto.endpoint(), "big", "ds", &record, object]);
    assert_eq!(peer(&moto.endpoint(), &["uploads", &moto.endpoint(), "big"]), "1");
    let report = ds.verify().unwrap();
    assert_eq!(report.stale_temps.len(), 1, "{report}");
    assert_clean(&moto.endpoint(), "big", "ds");
    assert_eq!(ds.read_pairs().unwrap().len(), 40);
}

#[test]
fn labels_on_s3_equal_labels_in_a_folder_and_training_reads_them() {
    let _timing = crate::support::timed();
    use pointreggpt::training::correction::data::LabelSet;
    let w = World::new("labels");
    let moto = &w.moto;
    let config = w.dir.path().join("l.toml");
    std::fs::write(&config, synthetic_labels_config(24, 160, 120)).unwrap();
    let local = w.dir.path().join("labels");
    let labels = |out: &str| run(&moto.endpoint(), &["labels", config.to_str().unwrap(), "--out", out, "--no-progress"]).output().unwrap();
    ok(labels(local.to_str().unwrap()));
    ok(labels("s3://labels/l"));
    // The training reader (`train correction --labels`) on both.
    let (a, b) = (LabelSet::open(&local).unwrap(), LabelSet::open(Path::new("s3://labels/l")).unwrap());
    assert!(!a.examples.is_empty());
    assert_eq!(a.examples.len(), b.examples.len());
    for (x, y) in a.examples.iter().zip(&b.examples) {
        assert_eq!((&x.key, &x.sparse, &x.dense, &x.keep), (&y.key, &y.sparse, &y.dense, &y.keep));
    }
    let v = ok(run(&moto.endpoint(), &["verify", "s3://labels/l"]).output().unwrap());
    assert!(v.contains("labels: 3 shards intact"), "{v}");
}
