//! Diffusion inpainting: the exact consistency step, seeded sampling, training lowers the loss, checkpoint
//! and resume round trips, the authors' key layout, the build with `inpaint = "diffusion"`, and
//! `eval inpaint` on real frames.

use crate::support;

use pointreggpt::diffusion::checkpoint::{export_ema, load_denoiser, save, sorted_variables, DiffusionMeta, EMA, FORMAT};
use pointreggpt::nn::space::to_network;
use pointreggpt::training::diffusion::data::{FrameSet, TrainFrame};
use pointreggpt::correction::NoCorrection;
use pointreggpt::training::diffusion::holes::holed_frame;
use pointreggpt::training::diffusion::train::{batch_loss, train_diffusion, DiffusionTrainOptions, Holes, Weighting, LATEST};
use pointreggpt::diffusion::sampler::Resample;
use pointreggpt::diffusion::{ddnm_sample, Problem, SamplerOptions, Schedule};
use pointreggpt::geometry::{DepthMap, Intrinsics};
use pointreggpt::inpainting::{Background, DiffusionInpaintConfig, DiffusionInpainter, InpaintContext, Inpainter, PushPull, Start};
use pointreggpt::nn::checkpoint::write_safetensors;
use pointreggpt::nn::denoiser::{Denoiser, DenoiserConfig};
use pointreggpt::nn::{ModelPath, Preset};
use pointreggpt::pipeline::{run_build, BuildConfig, BuildOptions};
use pointreggpt::rng::Rng;
use pointreggpt::runtime::CancelToken;
use pointreggpt::shards::dataset::Dataset;
use pointreggpt::sources::depth_png::decode_depth_png;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::collections::BTreeMap;
use std::path::Path;
use tch::{nn, Device, Kind, Tensor};

fn tiny(seed: i64) -> (nn::VarStore, Denoiser) {
    tch::manual_seed(seed);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = Denoiser::new(&vs.root(), &DenoiserConfig::from_preset(Preset::Tiny)).unwrap();
    (vs, net)
}

/// An untrained tiny denoiser saved as a checkpoint in `dir` (EMA weights, our metadata).
fn save_untrained(dir: &Path, seed: i64) -> std::path::PathBuf {
    let (vs, _net) = tiny(seed);
    let path = dir.join("denoiser.safetensors");
    let meta = DiffusionMeta { format: FORMAT.into(), net: DenoiserConfig::from_preset(Preset::Tiny), step: 0, info: serde_json::Value::Null };
    save(&path, &meta, &[], &sorted_variables(&vs), &[]).unwrap();
    path
}

/// A random inpainting problem of `w`×`h`: smooth depth in network space, `known_rate` of it known.
fn problem_data(w: usize, h: usize, known_rate: f64, seed: u64) -> (Vec<f32>, Vec<bool>) {
    let mut r = Rng::new(seed);
    let y = (0..w * h).map(|i| to_network(1.0 + (i % w) as f32 * 0.01 + r.uniform() as f32 * 0.05)).collect();
    let known = (0..w * h).map(|_| r.uniform() < known_rate).collect();
    (y, known)
}

const K: [f64; 4] = [30.0, 30.0, 16.0, 12.0];

#[test]
fn known_pixels_are_bit_identical_and_the_seed_fixes_the_rest() {
    let _timing = crate::support::timed();
    let (_vs, net) = tiny(0);
    let s = Schedule::official();
    let (w, h) = (30, 22); // not a multiple of 8: the sampler pads
    let (y1, m1) = problem_data(w, h, 0.6, 1);
    let (y2, m2) = problem_data(w, h, 0.3, 2);
    let opts = SamplerOptions { steps: 4, eta: 1.0, start_step: None, resample: None };
    let both = ddnm_sample(&net, &s, &opts, w, h, &[p(&y1, &m1, 5), p(&y2, &m2, 6)], Device::Cpu);
    for (out, (y, m)) in both.iter().zip([(&y1, &m1), (&y2, &m2)]) {
        assert_eq!(out.len(), w * h);
        for i in 0..w * h {
            if m[i] {
                assert_eq!(out[i].to_bits(), y[i].to_bits(), "known pixel {i}");
            } else {
                assert!((-1.0..=1.0).contains(&out[i]), "clamped x0");
            }
        }
    }
    // The same seed gives the same output, alone or in a batch; another seed another one.
    let alone = ddnm_sample(&net, &s, &opts, w, h, &[p(&y1, &m1, 5)], Device::Cpu);
    let again = ddnm_sample(&net, &s, &opts, w, h, &[p(&y1, &m1, 5)], Device::Cpu);
    assert_eq!(alone, again);
    let max_diff = alone[0].iter().zip(&both[0]).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(max_diff < 1e-4, "batched and alone differ by {max_diff}");
    // Started from a noised initial estimate (not the official sampler): known pixels stay exact.
    let init: Vec<f32> = y1.iter().zip(&m1).map(|(v, k)| if *k { *v } else { to_network(2.0) }).collect();
    let mut from_init = p(&y1, &m1, 5);
    from_init.init = Some(&init);
    let started = ddnm_sample(&net, &s, &SamplerOptions { steps: 3, eta: 1.0, start_step: Some(200), resample: None }, w, h, &[from_init], Device::Cpu);
    assert!((0..w * h).all(|i| !m1[i] || started[0][i].to_bits() == y1[i].to_bits()));
    assert_ne!(started[0], alone[0]);
    // RePaint-style resampling, deterministic η 0 (its re-noising is the only randomness): known pixels
    // exact, the seed fixes the output, and the extra passes change it.
    let det = SamplerOptions { steps: 4, eta: 0.0, start_step: None, resample: None };
    let resampled = SamplerOptions { resample: Some(Resample { jump: 1, repeats: 3 }), ..det };
    let r1 = ddnm_sample(&net, &s, &resampled, w, h, &[p(&y1, &m1, 5)], Device::Cpu);
    let r2 = ddnm_sample(&net, &s, &resampled, w, h, &[p(&y1, &m1, 5)], Device::Cpu);
    assert_eq!(r1, r2);
    assert!((0..w * h).all(|i| !m1[i] || r1[0][i].to_bits() == y1[i].to_bits()));
    let plain = ddnm_sample(&net, &s, &det, w, h, &[p(&y1, &m1, 5)], Device::Cpu);
    assert!((0..w * h).filter(|&i| !m1[i] && r1[0][i] != plain[0][i]).count() > (w * h) / 4);
    let other = ddnm_sample(&net, &s, &opts, w, h, &[p(&y1, &m1, 7)], Device::Cpu);
    let unknown_diff = (0..w * h).filter(|&i| !m1[i] && other[0][i] != alone[0][i]).count();
    assert!(unknown_diff > (w * h) / 4, "another seed changed only {unknown_diff} pixels");
}

