//! Sample previews during training: a strip of unconditional samples (nothing known), colour-mapped, so
//! a training run can be looked at while it goes.

use crate::diffusion::model::X0Model;
use crate::diffusion::sampler::{ddnm_sample, Problem, SamplerOptions};
use crate::diffusion::schedule::Schedule;
use crate::nn::space::from_network;
use crate::error::Result;
use crate::preview::canvas::Canvas;
use crate::preview::colormap::turbo;
use std::path::Path;
use tch::Device;

/// Samples per preview.
pub const SAMPLES: usize = 4;
/// DDIM steps of a preview sample.
pub const STEPS: usize = 20;
/// Depth range of the colour map, metres (black: no depth).
const RANGE_M: (f32, f32) = (0.5, 5.0);

/// Writes `SAMPLES` unconditional `size`×`size` samples side by side (2 px apart) to `path` as PNG.
pub fn write_preview(model: &dyn X0Model, schedule: &Schedule, size: usize, intrinsics: [f64; 4], seed: u64, path: &Path, device: Device) -> Result<()> {
    let y = vec![-1f32; size * size];
    let known = vec![false; size * size];
    let problems: Vec<Problem<'_>> =
        (0..SAMPLES as u64).map(|i| Problem { y: &y, known: &known, intrinsics, seed: seed ^ (i + 1), init: None }).collect();
    let opts = SamplerOptions { steps: STEPS, eta: 1.0, start_step: None, resample: None };
    let samples = ddnm_sample(model, schedule, &opts, size, size, &problems, device);
    let mut canvas = Canvas::new((SAMPLES * (size + 2) - 2) as u32, size as u32, [0, 0, 0]);
    for (i, s) in samples.iter().enumerate() {
        for (p, v) in s.iter().enumerate() {
            let z = from_network(*v);
            if z > 0.0 {
                let c = turbo((z - RANGE_M.0) / (RANGE_M.1 - RANGE_M.0));
                canvas.set((i * (size + 2) + p % size) as i64, (p / size) as i64, c);
            }
        }
    }
    canvas.write_png(path)
}
