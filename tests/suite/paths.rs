//! Paths that work from anywhere and clear first errors, run through the real binary from temporary
//! working directories: a config's relative paths resolve against the config file's folder and `--set`
//! values against the working directory; a build resumes from another working directory or a moved config
//! folder, but not with another checkpoint; the built-in default models work from any folder; and text that
//! looks like a URL but is not one is refused before anything is written.

use crate::support;

use std::path::{Path, PathBuf};
use std::process::Output;
use crate::support::bin;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the binary in the working directory `cwd`.
fn run(cwd: &Path, args: &[&str]) -> Output {
    bin().current_dir(cwd).args(args).output().unwrap()
}

fn ok(o: Output) -> String {
    assert!(o.status.success(), "{}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn failed(o: Output) -> String {
    assert!(!o.status.success(), "succeeded: {}", String::from_utf8_lossy(&o.stdout));
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn dir(p: PathBuf) -> PathBuf {
    std::fs::create_dir_all(&p).unwrap();
    p
}

/// `to` written relative to the folder `from` (both absolute).
fn relative(from: &Path, to: &Path) -> PathBuf {
    let up = from.components().count() - 1;
    let mut p: PathBuf = std::iter::repeat_n("..", up).collect();
    p.push(to.strip_prefix("/").unwrap());
    p
}

/// pipelines/demo.toml made small: 4 units of one scene at working size 64.
const SMALL_DEMO: [&str; 11] = [
    "source.scenes=1",
    "source.synthetic.frames=8",
    "select.every=2",
    "shard_size=2",
    "working.size=64",
    "source.synthetic.intrinsics.width=160",
    "source.synthetic.intrinsics.height=120",
    "source.synthetic.intrinsics.fx=146.25",
    "source.synthetic.intrinsics.fy=146.25",
    "source.synthetic.intrinsics.cx=80",
    "source.synthetic.intrinsics.cy=60",
];

fn build_args<'a>(config: &'a str, out: &'a str, sets: &'a [&'a str]) -> Vec<&'a str> {
    let mut a = vec!["build", config, "--out", out, "--no-progress", "--no-publish"];
    sets.iter().for_each(|s| a.extend(["--set", s]));
    a
}

/// The `(config <12 hex>)` a build prints.
fn config_hash(stdout: &str) -> String {
    stdout.split("(config ").nth(1).and_then(|s| s.split(')').next()).unwrap_or_default().to_string()
}

#[test]
fn the_shipped_demo_config_builds_from_any_folder_and_resumes_from_another() {
    let _timing = crate::support::timed();
    let tmp = tempfile::tempdir().unwrap();
    let (one, deep) = (dir(tmp.path().join("one")), dir(tmp.path().join("a/b/c")));
    let demo = root().join("pipelines/demo.toml");
    let first = ok(run(&one, &build_args(demo.to_str().unwrap(), "ds", &SMALL_DEMO)));
    let ds = one.join("ds");
    assert!(first.contains("4 units in 2 shards") && first.contains(", 2 committed now"), "{first}");
    // The dataset records the checkpoint as the config wrote it, relative to its folder, and its content.
    let recorded = std::fs::read_to_string(ds.join("dataset.toml")).unwrap();
    let model = blake3::hash(&std::fs::read(root().join("models/correction-tiny.safetensors")).unwrap()).to_hex().to_string();
    assert!(recorded.contains("checkpoint = \"../models/correction-tiny.safetensors\""), "{recorded}");
    assert!(recorded.contains(&format!("\"correct.condition.checkpoint\" = \"{model}\"")), "{recorded}");
    assert!(!recorded.contains(root().to_str().unwrap()), "no absolute path in the identity: {recorded}");

    // The config by a relative path from another folder: the same pairs, the same config hash.
    let rel = relative(&deep, &demo);
    assert!(rel.is_relative() && deep.join(&rel).is_file(), "{}", rel.display());
    let second = ok(run(&deep, &build_args(rel.to_str().unwrap(), "ds2", &SMALL_DEMO)));
    assert_eq!(config_hash(&second), config_hash(&first));
    assert_eq!(support::digests(deep.join("ds2")), support::digests(&ds));
    // Resuming the first dataset from there is the same build, not another config.
    let resumed = ok(run(&deep, &build_args(rel.to_str().unwrap(), ds.to_str().unwrap(), &SMALL_DEMO)));
    assert!(resumed.contains("2 shards already committed, 0 committed now"), "{resumed}");
}

/// A config in `folder` naming a sequence folder and a checkpoint beside it, and its sequence (`frames`
/// synthetic frames) and checkpoint (the shipped one).
fn config_folder(folder: &Path, frames: usize) {
    dir(folder.to_path_buf());
    ok(run(folder, &["synth", "--out", "frames", "--frames", &frames.to_string(), "--seed", "3"]));
    std::fs::copy(root().join("models/correction-tiny.safetensors"), folder.join("net.safetensors")).unwrap();
    let config = "seed = 1\nshard_size = 2\n[source]\nkind = \"directory\"\npath = \"frames/synthetic-3\"\n[select]\nevery = 4\n\
        [working]\nsize = 64\n[correct.condition]\nmethod = \"unet\"\ncheckpoint = \"net.safetensors\"\nthreshold = 0.5\n";
    std::fs::write(folder.join("build.toml"), config).unwrap();
}

#[test]
fn relative_paths_in_a_config_resolve_against_its_folder_and_set_values_against_the_working_directory() {
    let _timing = crate::support::timed();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("cfg");
    config_folder(&cfg, 12);
    let (config, run_dir) = (cfg.join("build.toml"), dir(tmp.path().join("run")));
    let config = config.to_str().unwrap();
    // Run from a folder holding neither `frames` nor `net.safetensors`: they are found beside the config.
    let out = ok(run(&run_dir, &build_args(config, "ds", &[])));
    assert!(out.contains("3 units in 2 shards"), "12 frames, every 4th: {out}");
    let recorded = std::fs::read_to_string(run_dir.join("ds/dataset.toml")).unwrap();
    assert!(recorded.contains("path = \"frames/synthetic-3\"") && recorded.contains("checkpoint = \"net.safetensors\""), "{recorded}");
    // --print-config shows where they resolved.
    let printed = ok(run(&run_dir, &["build", config, "--print-config"]));
    assert!(printed.contains(&format!("path = \"{}\"", cfg.join("frames/synthetic-3").display())), "{printed}");

    // A value on the command line is relative to the working directory (`mine` is not beside the config).
    ok(run(&run_dir, &["synth", "--out", "mine", "--frames", "20", "--seed", "4"]));
    let out = ok(run(&run_dir, &build_args(config, "ds-mine", &["source.path=mine/synthetic-4"])));
    assert!(out.contains("5 units in 3 shards"), "20 frames of ./mine, every 4th: {out}");
    let e = failed(run(&cfg, &build_args(config, "ds-none", &["source.path=mine/synthetic-4"])));
    assert!(e.contains(&cfg.join("mine/synthetic-4").display().to_string()), "resolved against the working directory: {e}");

    // The config folder moved elsewhere, run from a third folder: the same dataset resumes.
    let moved = dir(tmp.path().join("moved/away")).join("cfg");
    std::fs::rename(&cfg, &moved).unwrap();
    let moved_config = moved.join("build.toml");
    let ds = run_dir.join("ds");
    let third = dir(tmp.path().join("third"));
    let resumed = ok(run(&third, &build_args(moved_config.to_str().unwrap(), ds.to_str().unwrap(), &[])));
    assert!(resumed.contains("2 shards already committed, 0 committed now"), "{resumed}");
    // Another checkpoint at the same path is another config: refused, naming the checkpoint's hash.
    let net = moved.join("net.safetensors");
    let mut bytes = std::fs::read(&net).unwrap();
    let header = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    bytes[8 + header] ^= 1; // the lowest bit of the first weight
    std::fs::write(&net, bytes).unwrap();
    let e = failed(run(&third, &build_args(moved_config.to_str().unwrap(), ds.to_str().unwrap(), &[])));
    assert!(e.contains("another pipeline config") && e.contains("checkpoint_blake3"), "{e}");
}

#[test]
fn the_built_in_default_checkpoint_is_found_from_any_folder() {
    let _timing = crate::support::timed();
    let tmp = tempfile::tempdir().unwrap();
    let work = dir(tmp.path().join("work"));
    std::fs::write(work.join("labels.toml"), support::synthetic_labels_config(16, 160, 120)).unwrap();
    ok(run(&work, &["labels", "labels.toml", "--out", "labels", "--no-progress"]));
    // `eval correction` without --checkpoint: builtin:models/correction-tiny.safetensors, no models/ here.
    assert!(!work.join("models").exists());
    let out = ok(run(&work, &["eval", "correction", "--labels", "labels", "--out", "eval.csv"]));
    let csv = std::fs::read_to_string(work.join("eval.csv")).unwrap();
    assert!(csv.lines().any(|l| l.starts_with("\"U-Net + DepthAugment\",0.5,")), "a row of the built-in U-Net:\n{csv}\n{out}");
    // A built-in name that does not exist is refused, listing those that do.
    let e = failed(run(&work, &["eval", "correction", "--labels", "labels", "--out", "e.csv", "--checkpoint", "builtin:models/x.safetensors"]));
    assert!(e.contains("builtin:models/correction-tiny.safetensors"), "{e}");
}

#[test]
fn text_that_looks_like_a_url_is_refused_before_anything_is_written() {
    let _timing = crate::support::timed();
    let tmp = tempfile::tempdir().unwrap();
    let cwd = dir(tmp.path().join("empty"));
    let demo = root().join("pipelines/demo.toml");
    let labels = root().join("pipelines/labels-demo.toml");
    let (demo, labels) = (demo.to_str().unwrap(), labels.to_str().unwrap());
    let bad = "s3:/bucket/x";
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["build", demo, "--out", bad], "s3://bucket/x"),
        (vec!["build", demo, "--out", "s3:bucket"], "s3://bucket"),
        (vec!["build", demo, "--out", "s4://bucket/x"], "unknown URL scheme `s4`"),
        (vec!["labels", labels, "--out", "az:/container/x"], "az://container/x"),
        (vec!["query", bad, "select 1"], "s3://bucket/x"),
        (vec!["verify", "gs:/b/x"], "gs://b/x"),
        (vec!["publish", bad], "s3://bucket/x"),
        (vec!["export", bad, "--out", "o"], "s3://bucket/x"),
        (vec!["preview", bad, "--out", "o"], "s3://bucket/x"),
        (vec!["stats", bad, "--out", "o"], "s3://bucket/x"),
        (vec!["train", "descriptor", "--data", bad, "--out", "o"], "s3://bucket/x"),
        (vec!["eval", "correction", "--labels", bad, "--out", "o.csv"], "s3://bucket/x"),
        (vec!["export", "ds", "--out", "s3://bucket/x"], "local files only"),
        (vec!["stats", "ds", "--out", "file:/tmp/x"], "file:///tmp/x"),
    ];
    for (args, says) in cases {
        let e = failed(run(&cwd, &args));
        assert!(e.contains(says), "{args:?}: {e}");
        let left: Vec<_> = std::fs::read_dir(&cwd).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert!(left.is_empty(), "{args:?} wrote {left:?}");
    }
    let e = failed(run(&cwd, &["build", demo, "--out", bad]));
    assert!(e.contains("./s3:/bucket/x") && e.contains("s3://bucket/prefix"), "how to write a local name, the supported forms: {e}");
    // A local folder whose name has a colon, written as a path, is a folder.
    let out = ok(run(&cwd, &build_args(demo, "./s3:x", &SMALL_DEMO)));
    assert!(cwd.join("s3:x/dataset.toml").is_file(), "{out}");
}