fn p<'a>(y: &'a [f32], known: &'a [bool], seed: u64) -> Problem<'a> {
    Problem { y, known, intrinsics: K, seed, init: None }
}

#[test]
fn the_inpainter_keeps_metric_depths_exactly_and_fills_the_holes() {
    let _timing = crate::support::timed();
    let (vs, net) = tiny(3);
    let inpainter = DiffusionInpainter::new(vs, net, SamplerOptions { steps: 3, eta: 1.0, start_step: None, resample: None });
    let (w, h) = (32u32, 24u32);
    let mut r = Rng::new(9);
    let data: Vec<f32> = (0..w * h).map(|_| r.uniform_range(0.6, 4.0) as f32).collect();
    let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.5).collect();
    let d = DepthMap::new(w, h, data.clone()).unwrap();
    let ctx = InpaintContext { intrinsics: Intrinsics::new(30.0, 30.0, 16.0, 12.0, w, h).unwrap(), seed: 4, t_target_from_source: Isometry3::identity() };
    let out = inpainter.inpaint(&d, &known, &ctx);
    for i in 0..(w * h) as usize {
        if known[i] {
            assert_eq!(out.data()[i].to_bits(), data[i].to_bits());
        } else {
            assert!((0.0..=10.0).contains(&out.data()[i]));
        }
    }
    assert_eq!(out, inpainter.inpaint(&d, &known, &ctx), "same seed, same output");
}

/// Frames of 2 synthetic scenes at 64x64 (official intrinsics map), every 10th of 40.
#[test]
fn a_view_gives_the_same_result_whichever_views_share_its_batch() {
    let _timing = crate::support::timed();
    // Batch 4: five views go as [d e a b] + [c, padding]; three as [a b c, padding]; one as [a, padding].
    // Every forward pass has 4 views, so each view's output is bit-identical across groupings.
    let (vs, net) = tiny(5);
    let inpainter = DiffusionInpainter::new(vs, net, SamplerOptions { steps: 3, eta: 1.0, start_step: None, resample: None }).with_batch(4);
    let (w, h) = (64u32, 48u32);
    let k = Intrinsics::new(60.0, 60.0, 32.0, 24.0, w, h).unwrap();
    let views: Vec<(DepthMap, Vec<bool>, InpaintContext)> = (0..5u64)
        .map(|i| {
            let mut r = Rng::new(100 + i);
            let d: Vec<f32> = (0..w * h).map(|_| r.uniform_range(0.6, 4.0) as f32).collect();
            let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.4).collect();
            (DepthMap::new(w, h, d).unwrap(), known, InpaintContext { intrinsics: k, seed: 7 + i, t_target_from_source: Isometry3::identity() })
        })
        .collect();
    let v = |i: usize| (&views[i].0, views[i].1.as_slice(), &views[i].2);
    let (a, b, c, d, e) = (0, 1, 2, 3, 4);
    let three = inpainter.inpaint_batch(&[v(a), v(b), v(c)]);
    let five = inpainter.inpaint_batch(&[v(d), v(e), v(a), v(b), v(c)]);
    let alone = inpainter.inpaint(&views[a].0, &views[a].1, &views[a].2);
    assert_eq!(three.len(), 3);
    assert_eq!(five.len(), 5);
    assert_eq!(three[0], alone);
    assert_eq!(five[2], alone);
    assert_eq!(three[1], five[3]);
    assert_eq!(three[2], five[4]);
    assert_ne!(five[0], five[1], "different views, different fills");
}

fn small_frames() -> FrameSet {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("frames.toml");
    std::fs::write(&cfg, format!("{}[working]\nsize = 64\n", support::synthetic_config(2, 40, 10, 1, 640, 480, 8))).unwrap();
    FrameSet::load(&[cfg], false).unwrap()
}

fn opts(out: &Path, steps: u64) -> DiffusionTrainOptions {
    let mut o = DiffusionTrainOptions::for_preset(Preset::Tiny, out.to_path_buf());
    o.steps = steps;
    o.batch = 4;
    o.crop = Some(32);
    o.checkpoint_every = 2;
    o.ema_after = 1;
    o.ema_every = 1;
    o.seed = 5;
    o
}

/// The loss of `net` on a fixed set of (frame, t, noise) draws.
fn fixed_loss(net: &Denoiser, data: &FrameSet) -> f64 {
    let s = Schedule::official();
    tch::manual_seed(99);
    let n = data.len().min(8);
    let x: Vec<f32> = data.frames[..n].iter().flat_map(|f| f.depth.clone()).collect();
    let x0 = Tensor::from_slice(&x).view([n as i64, 1, data.height as i64, data.width as i64]);
    let k: Vec<f32> = data.frames[..n].iter().flat_map(|f| f.intrinsics.map(|v| v as f32)).collect();
    let k = Tensor::from_slice(&k).view([n as i64, 4]);
    let t: Vec<i64> = (0..n as i64).map(|i| 20 + 110 * i).collect();
    tch::no_grad(|| batch_loss(net, &s, Weighting::MinSnr, &x0, &k, &t, None).double_value(&[]))
}

