//! Realism of the target views on real sequences (`pointreggpt eval inpaint`): re-project frame j into the
//! stored pose of frame j + K, correct, fill, and compare with the depth captured at j + K.
//!
//! The scores are [`crate::training::fill_metrics`]'s; [`dump_views`] writes the views as `.npy` files so
//! an outside fill (`benchmarks/peers/fill_peers.py`) is scored on exactly the same pixels.

use crate::correction::{apply_keep_mask, Corrector};
use crate::error::{Error, Result};
use crate::geometry::{backproject, project_zbuffer, DepthMap, Intrinsics};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::stages::ingest::WorkingConfig;
use crate::sources::Frame;
pub use crate::training::fill_metrics::FillScores;
use nalgebra::Isometry3;
use std::path::Path;
use std::time::Instant;

/// One evaluation view: the condition re-projected from frame j into frame j + K's camera, and the depth
/// captured there, at the working resolution.
pub struct View {
    pub key: String,
    pub condition: DepthMap,
    pub known: Vec<bool>,
    pub captured: DepthMap,
    pub intrinsics: Intrinsics,
    pub seed: u64,
    /// The target camera from the source camera (the stored poses).
    pub t_target_from_source: Isometry3<f64>,
}

/// The view of `source` seen from `target`'s stored pose (both frames need poses).
pub fn make_view(source: &Frame, target: &Frame, working: &WorkingConfig, seed: u64) -> Result<View> {
    let pose = |f: &Frame| f.t_world_from_camera.ok_or_else(|| Error::input(&f.depth_path, "frame has no camera pose"));
    let t = pose(target)?.inverse() * pose(source)?;
    let (depth, k) = working.map_frame(source)?;
    let (captured, _) = working.map_frame(target)?;
    let memory = working.crop_box.crop(&backproject(&depth, &k, working.depth_range()));
    let proj = project_zbuffer(&memory, &t, &k, false);
    let key = format!("{} -> {}", source.key, target.key);
    Ok(View { key, condition: proj.depth, known: proj.known, captured, intrinsics: k, seed, t_target_from_source: t })
}

/// One row of the comparison.
pub struct MethodRow {
    pub correction: String,
    pub fill: String,
    pub scores: FillScores,
}

/// A correction method under evaluation.
pub struct NamedCorrector {
    pub name: String,
    pub corrector: Box<dyn Corrector>,
}

/// A fill method under evaluation.
pub struct NamedFill {
    pub name: String,
    pub inpainter: Box<dyn Inpainter>,
}

/// Scores every (correction, fill) pair over `views`; `on_view` is called after each view. With `dump`,
/// each fill's output is also written as `DIR/<correction>/NNN_fill_<fill>.npy` (float32 metres, beside
/// [`dump_views`]'s files; `/` in a fill name becomes `-`), so outside scripts score it on the same pixels
/// as their own fills.
pub fn evaluate(
    views: &[View],
    corrections: &[NamedCorrector],
    fills: &[NamedFill],
    range: (f32, f32),
    dump: Option<&Path>,
    mut on_view: impl FnMut(),
) -> Result<Vec<MethodRow>> {
    let mut rows: Vec<MethodRow> = corrections
        .iter()
        .flat_map(|c| fills.iter().map(move |f| MethodRow { correction: c.name.clone(), fill: f.name.clone(), scores: FillScores::default() }))
        .collect();
    for (i, v) in views.iter().enumerate() {
        for (ci, c) in corrections.iter().enumerate() {
            let (mut condition, mut known) = (v.condition.clone(), v.known.clone());
            let keep = c.corrector.keep_mask(&condition);
            apply_keep_mask(&mut condition, &mut known, &keep);
            let ctx = InpaintContext { intrinsics: v.intrinsics, seed: v.seed, t_target_from_source: v.t_target_from_source };
            for (fi, f) in fills.iter().enumerate() {
                let clock = Instant::now();
                let out = f.inpainter.inpaint(&condition, &known, &ctx);
                let scores = &mut rows[ci * fills.len() + fi].scores;
                scores.fill_ns += clock.elapsed().as_nanos();
                scores.add(&known, &out, &v.captured, &v.intrinsics, range);
                if let (Some(dir), false) = (dump, f.name == "none") {
                    let path = dir.join(&c.name).join(format!("{i:03}_fill_{}.npy", f.name.replace('/', "-")));
                    let (w, h) = (out.width() as usize, out.height() as usize);
                    std::fs::write(&path, crate::export::npy::encode_npy_image_f32(w, h, out.data())).map_err(|e| Error::io(&path, e))?;
                }
            }
        }
        on_view();
    }
    Ok(rows)
}

