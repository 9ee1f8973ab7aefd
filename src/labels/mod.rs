//! The correction-label pipeline (TSDF data preparation, paper §3.3; never released by the authors).
//!
//! For each window of N consecutive frames: fuse them into a TSDF volume in the reference frame's camera
//! coordinates; take the dense surface cloud `P_d` and its voxel-downsampled sparse copy `P_s`; for each
//! sample draw a target pose with the build's pivot sampler; re-project both into `I_d` and `I_s`; label
//! `M_gt = [|I_s − I_d| < τ_gt]`. Rows go to `labels` shards with the same commit protocol as pairs.

pub mod config;
pub mod label;
pub mod run;
pub mod stages;
pub mod windows;

pub use config::LabelsConfig;
pub use run::{run_labels, LabelsReport};
