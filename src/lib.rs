//! pointreggpt: realistic training pairs for point-cloud registration from single depth maps
//! (PointRegGPT, ECCV 2024).

pub mod cli;
pub mod commands;
pub mod correction;
pub mod error;
pub mod geometry;
pub mod inpainting;
pub mod rng;
pub mod sources;

pub use error::{Error, Result};
