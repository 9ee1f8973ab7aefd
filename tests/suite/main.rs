//! The integration tests: one test binary (issue 51), a module per area, so the crate's dependencies
//! (arrow, parquet, DataFusion, object_store, libtorch) are linked once rather than into 33 binaries, and
//! fixtures built once can be shared by every test of a module (`std::sync::OnceLock`).
//!
//! A new test goes into the module of its area (`tests/suite/<area>.rs`), or a new module listed below;
//! shared helpers live in `support/`. Every test starts with `let _timing = crate::support::timed();`
//! (checked below): the binary prints the slowest tests after its run and writes every test's wall time to
//! `target/tmp/suite-times.tsv`. Run one area with `cargo test --release --test suite <module>::`.

mod support;

mod azure;
mod boost;
mod build;
mod checkpoints;
mod correction;
mod delta;
mod descriptor;
mod device;
mod diffusion;
mod export;
mod faults;
mod fetch_data;
mod geometry;
mod kubernetes;
mod labels;
mod layering;
mod pairs_v1;
mod paths;
mod ply;
mod provenance;
mod python_package;
mod python_streaming;
mod query;
mod readme;
mod real_data;
mod registration;
mod scene;
mod schemas;
mod scripts;
mod shards;
mod slurm;
mod store;
mod synthetic;
mod toolchain;
mod torch_smoke;
mod tsdf;
mod unposed;

/// Every test of the suite records its time: its first statement is the [`support::timed`] guard.
#[test]
fn every_test_of_the_suite_is_timed() {
    let _timing = crate::support::timed();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/suite");
    let mut untimed = Vec::new();
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "rs") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            if line.trim() == "#[test]" {
                count += 1;
                let first = lines.get(i + 2).map(|l| l.trim());
                if first != Some("let _timing = crate::support::timed();") {
                    untimed.push(format!("{}:{}", path.file_name().unwrap().to_string_lossy(), i + 2));
                }
            }
        }
    }
    assert!(count > 100, "only {count} tests found under {}", dir.display());
    assert!(untimed.is_empty(), "tests without `let _timing = crate::support::timed();` as their first line: {untimed:?}");
}
