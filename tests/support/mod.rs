//! Shared fixtures for the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The real-data folder from `POINTREGGPT_REAL_DATA` (`make test` and `.ci/run` set it to
/// `../shared/realdata`). A test that needs it fails when it is missing, so a run without the data
/// cannot pass silently; `POINTREGGPT_SKIP_REAL_DATA=1` is the explicit opt-out for a machine that
/// has no copy (the test then returns `None` after a note).
pub fn real_data() -> Option<PathBuf> {
    match std::env::var_os("POINTREGGPT_REAL_DATA").filter(|v| !v.is_empty()) {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            assert!(dir.is_dir(), "POINTREGGPT_REAL_DATA={} is not a folder", dir.display());
            Some(dir)
        }
        None if std::env::var_os("POINTREGGPT_SKIP_REAL_DATA").is_some() && std::env::var_os("CI").is_none() => {
            eprintln!("note: POINTREGGPT_SKIP_REAL_DATA is set; skipping a real-data test");
            None
        }
        None => panic!(
            "POINTREGGPT_REAL_DATA is not set: point it at ../shared/realdata (make test does this when the folder exists), \
             or set POINTREGGPT_SKIP_REAL_DATA=1 to skip the real-data tests on a machine without the data"
        ),
    }
}
