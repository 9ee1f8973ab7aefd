//! Gives every binary (the CLI, tests, benchmarks) an rpath to libtorch's `lib/`, so nothing has to be
//! exported by hand at run time. LIBTORCH comes from `.cargo/config.toml` or the user's environment.
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    println!("cargo:rerun-if-env-changed=LIBTORCH_USE_PYTORCH");
    if let Ok(root) = std::env::var("LIBTORCH") {
        let lib = PathBuf::from(root).join("lib");
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }
}
