//! Shared helpers of the integration tests (tests/suite): the real-data folder, the binary and the
//! Python peers with the caller's cloud credentials removed, small configs, and the per-test timing.
#![allow(dead_code)]

pub mod azure;
pub mod repair;
pub mod store;

use std::path::PathBuf;

/// The real-data folder from `POINTREGGPT_REAL_DATA` (`make test` sets it to `../shared/realdata` when
/// that is there, as on CI, else to the cache that `make real-data` fetches the frames into). A test that needs it fails when it is missing, so a run without the data
/// cannot pass silently; `POINTREGGPT_SKIP_REAL_DATA=1` is the explicit opt-out for a machine that
/// has no copy (refused when `CI` is set). A skipped test returns `None` and still shows as `ok` in
/// cargo's list (stable Rust cannot mark a test ignored at run time), so the skip is made visible
/// outside the captured output: a `SKIPPED` line on the real stderr when it happens, and a count with
/// the names after the test binary's summary ([`skipped_real_data_tests`]).
pub fn real_data() -> Option<PathBuf> {
    match std::env::var_os("POINTREGGPT_REAL_DATA").filter(|v| !v.is_empty()) {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            assert!(dir.is_dir(), "POINTREGGPT_REAL_DATA={} is not a folder", dir.display());
            Some(dir)
        }
        None if std::env::var_os("POINTREGGPT_SKIP_REAL_DATA").is_some() && std::env::var_os("CI").is_none() => {
            report_skip();
            None
        }
        None => panic!(
            "POINTREGGPT_REAL_DATA is not set: run the tests with `make test` (it uses ../shared/realdata when present, \
             else fetches the frames from their public sources: `make real-data`), or point it at a copy, \
             or set POINTREGGPT_SKIP_REAL_DATA=1 to skip the real-data tests on a machine without the data"
        ),
    }
}

/// Names of the tests of this binary that skipped their real-data claim so far.
static SKIPPED: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

/// The tests of this binary that returned early under `POINTREGGPT_SKIP_REAL_DATA` so far.
pub fn skipped_real_data_tests() -> Vec<String> {
    SKIPPED.lock().unwrap_or_else(|e| e.into_inner()).clone()
}

/// Records a skipped real-data test: writes a `SKIPPED` line straight to the process's stderr (cargo
/// test captures `eprintln!` of passing tests, not the file descriptor), and once per binary registers
/// an exit hook that prints the count and names after cargo's `test result:` line.
fn report_skip() {
    use std::io::Write;
    // libtest names each test's thread after the test.
    let name = std::thread::current().name().unwrap_or("a real-data test").to_string();
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {name}: POINTREGGPT_SKIP_REAL_DATA is set, so this real-data test checks nothing (it still shows as ok)"
    );
    SKIPPED.lock().unwrap_or_else(|e| e.into_inner()).push(name);
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        extern "C" {
            fn atexit(f: extern "C" fn()) -> std::os::raw::c_int;
        }
        extern "C" fn summary() {
            let names = skipped_real_data_tests();
            let _ = writeln!(
                std::io::stderr(),
                "\nSKIPPED {} real-data test(s) of {} (POINTREGGPT_SKIP_REAL_DATA is set; each is listed as ok above but checked nothing): {}\n",
                names.len(),
                std::env::args().next().unwrap_or_default(),
                names.join(", ")
            );
        }
        // SAFETY: registers a plain function with the C library; it runs once when the process exits.
        unsafe {
            atexit(summary);
        }
    });
}

/// The `pointreggpt` binary built for these tests, with the caller's cloud credentials removed
/// ([`command`]).
pub fn bin() -> std::process::Command {
    command(env!("CARGO_BIN_EXE_pointreggpt"))
}

/// The Python interpreter the tests run peers with: `PYTHON` (the Makefile sets it to the project's
/// virtual environment), else that environment itself ([`python_for`]), never the system's `python3`.
pub fn python() -> String {
    python_for(std::env::var_os("PYTHON"), std::env::var_os("POINTREGGPT_VENV"))
}