#[test]
fn training_lowers_the_loss_and_resume_equals_an_uninterrupted_run() {
    let _timing = crate::support::timed();
    let data = small_frames();
    assert_eq!((data.width, data.height, data.len()), (64, 64, 8));
    assert!(data.frames.iter().all(|f| f.depth.iter().any(|v| *v > -1.0)));

    // 60 steps lower the loss on fixed draws (the initial network is the training run's: same seed).
    let dir = tempfile::tempdir().unwrap();
    let mut o = opts(dir.path(), 60);
    o.checkpoint_every = 60;
    train_diffusion(&data, &o, |_| {}).unwrap();
    let (_v0, init) = {
        tch::manual_seed(o.seed as i64);
        let vs = nn::VarStore::new(Device::Cpu);
        let net = Denoiser::new(&vs.root(), &DenoiserConfig::from_preset(Preset::Tiny)).unwrap();
        (vs, net)
    };
    let (_v1, trained, meta) = load_denoiser(&dir.path().join(LATEST), Device::Cpu).unwrap();
    assert_eq!(meta.step, 60);
    // load_denoiser takes the EMA; compare the online weights too.
    let before = fixed_loss(&init, &data);
    let after = fixed_loss(&trained, &data);
    assert!(after < 0.7 * before, "loss {before} -> {after}");

    // 4 steps in one go, or 2 then a resume to 4: the same model, EMA and Adam state, bit for bit.
    let a = tempfile::tempdir().unwrap();
    train_diffusion(&data, &opts(a.path(), 4), |_| {}).unwrap();
    let b = tempfile::tempdir().unwrap();
    train_diffusion(&data, &opts(b.path(), 2), |_| {}).unwrap();
    let mut resumed = opts(b.path(), 4);
    resumed.resume = true;
    let report = train_diffusion(&data, &resumed, |_| {}).unwrap();
    assert_eq!(report.first_step, 3);
    // Sample previews at every checkpoint: 4 samples of the 32x32 crop side by side.
    let png = std::fs::read(a.path().join("preview-0000004.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(u32::from_be_bytes(png[16..20].try_into().unwrap()), 4 * 34 - 2, "IHDR width");
    let ta = Tensor::read_safetensors(a.path().join(LATEST)).unwrap();
    let tb: BTreeMap<String, Tensor> = Tensor::read_safetensors(b.path().join(LATEST)).unwrap().into_iter().collect();
    assert!(ta.len() > 100 && ta.len() == tb.len());
    assert!(ta.iter().any(|(k, _)| k.starts_with("opt.v.")) && ta.iter().any(|(k, _)| k.starts_with(EMA)));
    for (k, t) in &ta {
        assert!(t.equal(&tb[k]), "tensor {k} differs after resume");
    }
    // And a different seed trains to a different model (the comparison above can fail).
    let c = tempfile::tempdir().unwrap();
    let mut other = opts(c.path(), 4);
    other.seed = 6;
    train_diffusion(&data, &other, |_| {}).unwrap();
    let tc: BTreeMap<String, Tensor> = Tensor::read_safetensors(c.path().join(LATEST)).unwrap().into_iter().collect();
    assert!(ta.iter().any(|(k, t)| !t.equal(&tc[k])));

    // The exported EMA file loads to the same network as the full checkpoint.
    let small = a.path().join("ema.safetensors");
    export_ema(&a.path().join(LATEST), &small).unwrap();
    let (_va, full, _) = load_denoiser(&a.path().join(LATEST), Device::Cpu).unwrap();
    let (_vb, exported, _) = load_denoiser(&small, Device::Cpu).unwrap();
    let x = Tensor::randn([1, 1, 32, 32], (Kind::Float, Device::Cpu));
    let t = Tensor::from_slice(&[100i64]);
    let k = Tensor::from_slice(&[30f32, 30.0, 16.0, 16.0]).view([1, 4]);
    let (ya, yb) = tch::no_grad(|| (full.forward(&x, &t, &k), exported.forward(&x, &t, &k)));
    assert!(ya.equal(&yb));
    assert!(std::fs::metadata(&small).unwrap().len() * 3 < std::fs::metadata(a.path().join(LATEST)).unwrap().len() + 1);

    // Fine-tuning (--init) starts from the file's sampling (EMA) weights at step 0 with a fresh optimiser:
    // one step with no EMA update leaves the EMA exactly the source's, while the online network moved.
    let f = tempfile::tempdir().unwrap();
    let mut tune = opts(f.path(), 1);
    tune.init = Some(small.clone());
    tune.ema_every = 1000;
    tune.max_t = Some(30);
    let report = train_diffusion(&data, &tune, |_| {}).unwrap();
    assert_eq!(report.first_step, 1);
    let tf: BTreeMap<String, Tensor> = Tensor::read_safetensors(f.path().join(LATEST)).unwrap().into_iter().collect();
    let source_ema: Vec<&(String, Tensor)> = ta.iter().filter(|(k, _)| k.starts_with(EMA)).collect();
    assert!(source_ema.len() > 50);
    for (k, t) in &source_ema {
        assert!(t.equal(&tf[k]), "EMA tensor {k} is not the initial checkpoint's");
        let online = k.replacen(EMA, "model.", 1);
        assert!(tf.contains_key(&online));
    }
    assert!(source_ema.iter().any(|(k, t)| !t.equal(&tf[&k.replacen(EMA, "model.", 1)])), "the online network trained");
    // A network trained only below step 30 samples only from a push-pull start below it.
    let tuned = ModelPath::new(f.path().join(LATEST).to_str().unwrap());
    let config = |start, start_step| DiffusionInpaintConfig { checkpoint: tuned, steps: 3, eta: 1.0, start, start_step, batch: 1, resample: None };
    assert!(config(Start::PushPull, 29).validate("inpaint").is_ok());
    for (start, step) in [(Start::PushPull, 30), (Start::Noise, 10)] {
        let err = config(start, step).validate("inpaint").unwrap_err().to_string();
        assert!(err.contains("below 30"), "{err}");
    }
    assert!(DiffusionInpaintConfig { checkpoint: ModelPath::new(small.to_str().unwrap()), ..config(Start::Noise, 500) }.validate("inpaint").is_ok());
    // A file that is not a denoiser checkpoint, or a time-step cap outside 1..=1000, is refused.
    let mut bad = opts(tempfile::tempdir().unwrap().path(), 1);
    bad.init = Some(f.path().join("loss.jsonl"));
    assert!(train_diffusion(&data, &bad, |_| {}).is_err());
    let mut bad = opts(tempfile::tempdir().unwrap().path(), 1);
    bad.max_t = Some(0);
    assert!(train_diffusion(&data, &bad, |_| {}).unwrap_err().to_string().contains("--max-t"));
}

/// The hole-aware loss of `net` on fixed draws: each frame holed by a fixed sideways round trip, the holes
/// filled by `fill`.
fn fixed_hole_loss(net: &Denoiser, data: &FrameSet, hole_weight: f32, fill: &dyn Inpainter) -> f64 {
    let s = Schedule::official();
    tch::manual_seed(99);
    let n = data.len().min(8);
    let (w, h) = (data.width, data.height);
    let motion = Isometry3::from_parts(Translation3::new(-0.3, 0.05, 0.0), UnitQuaternion::from_euler_angles(0.02, 0.08, 0.0));
    let (mut x, mut start, mut weight) = (Vec::new(), Vec::new(), Vec::new());
    for f in &data.frames[..n] {
        let holed = holed_frame(&f.depth, w, h, f.intrinsics, &motion, &NoCorrection, fill);
        x.extend_from_slice(&f.depth);
        start.extend_from_slice(&holed.start);
        weight.extend(f.depth.iter().zip(&holed.holes).map(|(v, hole)| if *v <= -1.0 { 0.0 } else if *hole { hole_weight } else { 1.0 }));
    }
    let image = |v: &[f32]| Tensor::from_slice(v).view([n as i64, 1, h as i64, w as i64]);
    let k: Vec<f32> = data.frames[..n].iter().flat_map(|f| f.intrinsics.map(|v| v as f32)).collect();
    let k = Tensor::from_slice(&k).view([n as i64, 4]);
    let t: Vec<i64> = (0..n as i64).map(|i| 2 * i).collect();
    let holes = Holes { start: image(&start), weight: image(&weight) };
    tch::no_grad(|| batch_loss(net, &s, Weighting::MinSnr, &image(&x), &k, &t, Some(&holes)).double_value(&[]))
}

#[test]
fn hole_aware_training_lowers_the_loss_on_push_pull_filled_round_trip_holes() {
    let _timing = crate::support::timed();
    let data = small_frames();
    let (_v, net) = tiny(5);
    // With the clean frame as the start and unit weights on every pixel, the hole-aware loss is the plain
    // one (same noise); a push-pull start with holes is a different input.
    let s = Schedule::official();
    let n = 4;
    let x: Vec<f32> = data.frames[..n].iter().flat_map(|f| f.depth.clone()).collect();
    let x0 = Tensor::from_slice(&x).view([n as i64, 1, 64, 64]);
    let k = Tensor::from_slice(&[30f32, 30.0, 32.0, 32.0].repeat(n)).view([n as i64, 4]);
    let t = [0i64, 3, 7, 15];
    let loss = |holes: Option<&Holes>| {
        tch::manual_seed(3);
        tch::no_grad(|| batch_loss(&net, &s, Weighting::MinSnr, &x0, &k, &t, holes).double_value(&[]))
    };
    let same = Holes { start: x0.copy(), weight: x0.ones_like() };
    assert!((loss(None) - loss(Some(&same))).abs() < 1e-6 * loss(None), "{} vs {}", loss(None), loss(Some(&same)));
    let before = fixed_hole_loss(&net, &data, 4.0, &PushPull);
    assert!((before - fixed_hole_loss(&net, &data, 1.0, &PushPull)).abs() > 1e-6, "hole weight has no effect");

    // 60 hole-aware steps (from the same initial network) lower the hole-aware loss on fixed draws.
    let dir = tempfile::tempdir().unwrap();
    let mut o = opts(dir.path(), 60);
    o.checkpoint_every = 60;
    o.holes = true;
    o.max_t = Some(20);
    train_diffusion(&data, &o, |_| {}).unwrap();
    let (_v1, trained, meta) = load_denoiser(&dir.path().join(LATEST), Device::Cpu).unwrap();
    assert_eq!(meta.info["options"]["holes"], true);
    let after = fixed_hole_loss(&trained, &data, 4.0, &PushPull);
    assert!(after < 0.7 * before, "hole-aware loss {before} -> {after}");

    // The same from the background fill's start (`--holes-start background`), on background-filled holes.
    let before = fixed_hole_loss(&net, &data, 4.0, &Background);
    let dir = tempfile::tempdir().unwrap();
    o.out = dir.path().to_path_buf();
    o.hole_start = Start::Background;
    train_diffusion(&data, &o, |_| {}).unwrap();
    let (_v2, trained, meta) = load_denoiser(&dir.path().join(LATEST), Device::Cpu).unwrap();
    assert_eq!(meta.info["options"]["hole_start"], "background");
    let after = fixed_hole_loss(&trained, &data, 4.0, &Background);
    assert!(after < 0.7 * before, "hole-aware loss from the background start {before} -> {after}");

    let mut bad = opts(tempfile::tempdir().unwrap().path(), 1);
    bad.hole_weight = 0.0;
    assert!(train_diffusion(&data, &bad, |_| {}).unwrap_err().to_string().contains("--hole-weight"));
    let mut bad = opts(tempfile::tempdir().unwrap().path(), 1);
    (bad.holes, bad.hole_start) = (true, Start::Noise);
    assert!(train_diffusion(&data, &bad, |_| {}).unwrap_err().to_string().contains("--holes-start"));
}

#[test]
fn the_authors_key_layout_loads_without_metadata() {
    let _timing = crate::support::timed();
    // A paper-size network saved as a converted official checkpoint: EMA weights under
    // `ema.ema_model.model.`, the online ones under `model.model.`, the GaussianDiffusion buffers beside them.
    let (vs, net) = {
        tch::manual_seed(2);
        let vs = nn::VarStore::new(Device::Cpu);
        let mut cfg = DenoiserConfig::from_preset(Preset::Paper);
        // Keep the test quick: paper topology at a quarter of the width, raw intrinsics as the authors.
        cfg.unet.dim = 16;
        cfg.unet.cond_dim = Some(128);
        cfg.intrinsics_scale = 1.0;
        cfg.preset = None;
        let net = Denoiser::new(&vs.root(), &cfg).unwrap();
        (vs, net)
    };
    let mut tensors: Vec<(String, Tensor)> = Vec::new();
    for (k, t) in sorted_variables(&vs) {
        tensors.push((format!("ema.ema_model.model.{k}"), t.shallow_clone()));
        tensors.push((format!("model.model.{k}"), t.zeros_like()));
    }
    tensors.push(("model.betas".into(), Tensor::zeros([1000], (Kind::Float, Device::Cpu))));
    tensors.push(("ema.step".into(), Tensor::zeros([1], (Kind::Float, Device::Cpu))));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("official.safetensors");
    write_safetensors(&path, &tensors, &BTreeMap::new()).unwrap();
    let (_v, loaded, meta) = load_denoiser(&path, Device::Cpu).unwrap();
    assert_eq!(meta.net, net.config, "inferred config");
    let x = Tensor::randn([1, 1, 16, 16], (Kind::Float, Device::Cpu));
    let t = Tensor::from_slice(&[500i64]);
    let k = Tensor::from_slice(&[311.7f32, 312.0, 128.5, 128.0]).view([1, 4]);
    let (a, b) = tch::no_grad(|| (net.forward(&x, &t, &k), loaded.forward(&x, &t, &k)));
    assert!(a.equal(&b), "EMA weights were not the ones loaded");
    // A correction checkpoint is refused with the reason.
    std::fs::write(&path, b"not a file").unwrap();
    assert!(load_denoiser(&path, Device::Cpu).unwrap_err().to_string().contains("official.safetensors"));
}

#[test]
fn a_build_with_the_diffusion_fill_keeps_the_condition_and_is_deterministic_across_threads() {
    let _timing = crate::support::timed();
    // An untrained tiny denoiser: the test is about wiring, exactness and determinism, not realism. With
    // `batch = 3` the inpaint stage takes the units waiting for it together, so batches form differently
    // on 1 and 2 threads; the pairs must not change.
    let dir = tempfile::tempdir().unwrap();
    let ckpt = save_untrained(dir.path(), 7);
    for batch in [1, 3] {
        let text = format!(
            "{}[working]\nsize = 64\n[inpaint]\nmethod = \"diffusion\"\ncheckpoint = {:?}\nsteps = 3\nbatch = {batch}\n[correct.output]\nmethod = \"none\"\n[output]\ndepth_maps = true\n",
            support::synthetic_config(1, 30, 10, 2, 640, 480, 4),
            ckpt.display().to_string()
        );
        build_twice_and_compare(&BuildConfig::from_toml(&text, "test").unwrap(), &dir.path().join(format!("b{batch}")));
    }
}

fn build_twice_and_compare(config: &BuildConfig, dir: &Path) {
    let mut digests = Vec::new();
    for threads in [1, 2] {
        let out = dir.join(format!("ds{threads}"));
        let opts = BuildOptions { strict: true, ..BuildOptions::into_folder(out.clone()) };
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| run_build(config, &opts, &CancelToken::new())).unwrap();
        let rows = Dataset::open(&out).unwrap().read_pairs().unwrap();
        assert_eq!(rows.len(), 6, "3 frames x 2 samples");
        let mut checked = 0;
        for r in &rows {
            assert!(r.stages.contains("\"diffusion\"") && r.stages.contains("model_blake3"), "{}", r.stages);
            if r.condition_depth_png.is_empty() {
                continue;
            }
            let c = decode_depth_png(&r.condition_depth_png, Path::new("condition")).unwrap();
            let t = decode_depth_png(&r.target_depth_png, Path::new("target")).unwrap();
            let known = c.data.iter().filter(|v| **v > 0).count();
            assert!(known > 100);
            for (cv, tv) in c.data.iter().zip(&t.data) {
                if *cv > 0 {
                    assert_eq!(cv, tv, "a known pixel changed");
                }
            }
            // The model filled (some of) the rest.
            assert!(t.data.iter().filter(|v| **v > 0).count() > known);
            checked += 1;
        }
        assert!(checked >= 4);
        digests.push(rows.iter().map(|r| (r.unit_index, r.content_digest().to_hex().to_string())).collect::<BTreeMap<_, _>>());
    }
    assert_eq!(digests[0], digests[1], "1 and 2 threads give different pairs");
}

/// Runs `eval inpaint` from the repository root on redkitchen, source frames 300, 320, ... 10 frames
/// before their targets, with `args` added; returns the CSV it wrote to `csv`.
fn eval_inpaint(real: &Path, csv: &Path, args: &[&str]) -> String {
    let o = support::bin()
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["eval", "inpaint"])
        .arg(real.join("7scenes-redkitchen"))
        .args(["--gap", "10", "--first", "300", "--every", "20", "--quiet"])
        .args(args)
        .arg("--out")
        .arg(csv)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read_to_string(csv).unwrap()
}