/// The rows as an aligned table.
pub fn format_table(rows: &[MethodRow]) -> String {
    let mut s = format!(
        "{:<10} {:<16} {:>5} {:>8} {:>8} {:>9} {:>8} {:>7} {:>7} {:>8} {:>7} {:>7} {:>7} {:>8} {:>8}\n",
        "correction", "fill", "views", "unknown", "wrong/m", "coverage", "AbsRel", "RMSE m", "d<1.25", "edge AR", "edge RM", "edge d", "flying", "cloud cm", "ms/view"
    );
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{:<10} {:<16} {:>5} {:>7.1}% {:>8.1} {:>8.1}% {:>8.4} {:>7.3} {:>6.1}% {:>8.4} {:>7.3} {:>6.1}% {:>6.1}% {:>8.2} {:>8.1}\n",
            r.correction,
            r.fill,
            c.views,
            100.0 * c.unknown_share(),
            c.wrong_kept_per_view(),
            100.0 * c.coverage(),
            c.filled.abs_rel(),
            c.filled.rmse(),
            100.0 * c.filled.delta(),
            c.band.abs_rel(),
            c.band.rmse(),
            100.0 * c.band.delta(),
            100.0 * c.flying_share(),
            100.0 * c.cloud_distance_m(),
            c.ms_per_view()
        );
    }
    s
}

/// The rows as CSV.
pub fn to_csv(rows: &[MethodRow]) -> String {
    let mut s = String::from(
        "correction,fill,views,unknown_share,kept_per_map,wrong_kept_per_map,kept_abs_rel,fill_coverage,fill_abs_rel,fill_rmse_m,\
         fill_delta_1_25,edge_abs_rel,edge_rmse_m,edge_delta_1_25,flying_share,cloud_distance_m,ms_per_view\n",
    );
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{},{},{},{:.6},{:.3},{:.3},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.3}\n",
            r.correction,
            r.fill,
            c.views,
            c.unknown_share(),
            c.kept_per_view(),
            c.wrong_kept_per_view(),
            c.kept_abs_rel(),
            c.coverage(),
            c.filled.abs_rel(),
            c.filled.rmse(),
            c.filled.delta(),
            c.band.abs_rel(),
            c.band.rmse(),
            c.band.delta(),
            c.flying_share(),
            c.cloud_distance_m(),
            c.ms_per_view()
        );
    }
    s
}

/// Writes every view as seen after each correction, for outside fills: `DIR/<correction>/NNN_condition.npy`
/// (float32 metres, 0 where unknown), `NNN_known.npy` (bool) and `NNN_captured.npy` (float32 metres), all
/// (H, W), and `DIR/<correction>/views.json` with each view's key, intrinsics, target-from-source pose
/// (row-major 4×4) and the valid depth range.
pub fn dump_views(dir: &Path, views: &[View], corrections: &[NamedCorrector], range: (f32, f32)) -> Result<()> {
    use crate::export::npy::{encode_npy_image_f32, encode_npy_mask};
    for c in corrections {
        let sub = dir.join(&c.name);
        std::fs::create_dir_all(&sub).map_err(|e| Error::io(&sub, e))?;
        let mut index = Vec::new();
        for (i, v) in views.iter().enumerate() {
            let (mut condition, mut known) = (v.condition.clone(), v.known.clone());
            let keep = c.corrector.keep_mask(&condition);
            apply_keep_mask(&mut condition, &mut known, &keep);
            let (w, h) = (v.condition.width() as usize, v.condition.height() as usize);
            let write = |name: &str, bytes: Vec<u8>| {
                let path = sub.join(format!("{i:03}_{name}.npy"));
                std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))
            };
            let masked: Vec<f32> = condition.data().iter().zip(&known).map(|(z, k)| if *k { *z } else { 0.0 }).collect();
            write("condition", encode_npy_image_f32(w, h, &masked))?;
            write("known", encode_npy_mask(w, h, &known))?;
            write("captured", encode_npy_image_f32(w, h, v.captured.data()))?;
            let k = &v.intrinsics;
            index.push(serde_json::json!({
                "index": i, "key": v.key, "width": w, "height": h,
                "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
                "t_target_from_source": v.t_target_from_source.to_homogeneous().transpose().as_slice().to_vec(),
            }));
        }
        let meta = serde_json::json!({ "correction": c.name, "depth_range": [range.0, range.1], "views": index });
        let path = sub.join("views.json");
        let text = serde_json::to_string_pretty(&meta).map_err(|e| Error::InvalidArgument(e.to_string()))?;
        std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
    }
    Ok(())
}
