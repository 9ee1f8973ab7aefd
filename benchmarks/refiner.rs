//! `cargo bench --bench refiner`: what more capacity would cost the one-step diffusion refiner (issue 17:
//! "report dim 8 / 16 / 32 with their ms per view"; the fill's budget is 100 ms per 256² view on 2 cores).
//!
//! The refiner is the product's own path, `DiffusionInpainter` with `start = "background"`, one DDIM
//! step from step 0, η 0 (the setting `docs/lab/2026-12-03-fills-against-peers.md` measured): the
//! background fill, one forward of the denoiser, the range–null-space step. Its cost does not depend on
//! the weights, so each width is an untrained denoiser of the tiny preset's shape (levels 1, 2, 4, 8, no
//! attention) at dim 8 (the tiny preset itself), 16 and 32. The view has the holes of a camera move: a synthetic room's exact depth at
//! frame 0 z-buffered into the camera of frame 40 at 256×256. Each refiner is timed one view at a time
//! and as two concurrent workers with their own refiner (how a build on 2 cores runs it), views one at a
//! time or 4 per forward pass (`[inpaint] batch = 4`); the background fill alone (the shipped default)
//! beside them.

use nalgebra::Isometry3;
use pointreggpt::geometry::{backproject, project_zbuffer, DepthMap, DepthRange, Intrinsics};
use pointreggpt::inpainting::{Background, DiffusionInpainter, InpaintContext, Inpainter, Start};
use pointreggpt::diffusion::SamplerOptions;
use pointreggpt::nn::denoiser::{Denoiser, DenoiserConfig};
use pointreggpt::nn::unet::parameter_count;
use pointreggpt::nn::Preset;
use pointreggpt::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use std::time::Instant;
use tch::{nn, Device};

#[path = "common/mod.rs"]
mod common;
use common::{cpu_model, load_average};

/// Median wall time in ms of `f` over `REPS` runs after `WARMUP` runs.
fn median_ms<T>(f: impl FnMut() -> T) -> f64 {
    common::median_ms(WARMUP, REPS, f).0
}

const SIZE: u32 = 256;
const WIDTHS: [i64; 3] = [8, 16, 32];
const WARMUP: usize = 2;
const REPS: usize = 9;
/// The budget for a fill, ms per 256² view on 2 cores.
const BUDGET_MS: f64 = 100.0;
const SCENE_SEED: u64 = 3;
const TARGET_FRAME: usize = 40;

fn main() {
    let load = load_average();
    tch::manual_seed(7);
    let (depth, known, ctx) = view();
    let unknown = known.iter().filter(|k| !**k).count() as f64 / known.len() as f64;

    let fill_ms = median_ms(|| Background.inpaint(&depth, &known, &ctx));
    println!("machine: {}, {} cores, load average {load} at start", cpu_model(), std::thread::available_parallelism().map_or(0, |n| n.get()));
    println!(
        "view: {SIZE}x{SIZE}, synthetic room (seed {SCENE_SEED}) frame 0 re-projected into frame {TARGET_FRAME}, {:.1} % unknown; \
         median of {REPS} after {WARMUP} warm-ups; untrained weights (the cost does not depend on them)",
        100.0 * unknown
    );
    println!();
    println!("{:<46} {:>9} {:>12} {:>12} {:>14} {:>8}", "fill", "params", "1 worker", "2 workers", "2 workers b4", "budget");
    println!("{}", "-".repeat(106));
    println!("{:<46} {:>9} {:>12.1} {:>12} {:>14} {:>8}", "background (the shipped default)", "-", fill_ms, "-", "-", verdict(fill_ms));
    for dim in WIDTHS {
        // A refiner pads a short batch to its batch size, and a build gives each worker its own.
        let refiner = |(vs, net): (nn::VarStore, Denoiser), batch: usize| {
            let sampler = SamplerOptions { steps: 1, eta: 0.0, start_step: Some(0), resample: None };
            DiffusionInpainter::new(vs, net, sampler).with_start(Start::Background).with_batch(batch)
        };
        let first = denoiser(dim);
        let params = parameter_count(&first.0);
        let single = refiner(first, 1);
        let one = median_ms(|| single.inpaint(&depth, &known, &ctx));
        let two = two_workers(&[refiner(denoiser(dim), 1), refiner(denoiser(dim), 1)], 1, &depth, &known, &ctx);
        let two_b4 = two_workers(&[refiner(denoiser(dim), 4), refiner(denoiser(dim), 4)], 4, &depth, &known, &ctx);
        let name = format!("background + 1-step refiner, dim {dim}{}", if dim == 8 { " (tiny)" } else { "" });
        println!("{:<46} {:>9} {:>12.1} {:>12.1} {:>14.1} {:>8}", name, params, one, two, two_b4, verdict(two.min(two_b4)));
    }
    println!();
    println!(
        "ms per view. 1 worker: one view at a time (latency; the inpainter runs one libtorch thread). 2 workers: two \
         concurrent workers with their own refiner, as a build on 2 cores runs them (wall time / views), views one at \
         a time or 4 per forward pass ([inpaint] batch = 4). budget: the issue's {BUDGET_MS:.0} ms per 256² view on \
         2 cores, judged on the better 2-worker figure."
    );
}