#[test]
fn eval_inpaint_on_real_frames_scores_every_method() {
    let _timing = crate::support::timed();
    let Some(real) = support::real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let ckpt = save_untrained(dir.path(), 8);
    let text = eval_inpaint(&real, &dir.path().join("eval.csv"), &["--max-views", "3", "--steps", "2", "--diffusion", ckpt.to_str().unwrap()]);
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let rows: Vec<Vec<String>> = text.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect();
    // 3 corrections x (none, push-pull, nearest, background, IP-Basic, diffusion from noise, from push-pull,
    // from background).
    assert_eq!(rows.len(), 24, "{text}");
    let get = |c: &str, f: &str, col: &str| -> f64 {
        let i = header.iter().position(|h| *h == col).unwrap_or_else(|| panic!("no column {col}"));
        rows.iter().find(|r| r[0] == c && r[1].starts_with(f)).unwrap_or_else(|| panic!("{c}/{f}"))[i].parse().unwrap()
    };
    for c in ["none", "min_pool", "unet@0.99"] {
        assert_eq!(get(c, "none", "views"), 3.0);
        // No fill covers nothing; the classical fills and diffusion fill nearly every unknown pixel the sensor saw.
        assert_eq!(get(c, "none", "fill_coverage"), 0.0);
        for f in ["push_pull", "nearest", "background"] {
            assert!(get(c, f, "fill_coverage") > 0.9, "{c}/{f}: {text}");
        }
        assert!(get(c, "diffusion", "fill_coverage") > 0.5, "{text}");
        // IP-Basic fills less than every hole (its dilations reach 15 px beyond the first fills), but more
        // than none.
        assert!(get(c, "ip_basic", "fill_coverage") > 0.3 && get(c, "ip_basic", "fill_coverage") <= get(c, "push_pull", "fill_coverage"), "{text}");
        // The kept pixels and the holes do not depend on the fill.
        assert_eq!(get(c, "none", "kept_per_map"), get(c, "diffusion", "kept_per_map"));
        assert_eq!(get(c, "none", "unknown_share"), get(c, "background", "unknown_share"));
    }
    // Re-projection 10 frames apart with the stored poses: kept depths mostly right.
    for c in ["none", "min_pool"] {
        assert!(get(c, "none", "kept_abs_rel") < 0.05, "{text}");
    }
    // Corrections drop pixels, and the penetrations among them; the holes grow.
    assert!(get("min_pool", "none", "kept_per_map") < get("none", "none", "kept_per_map"));
    assert!(get("min_pool", "none", "wrong_kept_per_map") <= get("none", "none", "wrong_kept_per_map"));
    assert!(get("min_pool", "none", "unknown_share") > get("none", "none", "unknown_share"));
}