/// [`python`] for the given `PYTHON` and `POINTREGGPT_VENV` values: `PYTHON` when set, else
/// `<POINTREGGPT_VENV, default the checkout's .venv>/bin/python`; it panics, naming `make test-deps`,
/// when that does not exist (a plain `cargo test` before `make test-deps` fails rather than running the
/// peers with whatever `python3` the machine has).
pub fn python_for(python: Option<std::ffi::OsString>, venv: Option<std::ffi::OsString>) -> String {
    if let Some(p) = python.filter(|p| !p.is_empty()) {
        return p.to_string_lossy().into_owned();
    }
    let venv = venv.filter(|v| !v.is_empty()).map(PathBuf::from).unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv"));
    let python = venv.join("bin").join("python");
    assert!(
        python.is_file(),
        "PYTHON is not set and the project's virtual environment has no {}: run `make test-deps` (it makes {} and installs \
         the peers), or `make test`; the tests never run the system's python3",
        python.display(),
        venv.display()
    );
    python.to_string_lossy().into_owned()
}

/// A Python peer process ([`python`]), with the caller's cloud credentials removed ([`command`]).
pub fn python_command() -> std::process::Command {
    command(python())
}

/// The AWS settings every process a test starts runs with, the test process's own store clients
/// included: no instance metadata service (`AWS_EC2_METADATA_DISABLED`, honoured by the AWS SDKs,
/// boto3, pyarrow and pointreggpt), and no shared credential or config file of the caller's home.
pub const ISOLATED_AWS: [(&str, &str); 3] = [
    ("AWS_EC2_METADATA_DISABLED", "true"),
    ("AWS_SHARED_CREDENTIALS_FILE", "/nonexistent/pointreggpt-tests/aws-credentials"),
    ("AWS_CONFIG_FILE", "/nonexistent/pointreggpt-tests/aws-config"),
];

/// `program` without any `AWS_*` variable the test process inherited (keys, profiles, session tokens,
/// web-identity and container credential settings) and with [`ISOLATED_AWS`]: a test talks only to the
/// servers it starts and never to a cloud or its metadata address. A test adds the variables of its own
/// server after this (`Command::envs`).
pub fn command(program: impl AsRef<std::ffi::OsStr>) -> std::process::Command {
    let mut c = std::process::Command::new(program);
    for (key, _) in std::env::vars_os() {
        if key.to_string_lossy().starts_with("AWS_") {
            c.env_remove(key);
        }
    }
    c.envs(ISOLATED_AWS);
    c
}

/// Removes every `AWS_*` variable from this test process and sets [`ISOLATED_AWS`], for the store
/// clients a test runs in-process (hold `store::ENV` while the environment is changed).
pub fn isolate_aws_env() {
    for (key, _) in std::env::vars_os() {
        if key.to_string_lossy().starts_with("AWS_") {
            std::env::remove_var(key);
        }
    }
    for (k, v) in ISOLATED_AWS {
        std::env::set_var(k, v);
    }
}

/// A small synthetic build config: `scenes` scenes of `frames` frames at `width`×`height` (fx scaled
/// from 585 at 640), every `every`-th frame, `samples` samples per frame.
pub fn synthetic_config(scenes: u32, frames: usize, every: usize, samples: u32, width: u32, height: u32, shard_size: u64) -> String {
    let f = 585.0 * width as f64 / 640.0;
    format!(
        "seed = 11\nsamples_per_frame = {samples}\nshard_size = {shard_size}\n\
         [source]\nkind = \"synthetic\"\nscenes = {scenes}\n\
         [source.synthetic]\nframes = {frames}\n\
         [source.synthetic.intrinsics]\nfx = {f}\nfy = {f}\ncx = {cx}\ncy = {cy}\nwidth = {width}\nheight = {height}\n\
         [select]\nevery = {every}\n",
        cx = width as f64 / 2.0,
        cy = height as f64 / 2.0
    )
}

/// A small synthetic labels config: one scene of `frames` frames at `width`×`height` (fx scaled from 585
/// at 640), windows of 8 frames with stride 8, two samples per window, one window per shard.
pub fn synthetic_labels_config(frames: usize, width: u32, height: u32) -> String {
    let f = 585.0 * width as f64 / 640.0;
    format!(
        "seed = 2\nsamples_per_window = 2\nshard_size = 1\n[source]\nkind = \"synthetic\"\nscenes = 1\n\
         [source.synthetic]\nframes = {frames}\n[source.synthetic.intrinsics]\nfx = {f}\nfy = {f}\ncx = {cx}\ncy = {cy}\nwidth = {width}\nheight = {height}\n\
         [window]\nframes = 8\nstride = 8\n[tsdf]\nvoxel_size_m = 0.02\ntruncation_m = 0.08\n",
        cx = width as f64 / 2.0,
        cy = height as f64 / 2.0
    )
}

