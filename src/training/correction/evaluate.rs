//! Evaluation of keep masks on held-out labels: handcrafted filters and U-Net checkpoints, at τ_m 0.5 and
//! 0.99, over the pixels that have input depth; a printed table and CSV.

use crate::nn::correction::{keep_probabilities, CorrectionNet};
use super::data::LabelSet;
use super::metrics::{Confusion, MaskMetrics};
use crate::correction::{Corrector, MedianFilter, MinPoolFilter};
use crate::error::{Error, Result};
use crate::geometry::DepthMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use tch::Device;

/// The keep thresholds τ_m reported for networks (the GIF demo's 0.5 and the generator's 0.99).
pub const THRESHOLDS: [f32; 2] = [0.5, 0.99];

/// Confusions of a network's keep probabilities at each of `thresholds`.
pub fn evaluate_net(
    net: &CorrectionNet,
    device: Device,
    set: &LabelSet,
    batch: usize,
    thresholds: &[f32],
) -> Vec<Confusion> {
    let mut out = vec![Confusion::default(); thresholds.len()];
    for chunk in set.examples.chunks(batch.max(1) * 4) {
        let inputs: Vec<Vec<f32>> = chunk.iter().map(|e| e.input()).collect();
        let refs: Vec<&[f32]> = inputs.iter().map(Vec::as_slice).collect();
        let probs = keep_probabilities(net, device, set.width, set.height, &refs, batch);
        for ((e, input), p) in chunk.iter().zip(&inputs).zip(&probs) {
            for (c, &t) in out.iter_mut().zip(thresholds) {
                let pred: Vec<bool> = p.iter().zip(input).map(|(p, x)| *x == 0.0 || *p > t).collect();
                c.add(|i| input[i] > 0.0, &e.sparse, &e.dense, &e.keep, &pred);
            }
        }
    }
    out
}

/// Confusion of any corrector (its keep mask is thresholdless).
pub fn evaluate_corrector(corrector: &dyn Corrector, set: &LabelSet) -> Result<Confusion> {
    let mut c = Confusion::default();
    for e in &set.examples {
        let input = e.input();
        let metres: Vec<f32> = input.iter().map(|x| x * crate::nn::space::DEPTH_SCALE_M).collect();
        let depth = DepthMap::new(set.width as u32, set.height as u32, metres)?;
        let keep = corrector.keep_mask(&depth);
        c.add(|i| input[i] > 0.0, &e.sparse, &e.dense, &e.keep, &keep);
    }
    Ok(c)
}

/// Confusion of a `scene` correction on `set` (`rule`, `fallback` where the scene saw nothing): each
/// example's scene is made of the frames of its sequence (found in `sequences` by name) around its
/// reference frame ([`crate::scene::window_frames`] of the reference's block, the whole sequence as span),
/// with its label window and `exclude` frames on each side held out (every frame of the window made the
/// label), ray-cast at the example's target camera. One fusion per label window. Also returns the share
/// of input pixels the scene saw.
pub fn evaluate_scene(
    set: &LabelSet,
    sequences: &[crate::sources::Sequence],
    config: &crate::scene::SceneConfig,
    rule: crate::correction::SceneRule,
    fallback: &dyn Corrector,
    exclude: usize,
) -> Result<(Confusion, f64)> {
    use crate::geometry::{pose_from_rows, Intrinsics};
    use crate::scene::{block_of, fuse_scene, scene_keep_mask, window_frames, HeldOut, Scene};
    let mut c = Confusion::default();
    let (mut seen, mut with_depth) = (0u64, 0u64);
    let mut fused: Option<(String, Scene)> = None;
    for e in &set.examples {
        let w = &e.window;
        let seq = sequences.iter().find(|s| s.name == e.scene).ok_or_else(|| Error::config("--scene-sequence", format!("no sequence named {} for label {}", e.scene, e.key)))?;
        let position = |key: &str| seq.frames.iter().position(|f| f.key == key).ok_or_else(|| Error::config("--scene-sequence", format!("{}: no frame {key} (label {})", seq.name, e.key)));
        let (first, last, reference) = (position(&w.first_frame)?, position(&w.last_frame)?, position(&w.reference_frame)?);
        let window_key = format!("{}/{first}-{last}", seq.name);
        if fused.as_ref().is_none_or(|(k, _)| *k != window_key) {
            let held_out = HeldOut { position: (first + last) / 2, radius: (last - first).div_ceil(2) + exclude };
            let frames = window_frames(config, block_of(reference, config), (0, seq.frames.len() - 1), |p| seq.frames[p].has_pose(), &[held_out]);
            fused = Some((window_key, fuse_scene(&frames, |p| seq.frames[p].load(), &config.tsdf)?));
        }
        let scene = &fused.as_ref().expect("fused above").1;
        let t_world_from_reference = seq.frames[reference].load()?.t_world_from_camera.ok_or_else(|| Error::input(&seq.frames[reference].depth_path, "frame has no camera pose"))?;
        let t = pose_from_rows(&w.t_target_from_reference).map_err(|m| Error::input(&e.key, m))?;
        let [fx, fy, cx, cy] = w.intrinsics;
        let k = Intrinsics::new(fx, fy, cx, cy, set.width as u32, set.height as u32)?;
        let ray = scene.depth_at(&k, &(t_world_from_reference * t.inverse()))?;
        let input = e.input();
        let metres: Vec<f32> = input.iter().map(|x| x * crate::nn::space::DEPTH_SCALE_M).collect();
        let depth = DepthMap::new(set.width as u32, set.height as u32, metres)?;
        let keep = scene_keep_mask(&depth, &ray, rule, &fallback.keep_mask(&depth));
        for i in 0..input.len() {
            if input[i] > 0.0 {
                with_depth += 1;
                seen += (ray.data()[i] > 0.0) as u64;
            }
        }
        c.add(|i| input[i] > 0.0, &e.sparse, &e.dense, &e.keep, &keep);
    }
    Ok((c, seen as f64 / with_depth.max(1) as f64))
}