#[test]
fn eval_inpaint_scores_a_build_config_and_dumps_the_views_it_scored() {
    let _timing = crate::support::timed();
    let Some(real) = support::real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let config = "pipelines/paper-3dmatch-classical.toml";
    let args = ["--max-views", "2", "--pipeline", config, "--dump-views", views.to_str().unwrap()];
    let text = eval_inpaint(&real, &dir.path().join("eval.csv"), &args);
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = text.lines().skip(1).map(|l| l.split(',').collect()).collect();
    // One row: the config's condition correction (min-pool) and its fill, named by the file.
    assert_eq!(rows.len(), 1, "{text}");
    assert_eq!((rows[0][0], rows[0][1]), ("min_pool", "paper-3dmatch-classical"));
    let col = |name: &str| rows[0][header.iter().position(|h| *h == name).unwrap()].parse::<f64>().unwrap();
    assert!(col("fill_coverage") > 0.9);
    // The dumped masks are the views scored: their unknown share is the CSV's.
    let folder = views.join("paper-3dmatch-classical").join("min_pool");
    let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(folder.join("views.json")).unwrap()).unwrap();
    assert_eq!(meta["views"].as_array().unwrap().len(), 2);
    let (mut unknown, mut pixels) = (0usize, 0usize);
    for i in 0..2 {
        let (w, h) = (meta["views"][i]["width"].as_u64().unwrap() as usize, meta["views"][i]["height"].as_u64().unwrap() as usize);
        let mask = std::fs::read(folder.join(format!("{i:03}_known.npy"))).unwrap();
        let header_len = u16::from_le_bytes([mask[8], mask[9]]) as usize;
        assert_eq!(mask.len(), 10 + header_len + w * h);
        unknown += mask[10 + header_len..].iter().filter(|b| **b == 0).count();
        pixels += w * h;
        for name in ["condition", "captured"] {
            assert_eq!(std::fs::metadata(folder.join(format!("{i:03}_{name}.npy"))).unwrap().len() as usize, 10 + 118 + 4 * w * h);
        }
        // The fill's output is dumped too: the condition's known pixels bit for bit, the holes filled.
        let f32s = |name: &str| -> Vec<f32> {
            let bytes = std::fs::read(folder.join(format!("{i:03}_{name}.npy"))).unwrap();
            let start = 10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
            bytes[start..].chunks(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
        };
        let (condition, fill) = (f32s("condition"), f32s("fill_paper-3dmatch-classical"));
        assert_eq!(fill.len(), w * h);
        let known = &mask[10 + header_len..];
        for j in 0..w * h {
            if known[j] == 1 {
                assert_eq!(fill[j].to_bits(), condition[j].to_bits(), "view {i} pixel {j}");
            }
        }
        assert!(fill.iter().filter(|z| **z > 0.0).count() > known.iter().filter(|k| **k == 1).count());
    }
    assert!((unknown as f64 / pixels as f64 - col("unknown_share")).abs() < 1e-6, "{text}");
}