/// Each committed pair of `dataset` (a folder or a store URL) by unit index: its content digest.
pub fn digests(dataset: impl AsRef<std::path::Path>) -> std::collections::BTreeMap<u64, String> {
    let ds = pointreggpt::shards::dataset::Dataset::open(dataset).unwrap();
    ds.read_pairs().unwrap().iter().map(|r| (r.unit_index, r.content_digest().to_hex().to_string())).collect()
}

/// A 3DMatch-layout folder of three synthetic frames whose first depth PNG is truncated, and a build
/// config reading it: with `--strict`, a build that starts work stops at that frame, naming it. A
/// command refused "before any work" never reads it, so its error names the store instead.
pub fn strict_trap(dir: &std::path::Path) -> PathBuf {
    use pointreggpt::sources::synthetic::{SyntheticConfig, SyntheticSequence};
    let data = dir.join("frames");
    SyntheticSequence::generate(&SyntheticConfig { frames: 3, ..Default::default() }, 5).unwrap().write_3dmatch(&data).unwrap();
    let png = data.join("frame-000000.depth.png");
    let bytes = std::fs::read(&png).unwrap();
    std::fs::write(&png, &bytes[..bytes.len() / 4]).unwrap();
    let config = dir.join("strict.toml");
    std::fs::write(&config, format!("shard_size = 1\n[source]\nkind = \"directory\"\npath = \"{}\"\n", data.display())).unwrap();
    config
}

/// The wall time of each test of this run: (test name, seconds, whether it failed).
static TIMES: std::sync::Mutex<Vec<(String, f64, bool)>> = std::sync::Mutex::new(Vec::new());

/// How many of the slowest tests the summary after the run names.
const SLOWEST: usize = 25;

/// Times the test that calls it, from this call until the guard drops at the test's end (failed tests
/// too): every test of the suite starts with `let _timing = crate::support::timed();` (checked by
/// `every_test_of_the_suite_is_timed`). A test over 20 s prints a line on the real stderr as it ends; once
/// per run, after cargo's `test result:` line, the binary prints its slowest tests and writes every
/// test's time, slowest first, to `target/tmp/suite-times.tsv` (`POINTREGGPT_TEST_TIMES` moves it).
pub fn timed() -> Timed {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        extern "C" {
            fn atexit(f: extern "C" fn()) -> std::os::raw::c_int;
        }
        // SAFETY: registers a plain function with the C library; it runs once when the process exits.
        unsafe {
            atexit(print_times);
        }
    });
    // libtest names each test's thread after the test.
    let name = std::thread::current().name().unwrap_or("unnamed test").to_string();
    Timed { name, start: std::time::Instant::now() }
}

/// The guard [`timed`] returns.
pub struct Timed {
    name: String,
    start: std::time::Instant,
}

impl Drop for Timed {
    fn drop(&mut self) {
        use std::io::Write;
        let seconds = self.start.elapsed().as_secs_f64();
        let failed = std::thread::panicking();
        if seconds >= 20.0 || failed {
            let _ = writeln!(std::io::stderr(), "[{seconds:6.1} s] {}{}", self.name, if failed { " (failed)" } else { "" });
        }
        TIMES.lock().unwrap_or_else(|e| e.into_inner()).push((self.name.clone(), seconds, failed));
    }
}