/// One line of the evaluation table.
#[derive(Clone, Debug)]
pub struct EvalRow {
    pub method: String,
    /// None for thresholdless (handcrafted) methods.
    pub tau_m: Option<f32>,
    pub metrics: MaskMetrics,
}

/// The handcrafted baselines of the table: the official min-pool filter and a 3×3 median filter, both
/// at 0.0375 m.
pub fn handcrafted_rows(set: &LabelSet) -> Result<Vec<EvalRow>> {
    let filters: [(&str, Box<dyn Corrector>); 2] = [
        ("min-pool 3x3 (0.0375 m)", Box::new(MinPoolFilter { threshold: 0.0375 })),
        ("median 3x3 (0.0375 m)", Box::new(MedianFilter { window: 3, threshold: 0.0375 })),
    ];
    filters
        .iter()
        .map(|(name, f)| {
            Ok(EvalRow {
                method: name.to_string(),
                tau_m: None,
                metrics: evaluate_corrector(f.as_ref(), set)?.metrics(),
            })
        })
        .collect()
}

/// Rows of a checkpoint at each τ_m of `thresholds`.
pub fn checkpoint_rows(
    name: &str,
    path: &Path,
    set: &LabelSet,
    device: Device,
    batch: usize,
    thresholds: &[f32],
) -> Result<Vec<EvalRow>> {
    let (_vs, net, _) = crate::nn::checkpoint::load_correction(path, device)?;
    let confusions = evaluate_net(&net, device, set, batch, thresholds);
    Ok(thresholds
        .iter()
        .zip(confusions)
        .map(|(&t, c)| EvalRow { method: name.to_string(), tau_m: Some(t), metrics: c.metrics() })
        .collect())
}

/// The whole table: handcrafted filters, then each `(name, checkpoint)`.
pub fn evaluate_all(
    set: &LabelSet,
    checkpoints: &[(String, PathBuf)],
    device: Device,
    batch: usize,
    thresholds: &[f32],
) -> Result<Vec<EvalRow>> {
    if set.is_empty() {
        return Err(Error::InvalidArgument("the evaluation label set has no `ok` rows".into()));
    }
    let mut rows = handcrafted_rows(set)?;
    for (name, path) in checkpoints {
        rows.extend(checkpoint_rows(name, path, set, device, batch, thresholds)?);
    }
    Ok(rows)
}

/// A fixed-width text table of the rows.
pub fn format_table(rows: &[EvalRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<34} {:>6} {:>7} {:>9} {:>10} {:>10} {:>10}",
        "method", "tau_m", "mIoU", "accuracy", "FP/map", "FN/map", "SAE/map m"
    );
    for r in rows {
        let m = &r.metrics;
        let tau = r.tau_m.map_or("-".to_string(), |t| format!("{t}"));
        let _ = writeln!(
            s,
            "{:<34} {:>6} {:>7.2} {:>9.2} {:>10.1} {:>10.1} {:>10.1}",
            r.method,
            tau,
            100.0 * m.miou,
            100.0 * m.accuracy,
            m.fp_per_map,
            m.fn_per_map,
            m.sae_per_map
        );
    }
    s
}

/// CSV of the rows (percentages as fractions in [0, 1]; empty `tau_m` for thresholdless methods).
pub fn to_csv(rows: &[EvalRow]) -> String {
    let mut s = String::from(
        "method,tau_m,miou,iou_keep,iou_drop,pixel_accuracy,fp_per_map,fn_per_map,sae_per_map_m,maps,pixels\n",
    );
    for r in rows {
        let m = &r.metrics;
        let tau = r.tau_m.map_or(String::new(), |t| format!("{t}"));
        let _ = writeln!(
            s,
            "\"{}\",{},{:.6},{:.6},{:.6},{:.6},{:.3},{:.3},{:.3},{},{}",
            r.method.replace('"', "'"),
            tau,
            m.miou,
            m.iou_keep,
            m.iou_drop,
            m.accuracy,
            m.fp_per_map,
            m.fn_per_map,
            m.sae_per_map,
            m.maps,
            m.pixels
        );
    }
    s
}