/// Filled-pixel (AbsRel, RMSE, delta < 1.25) of one `eval inpaint` row.
#[derive(Clone, Copy, Debug)]
struct Fill {
    abs_rel: f64,
    rmse: f64,
    delta: f64,
}

/// `eval inpaint` on 4 held-out redkitchen views with a checkpoint started from the push-pull fill at
/// `start_step`, `steps` deterministic steps: `(correction, fill) -> scores`, fill "push_pull", "background"
/// or "diffusion" (the push-pull-started row; the pure-noise and background-started rows are left out).
fn fill_scores(real: &Path, checkpoint: &str, steps: usize, start_step: usize, dir: &Path) -> BTreeMap<(String, String), Fill> {
    let csv = dir.join(format!("{}-{steps}-{start_step}.csv", checkpoint.replace('/', "_")));
    let (steps, start) = (steps.to_string(), start_step.to_string());
    let args = ["--max-views", "4", "--steps", &steps, "--start-step", &start, "--eta", "0", "--diffusion", checkpoint];
    let text = eval_inpaint(real, &csv, &args);
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}: {header:?}"));
    let (abs_rel, rmse, delta) = (col("fill_abs_rel"), col("fill_rmse_m"), col("fill_delta_1_25"));
    text.lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| ["push_pull", "background"].contains(&r[1]) || r[1].contains("/pp"))
        .map(|r| {
            let fill = if r[1].contains("/pp") { "diffusion" } else { r[1] };
            let f = Fill { abs_rel: r[abs_rel].parse().unwrap(), rmse: r[rmse].parse().unwrap(), delta: r[delta].parse().unwrap() };
            ((r[0].to_string(), fill.to_string()), f)
        })
        .collect()
}