extern "C" fn print_times() {
    use std::io::Write;
    let mut times = TIMES.lock().unwrap_or_else(|e| e.into_inner()).clone();
    times.sort_by(|a, b| b.1.total_cmp(&a.1));
    let total: f64 = times.iter().map(|t| t.1).sum();
    let mut text = format!("\nslowest tests of {} ({} timed, {total:.0} s in all, summed over test threads):\n", std::env::args().next().unwrap_or_default(), times.len());
    for (name, seconds, failed) in times.iter().take(SLOWEST) {
        text += &format!("{seconds:8.1} s  {name}{}\n", if *failed { " (failed)" } else { "" });
    }
    let path = std::env::var_os("POINTREGGPT_TEST_TIMES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("suite-times.tsv"));
    let tsv: String = times.iter().map(|(n, s, f)| format!("{s:.2}\t{n}\t{}\n", if *f { "failed" } else { "ok" })).collect();
    match std::fs::write(&path, format!("seconds\ttest\tresult\n{tsv}")) {
        Ok(()) => text += &format!("every test's time: {}\n", path.display()),
        Err(e) => text += &format!("could not write {}: {e}\n", path.display()),
    }
    let _ = writeln!(std::io::stderr(), "{text}");
}

/// The folder of this run's shared fixtures, `target/tmp/suite-<pid>`: removed when the process exits,
/// and folders of earlier runs whose process is gone are removed when it is first made.
fn shared_root() -> &'static std::path::Path {
    static ROOT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    ROOT.get_or_init(|| {
        let base = PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
        for entry in std::fs::read_dir(&base).into_iter().flatten().flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if let Some(pid) = name.strip_prefix("suite-").and_then(|p| p.parse::<u32>().ok()) {
                if !std::path::Path::new(&format!("/proc/{pid}")).exists() {
                    let _ = std::fs::remove_dir_all(entry.path());
                }
            }
        }
        let root = base.join(format!("suite-{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        extern "C" {
            fn atexit(f: extern "C" fn()) -> std::os::raw::c_int;
        }
        extern "C" fn remove() {
            if let Some(root) = ROOT.get() {
                let _ = std::fs::remove_dir_all(root);
            }
        }
        // SAFETY: registers a plain function with the C library; it runs once when the process exits.
        unsafe {
            atexit(remove);
        }
        root
    })
}

/// A fixture shared by the tests of this run: the folder `key` of [`shared_root`], filled once by `make`
/// (the first test to ask makes it, the others wait for it). A fixture is read, never changed, by the
/// tests that share it; a `make` that panics fails the test that ran it, and the next test tries again.
pub fn shared(key: &str, make: impl FnOnce(&std::path::Path)) -> PathBuf {
    type Cell = std::sync::Arc<std::sync::OnceLock<PathBuf>>;
    static MADE: std::sync::Mutex<Vec<(String, Cell)>> = std::sync::Mutex::new(Vec::new());
    let cell: Cell = {
        let mut made = MADE.lock().unwrap_or_else(|e| e.into_inner());
        match made.iter().find(|(k, _)| k == key) {
            Some((_, c)) => c.clone(),
            None => {
                let c = Cell::default();
                made.push((key.to_string(), c.clone()));
                c
            }
        }
    };
    cell.get_or_init(|| {
        let dir = shared_root().join(key);
        let _ = std::fs::remove_dir_all(&dir); // what a panicked `make` left
        std::fs::create_dir_all(&dir).unwrap();
        make(&dir);
        dir
    })
    .clone()
}

/// `pointreggpt synth --frames <frames> --seed <seed>` made once per run: the sequence folder
/// (`synthetic-<seed>`).
pub fn synthetic_sequence(frames: usize, seed: u64) -> PathBuf {
    shared(&format!("synth-{frames}-{seed}"), |dir| {
        let o = bin().args(["synth", "--out", dir.to_str().unwrap(), "--frames", &frames.to_string(), "--seed", &seed.to_string()]).output().unwrap();
        assert!(o.status.success(), "synth: {}", String::from_utf8_lossy(&o.stderr));
    })
    .join(format!("synthetic-{seed}"))
}

/// `pointreggpt fragments <synthetic_sequence(frames, seed)> --single-frames <extra> --quiet` made once per
/// run: the benchmark folder.
pub fn single_frame_bench(frames: usize, seed: u64, extra: &[&str]) -> PathBuf {
    let seq = synthetic_sequence(frames, seed);
    shared(&format!("singles-{frames}-{seed}{}", extra.join("")), |dir| {
        let bench = dir.join("bench");
        let o = bin()
            .args(["fragments", seq.to_str().unwrap(), "--single-frames", "--out", bench.to_str().unwrap(), "--quiet"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "fragments: {}", String::from_utf8_lossy(&o.stderr));
    })
    .join("bench")
}
