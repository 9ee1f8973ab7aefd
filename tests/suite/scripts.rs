//! The scripts no other test runs: the tests' own Python (the project's virtual environment, never the
//! system's `python3`), `scripts/python-env.sh` that makes it (once; again when it broke; without
//! ensurepip through pip's wheel from PyPI; and its errors), and the shell benchmarks `benchmarks/scale.sh`
//! and `benchmarks/row_groups.sh`, run whole on 40 real frames.

use crate::support::{self, python, python_command, real_data};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// Without `PYTHON` (a plain `cargo test`), the peers run in the project's virtual environment, and
/// without that environment the tests stop naming `make test-deps`: never the system's `python3`.
#[test]
fn the_tests_run_python_from_the_projects_virtual_environment() {
    let _timing = crate::support::timed();
    // An environment of our own (CI keeps its own outside the clone, so the checkout's .venv may not exist).
    let dir = tempfile::tempdir().unwrap();
    let venv = dir.path().join("venv");
    std::fs::create_dir_all(venv.join("bin")).unwrap();
    std::fs::write(venv.join("bin/python"), "").unwrap();
    let v = || Some(venv.clone().into_os_string());
    assert_eq!(support::python_for(None, v()), venv.join("bin/python").to_string_lossy(), "PYTHON unset");
    assert_eq!(support::python_for(Some("".into()), v()), venv.join("bin/python").to_string_lossy(), "PYTHON empty");
    assert_eq!(support::python_for(Some("/x/bin/python".into()), v()), "/x/bin/python", "PYTHON wins");
    // Without POINTREGGPT_VENV: the checkout's .venv, or a stop naming it.
    let checkout = Path::new(ROOT).join(".venv/bin/python");
    match std::panic::catch_unwind(|| support::python_for(None, None)) {
        Ok(p) => assert_eq!(p, checkout.to_string_lossy(), "POINTREGGPT_VENV unset"),
        Err(e) => {
            let message = e.downcast_ref::<String>().cloned().unwrap_or_default();
            assert!(!checkout.is_file() && message.contains(&*checkout.to_string_lossy()), "{message}");
        }
    }
    let missing = std::panic::catch_unwind(|| support::python_for(None, Some("/nonexistent/venv".into())));
    let message = missing.expect_err("a missing environment must stop the test run");
    let message = message.downcast_ref::<String>().cloned().unwrap_or_default();
    assert!(message.contains("make test-deps") && message.contains("/nonexistent/venv/bin/python"), "{message}");
    // The interpreter this run uses is a virtual environment's.
    let o = python_command().args(["-c", "import sys; print(sys.prefix != sys.base_prefix, sys.prefix)"]).output().unwrap();
    let (out, err) = text(&o);
    assert!(o.status.success() && out.starts_with("True "), "{} is not a virtual environment's python: {out}{err}", python());
}

/// A fake base interpreter for python-env.sh: the real one, except that `-m venv` without
/// `--without-pip` fails (no ensurepip, as on Debian without python3-venv) and, with `no_pip`, that
/// `-m pip` fails too.
fn fake_base(dir: &Path, real: &str, no_pip: bool) -> PathBuf {
    let path = dir.join(if no_pip { "python-no-pip" } else { "python-no-ensurepip" });
    let pip = if no_pip { "if [[ \"${1:-} ${2:-}\" == \"-m pip\" ]]; then echo 'No module named pip' >&2; exit 1; fi\n" } else { "" };
    std::fs::write(
        &path,
        format!(
            "#!/usr/bin/env bash\nif [[ \"${{1:-}} ${{2:-}}\" == \"-m venv\" && \" $* \" != *\" --without-pip \"* ]]; then echo 'ensurepip is not available' >&2; exit 1; fi\n{pip}exec {real} \"$@\"\n"
        ),
    )
    .unwrap();
    executable(&path);
    path
}

