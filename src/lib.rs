//! pointreggpt: realistic training pairs for point-cloud registration from single depth maps
//! (PointRegGPT, ECCV 2024).

pub mod atomic;
pub mod cli;
pub mod commands;
pub mod config_paths;
pub mod correction;
pub mod diffusion;
pub mod error;
pub mod export;
pub mod geometry;
pub mod inpainting;
pub mod labels;
pub mod nn;
pub mod pipeline;
pub mod ply;
pub mod query;
pub mod registration;
pub mod preview;
pub mod rng;
pub mod runtime;
pub mod scene;
pub mod shards;
pub mod sources;
pub mod stages;
pub mod training;
pub mod tsdf;

pub use error::{Error, Result};