#[test]
fn the_shipped_fill_model_beats_push_pull_on_unseen_real_views_and_the_earlier_models_do_not() {
    let _timing = crate::support::timed();
    let Some(real) = support::real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let at = |m: &BTreeMap<(String, String), Fill>, c: &str, f: &str| m[&(c.to_string(), f.to_string())];
    let holes = fill_scores(&real, "models/diffusion-tiny-holes.safetensors", 1, 0, dir.path());
    let refine = fill_scores(&real, "models/diffusion-tiny-refine.safetensors", 1, 0, dir.path());
    let all_steps = fill_scores(&real, "models/diffusion-tiny.safetensors", 5, 5, dir.path());
    // docs/lab/2026-12-01-diffusion-fills-on-real-views.md has the 18-view table. These 4 views measured, holes vs push-pull AbsRel / delta:
    // no correction 0.0900 / 88.4 % vs 0.0952 / 87.8 %, min-pool 0.0847 / 89.5 % vs 0.0912 / 88.2 %,
    // U-Net 0.0519 vs 0.0507; RMSE with min-pool 0.274 vs 0.270 here (level on the 18 views), without
    // correction 0.282 vs 0.267.
    for c in ["none", "min_pool"] {
        let (pp, d) = (at(&holes, c, "push_pull"), at(&holes, c, "diffusion"));
        assert!(d.abs_rel < 0.97 * pp.abs_rel, "{c}: AbsRel {} vs push-pull {}", d.abs_rel, pp.abs_rel);
        assert!(d.delta > pp.delta, "{c}: delta {} vs push-pull {}", d.delta, pp.delta);
    }
    let (pp, d) = (at(&holes, "min_pool", "push_pull"), at(&holes, "min_pool", "diffusion"));
    assert!(d.rmse < 1.03 * pp.rmse, "min_pool: RMSE {} vs push-pull {}", d.rmse, pp.rmse);
    let (pp, d) = (at(&holes, "unet@0.99", "push_pull"), at(&holes, "unet@0.99", "diffusion"));
    assert!(d.abs_rel < 1.05 * pp.abs_rel, "unet: AbsRel {} vs push-pull {}", d.abs_rel, pp.abs_rel);
    // The shipped default fill (background) beats push-pull and the hole-aware refiner on AbsRel, RMSE and
    // delta without correction and with min-pool (docs/lab/2026-12-03-fills-against-peers.md has the 30-view tables).
    for c in ["none", "min_pool"] {
        let (bg, pp, d) = (at(&holes, c, "background"), at(&holes, c, "push_pull"), at(&holes, c, "diffusion"));
        for other in [pp, d] {
            assert!(bg.abs_rel < 0.9 * other.abs_rel && bg.rmse < other.rmse && bg.delta > other.delta, "{c}: {bg:?} vs {other:?}");
        }
    }
    // The refine model (no holes in training) does not beat push-pull's AbsRel, nor the holes model's.
    for c in ["none", "min_pool", "unet@0.99"] {
        let (pp, r) = (at(&refine, c, "push_pull"), at(&refine, c, "diffusion"));
        assert!(r.abs_rel > pp.abs_rel && r.abs_rel > at(&holes, c, "diffusion").abs_rel, "{c}: refine {r:?}");
    }
    // The all-steps model, 5 steps from step 5: more than twice the holes model's AbsRel.
    assert!(at(&all_steps, "unet@0.99", "diffusion").abs_rel > 2.0 * at(&holes, "unet@0.99", "diffusion").abs_rel);
}

#[test]
fn frames_load_from_a_sequence_folder_in_network_space() {
    let _timing = crate::support::timed();
    let Some(real) = support::real_data() else { return };
    let set = FrameSet::load(&[real.join("sun3d-studyroom-5frames")], false).unwrap();
    assert_eq!((set.len(), set.width, set.height), (5, 256, 256));
    let f: &TrainFrame = &set.frames[0];
    assert!(f.depth.iter().all(|v| (-1.0..=1.0).contains(v)));
    assert!(f.depth.iter().filter(|v| **v > -1.0).count() > 256 * 128);
    // Official intrinsics map: principal point (128.5, 128).
    assert_eq!((f.intrinsics[2], f.intrinsics[3]), (128.5, 128.0));
}