fn executable(path: &Path) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// `scripts/python-env.sh <venv>` with `BASE_PYTHON=base`; a `dpkg` that says python3-venv is installed
/// comes first on the PATH, so the script never runs apt-get here.
fn python_env(venv: &Path, base: &str, fake_bin: &Path) -> Output {
    let path = format!("{}:{}", fake_bin.display(), std::env::var("PATH").unwrap_or_default());
    support::command(Path::new(ROOT).join("scripts/python-env.sh")).arg(venv).env("BASE_PYTHON", base).env("PATH", path).output().unwrap()
}

#[test]
fn python_env_makes_the_environment_once_remakes_a_broken_one_and_bootstraps_pip_without_ensurepip() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let fake_bin = dir.path().join("bin");
    std::fs::create_dir(&fake_bin).unwrap();
    std::fs::write(fake_bin.join("dpkg"), "#!/bin/sh\nexit 0\n").unwrap();
    executable(&fake_bin.join("dpkg"));
    // The base interpreter: the one the project's environment was made from.
    let o = python_command().args(["-c", "import sys, os; print(os.path.join(sys.base_prefix, 'bin', 'python3'))"]).output().unwrap();
    let real = text(&o).0.trim().to_string();
    assert!(Path::new(&real).is_file(), "no base python at {real}");
    let venv_python = |v: &Path| v.join("bin/python").to_string_lossy().into_owned();
    let pip_works = |v: &Path| Command::new(v.join("bin/python")).args(["-m", "pip", "--version"]).output().is_ok_and(|o| o.status.success());

    // Made once: the second run prints the same interpreter and says nothing.
    let venv = dir.path().join("venv");
    let o = python_env(&venv, &real, &fake_bin);
    let (out, err) = text(&o);
    assert!(o.status.success() && out.trim() == venv_python(&venv), "{out}{err}");
    assert!(pip_works(&venv) && err.contains("-m venv"), "{err}");
    let made = std::fs::metadata(venv.join("pyvenv.cfg")).unwrap().modified().unwrap();
    let o = python_env(&venv, &real, &fake_bin);
    let (out, err) = text(&o);
    assert!(o.status.success() && out.trim() == venv_python(&venv) && err.is_empty(), "second run: {out}{err}");
    assert_eq!(std::fs::metadata(venv.join("pyvenv.cfg")).unwrap().modified().unwrap(), made, "a working environment was made again");

    // Broken (its interpreter gone): made again.
    std::fs::remove_file(venv.join("bin/python")).unwrap();
    let o = python_env(&venv, &real, &fake_bin);
    let (out, err) = text(&o);
    assert!(o.status.success() && out.trim() == venv_python(&venv) && pip_works(&venv), "{out}{err}");
    assert!(err.contains("does not work") && err.contains("making it again"), "{err}");

    // No ensurepip: the environment without pip, then pip from PyPI's wheel.
    let bare = dir.path().join("bare");
    let o = python_env(&bare, fake_base(dir.path(), &real, false).to_str().unwrap(), &fake_bin);
    let (out, err) = text(&o);
    assert!(o.status.success() && out.trim() == venv_python(&bare) && pip_works(&bare), "{out}{err}");
    assert!(err.contains("cannot make a venv with pip (no ensurepip)"), "{err}");

    // Neither ensurepip nor pip: an error that says what to install, and nothing left behind.
    let none = dir.path().join("none");
    let o = python_env(&none, fake_base(dir.path(), &real, true).to_str().unwrap(), &fake_bin);
    let (out, err) = text(&o);
    assert!(!o.status.success() && err.contains("apt-get install python3-venv") && out.is_empty(), "{out}{err}");
    assert!(!none.join("bin/python").exists(), "a half-made environment was left");

    // No base interpreter at all.
    let o = python_env(&dir.path().join("x"), "no-such-python3", &fake_bin);
    let (_, err) = text(&o);
    assert!(!o.status.success() && err.contains("no 'no-such-python3' on the PATH"), "{err}");
}

