//! The `rust-version` that Cargo.toml states is the real minimum: no dependency in the lock file asks for a
//! newer compiler (read from `cargo metadata`, the versions cargo itself enforces), and it is not set below
//! what they need, as it once was (1.80 while DataFusion 55 needs 1.94).

use std::process::Command;

fn version(v: &str) -> (u64, u64, u64) {
    let mut it = v.split('.').map(|x| x.parse::<u64>().unwrap_or(0));
    (it.next().unwrap_or(0), it.next().unwrap_or(0), it.next().unwrap_or(0))
}

#[test]
fn rust_version_is_the_highest_any_dependency_needs() {
    let _timing = crate::support::timed();
    let host = String::from_utf8(Command::new(env!("CARGO")).args(["-vV"]).output().unwrap().stdout).unwrap();
    let host = host.lines().find_map(|l| l.strip_prefix("host: ")).unwrap_or("x86_64-unknown-linux-gnu").to_string();
    let o = Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--filter-platform", &host, "--manifest-path", concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml")])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let meta: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let used: std::collections::HashSet<&str> =
        meta["resolve"]["nodes"].as_array().unwrap().iter().map(|n| n["id"].as_str().unwrap()).collect();
    let mut ours = None;
    let mut needed = ((0, 0, 0), String::new());
    for p in meta["packages"].as_array().unwrap().iter().filter(|p| used.contains(p["id"].as_str().unwrap())) {
        let Some(v) = p["rust_version"].as_str() else { continue };
        if p["name"] == "pointreggpt" {
            ours = Some(version(v));
        } else if version(v) > needed.0 {
            needed = (version(v), format!("{} {}", p["name"].as_str().unwrap(), p["version"].as_str().unwrap()));
        }
    }
    let ours = ours.expect("Cargo.toml states a rust-version");
    assert_eq!(ours, needed.0, "Cargo.toml's rust-version {ours:?}; the dependencies need {:?} ({})", needed.0, needed.1);
    // The compiler building this test meets it.
    let rustc = String::from_utf8(Command::new("rustc").arg("--version").output().unwrap().stdout).unwrap();
    let have = version(rustc.split_whitespace().nth(1).unwrap());
    assert!(have >= ours, "{rustc} is older than the stated minimum");
}
