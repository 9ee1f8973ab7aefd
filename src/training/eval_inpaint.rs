//! Realism of the target views on real sequences (`pointreggpt eval inpaint`): re-project frame j into the
//! stored pose of frame j + K, correct, fill, and compare with the depth captured at j + K.
//!
//! The scores are [`crate::training::fill_metrics`]'s; [`dump_views`] writes the views as `.npy` files so
//! an outside fill (`benchmarks/peers/fill_peers.py`) is scored on exactly the same pixels.
//!
//! With a scene ([`scene_of_view`]), the `scene` correction and fills see the frames around the source
//! fused and ray-cast at the target pose, with the held-out rule: the captured target frame and its
//! neighbours never enter the scene ([`crate::scene::HeldOut`]).

use crate::correction::{apply_keep_mask, Corrector};
use crate::error::{Error, Result};
use crate::geometry::{backproject, project_zbuffer, DepthMap, Intrinsics};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::scene::{block_of, fuse_scene, paste_scene, window_frames, HeldOut, SceneConfig};
use crate::stages::correct::keep_mask;
use crate::stages::ingest::WorkingConfig;
use crate::sources::{Frame, Sequence};
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
    /// The scene seen from the target camera (0 where it has no surface), when scenes are evaluated.
    pub scene: Option<DepthMap>,
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
    Ok(View { key, condition: proj.depth, known: proj.known, captured, intrinsics: k, seed, t_target_from_source: t, scene: None })
}

/// The scene of the view of `seq`'s frame `source` seen from frame `target` (working intrinsics `k`): the
/// frames of the source's block window ([`window_frames`], the whole sequence as span), with `target` and
/// the `exclude` frames on each side of it held out, fused and ray-cast at the target's stored pose. Also
/// returns the positions fused.
pub fn scene_of_view(seq: &Sequence, source: usize, target: usize, exclude: usize, config: &SceneConfig, k: &Intrinsics) -> Result<(DepthMap, Vec<usize>)> {
    let held_out = HeldOut { position: target, radius: exclude };
    let frames = window_frames(config, block_of(source, config), (0, seq.frames.len() - 1), |p| seq.frames[p].has_pose(), &[held_out]);
    let scene = fuse_scene(&frames, |p| seq.frames[p].load(), &config.tsdf)?;
    let t_world_from_target = seq.frames[target].load()?.t_world_from_camera.ok_or_else(|| Error::input(&seq.frames[target].depth_path, "frame has no camera pose"))?;
    Ok((scene.depth_at(k, &t_world_from_target)?, frames.positions().to_vec()))
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
    /// The method's corrector (for `scene`, its fallback's).
    pub corrector: Box<dyn Corrector>,
    /// For `scene`: the scene's rule, applied where the view has a scene.
    pub scene_rule: Option<crate::correction::SceneRule>,
}

impl NamedCorrector {
    /// `config` under `name` (with the scene's rule when it is `scene`).
    pub fn new(name: impl Into<String>, config: &crate::correction::CorrectionConfig) -> Self {
        NamedCorrector { name: name.into(), corrector: config.build(), scene_rule: config.scene_rule() }
    }

    /// A view's condition and known mask after this correction.
    fn apply(&self, v: &View) -> (DepthMap, Vec<bool>) {
        let (mut condition, mut known) = (v.condition.clone(), v.known.clone());
        let scene = self.scene_rule.and_then(|r| v.scene.as_ref().map(|s| (s, r)));
        let keep = keep_mask(self.corrector.as_ref(), scene, &condition);
        apply_keep_mask(&mut condition, &mut known, &keep);
        (condition, known)
    }
}

/// A fill method under evaluation.
pub struct NamedFill {
    pub name: String,
    /// The method's inpainter (for `scene`, its fallback's).
    pub inpainter: Box<dyn Inpainter>,
    /// Whether the method is `scene`: the view's scene fills first, the inpainter the rest.
    pub scene: bool,
}

impl NamedFill {
    /// `config` under `name`.
    pub fn new(name: impl Into<String>, config: &crate::inpainting::InpaintConfig) -> Result<Self> {
        Ok(NamedFill { name: name.into(), inpainter: config.build()?, scene: config.is_scene() })
    }

