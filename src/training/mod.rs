//! Developing the networks: training data, training loops, and the evaluations that choose between
//! checkpoints and classical methods (`pointreggpt train …`, `pointreggpt eval …`).
//!
//! This sits above everything the build uses: it reads label shards and frame catalogs, runs the
//! inference modules ([`crate::nn`], [`crate::diffusion`], [`crate::correction`], [`crate::inpainting`])
//! and is imported by none of them.

pub mod boost;
pub mod correction;
pub mod descriptor;
pub mod diffusion;
pub mod eval_inpaint;
pub mod fill_metrics;
pub mod optim;
