//! Checks that libtorch is there and says what to run when it is not (`make libtorch`, or
//! LIBTORCH_USE_PYTORCH=1 / LIBTORCH=<folder>), and gives every binary (the CLI, tests, benchmarks) an
//! rpath to libtorch's `lib/`, so nothing has to be exported by hand at run time. LIBTORCH comes from
//! `.cargo/config.toml` or the user's environment.
//!
//! On a first build cargo runs torch-sys's C++ compile before this script (it schedules the crates with
//! more dependents first), so that compile is where a missing libtorch shows first: `.cargo/c++`, the C++
//! compiler `.cargo/config.toml` sets, makes it stop on a fallback `torch/torch.h` holding the same
//! instructions. This script is the check when torch-sys is already built and libtorch went missing since
//! (it reruns when `<LIBTORCH>/build-version` changes or disappears, and when a LIBTORCH* variable changes).
use std::path::{Path, PathBuf};

fn main() {
    for var in ["LIBTORCH", "LIBTORCH_USE_PYTORCH", "LIBTORCH_INCLUDE", "LIBTORCH_LIB"] {
        println!("cargo:rerun-if-env-changed={var}");
    }
    let root = std::env::var_os("LIBTORCH").map(PathBuf::from);
    let folder = |name: &str| std::env::var_os(name).map(PathBuf::from).or_else(|| root.clone());
    // With LIBTORCH_USE_PYTORCH, torch-sys asks the active Python's PyTorch where its headers and libraries are.
    if std::env::var_os("LIBTORCH_USE_PYTORCH").is_none() {
        check(root.as_deref(), folder("LIBTORCH_INCLUDE"), folder("LIBTORCH_LIB"));
    }
    if let Some(lib) = folder("LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.join("lib").display());
    }
}

/// Stops the build when the libtorch torch-sys is about to compile against is missing.
fn check(root: Option<&Path>, include: Option<PathBuf>, lib: Option<PathBuf>) {
    let (Some(root), Some(include), Some(lib)) = (root, include, lib) else {
        if !Path::new("/usr/lib/libtorch.so").exists() {
            fail("LIBTORCH is not set (.cargo/config.toml sets it to third_party/libtorch) and there is no system libtorch");
        }
        return;
    };
    // (Watched only when present: a missing watched file would rerun this script, and rebuild the crate, every time.)
    let version = root.join("build-version");
    if version.is_file() {
        println!("cargo:rerun-if-changed={}", version.display());
    }
    let header = include.join("include/torch/csrc/api/include/torch/torch.h");
    if !header.is_file() {
        fail(&format!("no libtorch at {} (LIBTORCH): {} is missing", root.display(), header.display()));
    }
    if !lib.join("lib").is_dir() {
        fail(&format!("no libtorch at {} (LIBTORCH): the folder {} is missing", root.display(), lib.join("lib").display()));
    }
}

/// Stops the build with `problem` and what to do about it.
fn fail(problem: &str) -> ! {
    eprintln!(
        "error: {problem}.\n\
         pointreggpt needs libtorch 2.13.0. Either\n  \
         - run `make libtorch` in the checkout (assembles a CPU libtorch from PyPI wheels into third_party/libtorch, once), or\n  \
         - set LIBTORCH_USE_PYTORCH=1 to build against the PyTorch 2.13 of the active Python, or\n  \
         - set LIBTORCH=<folder of a libtorch 2.13.0> (with include/ and lib/),\n\
         then run cargo again."
    );
    std::process::exit(1);
}