/// Wall ms per view of `refiners.len()` concurrent workers, each filling `REPS` groups of `batch` views
/// with its own refiner (after `WARMUP` groups).
fn two_workers(refiners: &[DiffusionInpainter], batch: usize, depth: &DepthMap, known: &[bool], ctx: &InpaintContext) -> f64 {
    let group: Vec<(&DepthMap, &[bool], &InpaintContext)> = (0..batch).map(|_| (depth, known, ctx)).collect();
    let barrier = std::sync::Barrier::new(refiners.len() + 1);
    std::thread::scope(|s| {
        for r in refiners {
            let (group, barrier) = (&group, &barrier);
            s.spawn(move || {
                for _ in 0..WARMUP {
                    std::hint::black_box(r.inpaint_batch(group));
                }
                barrier.wait();
                for _ in 0..REPS {
                    std::hint::black_box(r.inpaint_batch(group));
                }
            });
        }
        barrier.wait();
        let start = Instant::now();
        // The scope joins every worker before it returns.
        start
    })
    .elapsed()
    .as_secs_f64()
        * 1e3
        / (refiners.len() * REPS * batch) as f64
}

fn verdict(ms: f64) -> &'static str {
    if ms <= BUDGET_MS { "within" } else { "over" }
}

/// A depth map with the holes of a camera move: frame 0's exact depth z-buffered into frame 40.
fn view() -> (DepthMap, Vec<bool>, InpaintContext) {
    let n = SIZE as f64;
    // The 7-Scenes field of view (585 px at 640 wide) at the working resolution.
    let k = Intrinsics::new(585.0 * n / 640.0, 585.0 * n / 480.0, n / 2.0, n / 2.0, SIZE, SIZE).expect("intrinsics");
    let config = SyntheticConfig { intrinsics: k, frames: TARGET_FRAME + 1, ..SyntheticConfig::default() };
    let seq = SyntheticSequence::generate(&config, SCENE_SEED).unwrap_or_else(|e| panic!("synthetic scene: {e}"));
    let source = seq.true_depth(0);
    let t: Isometry3<f64> = seq.poses[TARGET_FRAME].inverse() * seq.poses[0];
    let points = backproject(&source, &k, DepthRange { near: 0.1, far: 10.0 });
    let proj = project_zbuffer(&points, &t, &k, false);
    let ctx = InpaintContext { intrinsics: k, seed: 0, t_target_from_source: t };
    (proj.depth, proj.known, ctx)
}

/// An untrained denoiser of the tiny preset's shape at width `dim`.
fn denoiser(dim: i64) -> (nn::VarStore, Denoiser) {
    let mut config = DenoiserConfig::from_preset(Preset::Tiny);
    if dim != config.unet.dim {
        config.preset = None;
        config.unet.dim = dim;
        config.unet.cond_dim = Some(8 * dim);
    }
    let vs = nn::VarStore::new(Device::Cpu);
    let net = Denoiser::new(&vs.root(), &config).unwrap_or_else(|e| panic!("denoiser dim {dim}: {e}"));
    (vs, net)
}
