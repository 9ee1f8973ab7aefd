//! The build pipeline: its top-level configuration and the assembly of the stages into a run over a
//! dataset folder.

pub mod build;
pub mod config;
pub mod load;
pub mod overrides;

pub use build::{run_build, BuildOptions, BuildReport};
pub use config::BuildConfig;