    /// The filled view and the mask of the pixels the scene gave (empty without a scene).
    fn fill(&self, condition: &DepthMap, known: &[bool], scene: Option<&DepthMap>, ctx: &InpaintContext) -> (DepthMap, Vec<bool>) {
        match (self.scene, scene) {
            (true, Some(scene)) => {
                let p = paste_scene(condition, known, scene);
                (self.inpainter.inpaint(&p.depth, &p.known, ctx), p.from_scene)
            }
            _ => (self.inpainter.inpaint(condition, known, ctx), Vec::new()),
        }
    }
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
            let (condition, known) = c.apply(v);
            let ctx = InpaintContext { intrinsics: v.intrinsics, seed: v.seed, t_target_from_source: v.t_target_from_source };
            for (fi, f) in fills.iter().enumerate() {
                let clock = Instant::now();
                let (out, from_scene) = f.fill(&condition, &known, v.scene.as_ref(), &ctx);
                let scores = &mut rows[ci * fills.len() + fi].scores;
                scores.fill_ns += clock.elapsed().as_nanos();
                scores.add(&known, &out, &v.captured, &v.intrinsics, range);
                scores.scene_pixels += from_scene.iter().filter(|s| **s).count() as u64;
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
        "{:<10} {:<16} {:>5} {:>8} {:>7} {:>8} {:>9} {:>8} {:>7} {:>7} {:>8} {:>7} {:>7} {:>7} {:>8} {:>8}\n",
        "correction", "fill", "views", "unknown", "scene", "wrong/m", "coverage", "AbsRel", "RMSE m", "d<1.25", "edge AR", "edge RM", "edge d", "flying", "cloud cm", "ms/view"
    );
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{:<10} {:<16} {:>5} {:>7.1}% {:>6.1}% {:>8.1} {:>8.1}% {:>8.4} {:>7.3} {:>6.1}% {:>8.4} {:>7.3} {:>6.1}% {:>6.1}% {:>8.2} {:>8.1}\n",
            r.correction,
            r.fill,
            c.views,
            100.0 * c.unknown_share(),
            100.0 * c.scene_share(),
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
        "correction,fill,views,unknown_share,scene_share,kept_per_map,wrong_kept_per_map,kept_abs_rel,fill_coverage,fill_abs_rel,fill_rmse_m,\
         fill_delta_1_25,edge_abs_rel,edge_rmse_m,edge_delta_1_25,flying_share,cloud_distance_m,ms_per_view\n",
    );
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{},{},{},{:.6},{:.6},{:.3},{:.3},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.3}\n",
            r.correction,
            r.fill,
            c.views,
            c.unknown_share(),
            c.scene_share(),
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
/// (row-major 4×4) and the valid depth range. Views with a scene also get `NNN_scene.npy` (float32 metres,
/// the scene's depth at the unknown pixels where it has a surface, 0 elsewhere): an outside fill then runs
/// as the `scene` fill's fallback (`fill_peers.py` scores both).
pub fn dump_views(dir: &Path, views: &[View], corrections: &[NamedCorrector], range: (f32, f32)) -> Result<()> {
    use crate::export::npy::{encode_npy_image_f32, encode_npy_mask};
    for c in corrections {
        let sub = dir.join(&c.name);
        std::fs::create_dir_all(&sub).map_err(|e| Error::io(&sub, e))?;
        let mut index = Vec::new();
        for (i, v) in views.iter().enumerate() {
            let (condition, known) = c.apply(v);
            let (w, h) = (v.condition.width() as usize, v.condition.height() as usize);
            let write = |name: &str, bytes: Vec<u8>| {
                let path = sub.join(format!("{i:03}_{name}.npy"));
                std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))
            };
            let masked: Vec<f32> = condition.data().iter().zip(&known).map(|(z, k)| if *k { *z } else { 0.0 }).collect();
            write("condition", encode_npy_image_f32(w, h, &masked))?;
            write("known", encode_npy_mask(w, h, &known))?;
            write("captured", encode_npy_image_f32(w, h, v.captured.data()))?;
            if let Some(scene) = &v.scene {
                let p = paste_scene(&condition, &known, scene);
                let at_unknown: Vec<f32> = p.depth.data().iter().zip(&p.from_scene).map(|(z, s)| if *s { *z } else { 0.0 }).collect();
                write("scene", encode_npy_image_f32(w, h, &at_unknown))?;
            }
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
