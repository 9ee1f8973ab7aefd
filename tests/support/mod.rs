//! Shared fixtures for the integration tests.
#![allow(dead_code)]

pub mod azure;
pub mod store;

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

/// The `pointreggpt` binary built for these tests.
pub fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_pointreggpt"))
}

/// The Python interpreter the tests run peers with (`PYTHON`, default `python3`).
pub fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
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