/// A real-data folder holding the first 40 redkitchen frames (links), for the benchmarks below: their
/// arithmetic assumes 400 frames, so SIZE=400 is one sample of each of these 40.
fn forty_redkitchen_frames(dir: &Path) -> Option<PathBuf> {
    let real = real_data()?;
    let from = real.join("7scenes-redkitchen");
    let to = dir.join("realdata/7scenes-redkitchen");
    std::fs::create_dir_all(&to).unwrap();
    for entry in std::fs::read_dir(&from).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let keep = match name.strip_prefix("frame-") {
            Some(rest) => rest[..6].parse::<usize>().unwrap() < 40,
            None => name == "camera-intrinsics.txt",
        };
        if keep {
            std::os::unix::fs::symlink(&path, to.join(&name)).unwrap();
        }
    }
    Some(dir.join("realdata"))
}

/// The benchmark script `script` with `env`, on 40 real frames: its stdout, after asserting it succeeded.
fn run_benchmark(script: &str, realdata: &Path, env: &[(&str, &str)]) -> String {
    let mut c = support::command("bash");
    c.arg(Path::new(ROOT).join("benchmarks").join(script))
        .env("POINTREGGPT_REAL_DATA", realdata)
        .env("POINTREGGPT_BIN", env!("CARGO_BIN_EXE_pointreggpt"))
        .env("PYTHON", python())
        .envs(env.iter().copied());
    let o = c.output().unwrap();
    let (out, err) = text(&o);
    assert!(o.status.success(), "benchmarks/{script} failed:\n{out}\n{err}");
    out
}

/// `benchmarks/scale.sh`, every part, at 40 pairs in shards of 4: each part prints its line, and the
/// checks it makes itself (the resumed dataset, the 8 workers into a folder and into S3) come out equal.
#[test]
fn the_scale_benchmark_runs_every_part() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let Some(realdata) = forty_redkitchen_frames(dir.path()) else { return };
    let out = run_benchmark("scale.sh", &realdata, &[("SIZE", "400"), ("SCALE_SHARD_SIZE", "4")]);
    // 40 pairs in 10 shards: every one of the 8 array workers commits some (a worker left out would show).
    assert!(out.contains("opening and resuming it (10 shards"), "{out}");
    for want in [
        "build: ",
        "resume with nothing to do: ",
        "verify: ",
        "publish: ",
        "delta readers: ",
        "export --format geotransformer: ",
        "loaders: ",
        "8 workers into ",
        "8 workers into s3://bench/array",
        "opening and resuming it (",
    ] {
        assert!(out.contains(want), "no `{want}` line:\n{out}");
    }
    assert!(out.contains(" pairs/s"), "{out}");
    assert_eq!(out.matches("query \"").count(), 3, "{out}");
    assert_eq!(out.matches("the committed rows equal the one-process build's").count(), 2, "{out}");
    assert!(out.contains("the resumed dataset has the uninterrupted one's rows and points") || out.contains("too short to interrupt"), "{out}");
    assert!(!out.contains("DIFFER"), "{out}");
}

/// `benchmarks/row_groups.sh` at two row-group sizes, 40 pairs each: a line per size with every rate.
#[test]
fn the_row_group_benchmark_runs() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let Some(realdata) = forty_redkitchen_frames(dir.path()) else { return };
    let out = run_benchmark("row_groups.sh", &realdata, &[("SIZE", "400"), ("ROWS", "8 16")]);
    for g in ["   8", "  16"] {
        let line = out.lines().find(|l| l.starts_with(&format!("row_group_rows {g}:"))).unwrap_or_else(|| panic!("no line for {g}:\n{out}"));
        for want in ["MB, build", "map in order", "map random", "streaming 0 workers", "2 workers", "DuckDB", "ratio"] {
            assert!(line.contains(want), "{want} missing: {line}");
        }
    }
}
