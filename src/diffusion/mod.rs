//! Diffusion sampling (paper §3.2, reference §5): the noise schedule, the DDIM sampler with the exact
//! range–null-space step, the denoiser behind the sampler ([`model`]) and denoiser checkpoints. This is
//! what inference needs; training data, hole-aware fine-tuning and the training loop live in
//! [`crate::training::diffusion`]. The network itself is [`crate::nn::denoiser`]; the build's inpainter is
//! [`crate::inpainting::DiffusionInpainter`].

pub mod checkpoint;
pub mod model;
pub mod sampler;
pub mod schedule;

pub use model::{load_model, X0Model};
pub use sampler::{ddnm_sample, Problem, SamplerOptions};
pub use schedule::Schedule;