#[test]
fn a_torchscript_denoiser_samples_like_the_native_one() {
    let _timing = crate::support::timed();
    // Trace the native network into TorchScript at the padded size the inpainter will use (32x32), save it,
    // and load it through the build's config: same output as the native inpainter, known pixels exact.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("denoiser.pt");
    let (mut vs, net) = tiny(11);
    vs.freeze(); // traced weights become constants: they must not require gradients
    {
        let inputs = [
            Tensor::randn([1, 1, 32, 32], (Kind::Float, Device::Cpu)),
            Tensor::from_slice(&[10i64]),
            Tensor::from_slice(&[30f32, 30.0, 16.0, 12.0]).view([1, 4]),
        ];
        let mut trace = |x: &[Tensor]| vec![net.forward(&x[0], &x[1], &x[2])];
        let module = tch::CModule::create_by_tracing("Denoiser", "forward", &inputs, &mut trace).unwrap();
        module.save(&path).unwrap();
    }
    let sampler = SamplerOptions { steps: 3, eta: 1.0, start_step: None, resample: None };
    let native = DiffusionInpainter::new(vs, net, sampler);
    let config = DiffusionInpaintConfig { checkpoint: ModelPath::new(path.to_str().unwrap()), steps: 3, eta: 1.0, start: Start::Noise, start_step: 500, batch: 1, resample: None };
    config.validate("inpaint").unwrap();
    let scripted = DiffusionInpainter::load(&config, Device::Cpu).unwrap();
    let (w, h) = (32u32, 24u32);
    let mut r = Rng::new(12);
    let data: Vec<f32> = (0..w * h).map(|_| r.uniform_range(0.6, 4.0) as f32).collect();
    let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.5).collect();
    let d = DepthMap::new(w, h, data.clone()).unwrap();
    let ctx = InpaintContext { intrinsics: Intrinsics::new(30.0, 30.0, 16.0, 12.0, w, h).unwrap(), seed: 4, t_target_from_source: Isometry3::identity() };
    // The native network pads 24 rows to 24 (multiple of 8), TorchScript to 32: compare the TorchScript
    // output with a native run on the same 32x32 padding instead.
    let d32 = DepthMap::new(w, 32, data.iter().copied().chain(std::iter::repeat(0.0).take((w * 8) as usize)).collect()).unwrap();
    let known32: Vec<bool> = known.iter().copied().chain(std::iter::repeat(false).take((w * 8) as usize)).collect();
    let ctx32 = InpaintContext { intrinsics: Intrinsics::new(30.0, 30.0, 16.0, 12.0, w, 32).unwrap(), seed: 4, t_target_from_source: Isometry3::identity() };
    let a = native.inpaint(&d32, &known32, &ctx32);
    let b = scripted.inpaint(&d, &known, &ctx);
    for i in 0..(w * h) as usize {
        if known[i] {
            assert_eq!(b.data()[i].to_bits(), data[i].to_bits());
        }
        assert!((a.data()[i] - b.data()[i]).abs() < 1e-4, "pixel {i}: {} vs {}", a.data()[i], b.data()[i]);
    }
    // A file that is neither safetensors nor TorchScript is refused with its name.
    std::fs::write(&path, b"PK\x03\x04 broken").unwrap();
    let err = DiffusionInpaintConfig { checkpoint: ModelPath::new(path.to_str().unwrap()), steps: 3, eta: 1.0, start: Start::Noise, start_step: 500, batch: 1, resample: None }.validate("inpaint").unwrap_err();
    assert!(err.to_string().contains("denoiser.pt"), "{err}");
}

/// A shipped pipeline config, loaded as `build` loads it (its relative model paths resolve against its
/// folder, so the test needs no change of the process-wide working directory).
fn shipped_pipeline(name: &str) -> pointreggpt::Result<BuildConfig> {
    // Its checkpoint paths resolve against its folder, wherever the test runs.
    pointreggpt::pipeline::load::load_toml(&Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines").join(name), &[])
}

#[test]
fn the_shipped_pipelines_validate_and_the_paper_one_names_its_missing_models() {
    let _timing = crate::support::timed();
    for name in ["demo.toml", "paper-3dmatch-classical.toml", "paper-3dmatch-nofill.toml", "paper-3dmatch-scene.toml"] {
        shipped_pipeline(name).and_then(|c| c.validate()).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let err = shipped_pipeline("paper-3dmatch.toml").and_then(|c| c.validate()).unwrap_err().to_string();
    assert!(err.contains("models/correction-paper.safetensors") || err.contains("models/diffusion-paper.safetensors"), "{err}");
}

/// An x0 predictor that records the time step of every call and predicts its input.
struct CountingModel(std::sync::Arc<std::sync::Mutex<Vec<i64>>>);

impl pointreggpt::diffusion::X0Model for CountingModel {
    fn predict_x0(&self, x: &Tensor, t: &Tensor, _intrinsics: &Tensor) -> Tensor {
        self.0.lock().unwrap().push(t.int64_value(&[0]));
        x.shallow_clone()
    }
    fn size_multiple(&self) -> usize {
        1
    }
}

#[test]
fn a_push_pull_start_runs_exactly_the_configured_steps_and_refuses_more_than_it_can() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let checkpoint = ModelPath::new(save_untrained(dir.path(), 2).to_str().unwrap());
    let config = |steps| DiffusionInpaintConfig { checkpoint, steps, eta: 1.0, start: Start::PushPull, start_step: 4, batch: 1, resample: None };
    // From step 4 the chain has 5 steps left (4, 3, 2, 1, 0): 6 is refused, naming the key and both values.
    let err = config(6).validate("inpaint").unwrap_err().to_string();
    for part in ["`inpaint`", "steps = 6", "start_step = 4", "at most start_step + 1 = 5"] {
        assert!(err.contains(part), "{part:?} missing from: {err}");
    }
    // `eval inpaint` refuses the same combination of its flags before reading anything.
    let o = support::bin()
        .args(["eval", "inpaint", "/nonexistent", "--steps", "30", "--start-step", "20", "--out"])
        .arg(dir.path().join("x.csv"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && stderr.contains("--steps") && stderr.contains("--start-step + 1 = 21"), "{stderr}");
    // Every valid count runs exactly that many model calls, at distinct steps from 4 down.
    let (w, h) = (16u32, 12u32);
    let mut r = Rng::new(5);
    let d = DepthMap::new(w, h, (0..w * h).map(|_| r.uniform_range(0.6, 4.0) as f32).collect()).unwrap();
    let known: Vec<bool> = (0..w * h).map(|_| r.uniform() < 0.5).collect();
    let ctx = InpaintContext { intrinsics: Intrinsics::new(15.0, 15.0, 8.0, 6.0, w, h).unwrap(), seed: 1, t_target_from_source: Isometry3::identity() };
    for (steps, want) in [(1, vec![4]), (3, vec![4, 2, 0]), (5, vec![4, 3, 2, 1, 0])] {
        config(steps).validate("inpaint").unwrap_or_else(|e| panic!("{steps} steps: {e}"));
        let calls = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let model = Box::new(CountingModel(calls.clone()));
        DiffusionInpainter::from_model(model, config(steps).sampler(), Device::Cpu).inpaint(&d, &known, &ctx);
        assert_eq!(*calls.lock().unwrap(), want, "{steps} steps");
    }
}
