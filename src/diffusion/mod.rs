//! Diffusion inpainting (paper §3.2, reference §5): the noise schedule, the DDIM sampler with the exact
//! range–null-space step, denoiser checkpoints, training data and the training loop. The network itself
//! is [`crate::nn::denoiser`] (the U-Net skeleton shared with the correction network); the build's
//! inpainter is [`crate::inpainting::DiffusionInpainter`].

pub mod checkpoint;
pub mod data;
pub mod evaluate;
pub mod holes;
pub mod model;
pub mod preview;
pub mod sampler;
pub mod schedule;
pub mod train;

pub use model::{load_model, X0Model};
pub use sampler::{ddnm_sample, Problem, SamplerOptions};
pub use schedule::Schedule;
