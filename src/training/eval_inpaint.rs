//! Realism of the target views on real sequences (`pointreggpt eval inpaint`): re-project frame j into the
//! stored pose of frame j + K, correct, fill, and compare with the depth captured at j + K.
//!
//! Two groups of pixels are scored against the captured depth (where it is valid):
//! - kept: re-projected pixels that survive correction. A kept depth more than [`PENETRATION_M`] behind the
//!   captured surface is a penetration error (a background point seen through a foreground hole);
//! - filled: pixels the re-projection left unknown and the fill gave a depth: AbsRel, RMSE, δ < 1.25, and
//!   the coverage (filled share of the unknown pixels the sensor saw).

use crate::correction::{apply_keep_mask, Corrector};
use crate::error::{Error, Result};
use crate::geometry::{backproject, project_zbuffer, DepthMap, Intrinsics};
use crate::inpainting::{InpaintContext, Inpainter};
use crate::stages::ingest::WorkingConfig;
use crate::sources::Frame;
use serde::Serialize;

/// A kept depth this far behind the captured one is a penetration error (the official τ_gt).
pub const PENETRATION_M: f32 = 0.05;

/// One evaluation view: the condition re-projected from frame j into frame j + K's camera, and the depth
/// captured there, at the working resolution.
pub struct View {
    pub key: String,
    pub condition: DepthMap,
    pub known: Vec<bool>,
    pub captured: DepthMap,
    pub intrinsics: Intrinsics,
    pub seed: u64,
}

/// The view of `source` seen from `target`'s stored pose (both frames need poses).
pub fn make_view(source: &Frame, target: &Frame, working: &WorkingConfig, seed: u64) -> Result<View> {
    let pose = |f: &Frame| f.t_world_from_camera.ok_or_else(|| Error::input(&f.depth_path, "frame has no camera pose"));
    let t = pose(target)?.inverse() * pose(source)?;
    let (depth, k) = working.map_frame(source)?;
    let (captured, _) = working.map_frame(target)?;
    let memory = working.crop_box.crop(&backproject(&depth, &k, working.depth_range()));
    let proj = project_zbuffer(&memory, &t, &k, false);
    Ok(View { key: format!("{} -> {}", source.key, target.key), condition: proj.depth, known: proj.known, captured, intrinsics: k, seed })
}

/// Sums of one (correction, fill) method over views.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FillScores {
    pub views: u64,
    pub kept: u64,
    pub kept_wrong: u64,
    kept_abs_rel: f64,
    /// Unknown pixels (after correction) where the sensor has depth.
    pub unknown: u64,
    pub filled: u64,
    abs_rel: f64,
    sq: f64,
    delta_ok: u64,
}

impl FillScores {
    /// Adds one view: `known` after correction, `filled` the fill's output.
    pub fn add(&mut self, known: &[bool], filled: &DepthMap, captured: &DepthMap, range: (f32, f32)) {
        self.views += 1;
        let valid = |z: f32| z > range.0 && z < range.1;
        for ((k, z), g) in known.iter().zip(filled.data()).zip(captured.data()) {
            if !valid(*g) {
                continue;
            }
            if *k {
                if *z > 0.0 {
                    self.kept += 1;
                    self.kept_wrong += (*z - *g > PENETRATION_M) as u64;
                    self.kept_abs_rel += ((*z - *g).abs() / *g) as f64;
                }
            } else {
                self.unknown += 1;
                if valid(*z) {
                    self.filled += 1;
                    let (z, g) = (*z as f64, *g as f64);
                    self.abs_rel += (z - g).abs() / g;
                    self.sq += (z - g) * (z - g);
                    self.delta_ok += ((z / g).max(g / z) < 1.25) as u64;
                }
            }
        }
    }

    pub fn kept_per_view(&self) -> f64 {
        self.kept as f64 / self.views.max(1) as f64
    }
    pub fn wrong_kept_per_view(&self) -> f64 {
        self.kept_wrong as f64 / self.views.max(1) as f64
    }
    pub fn kept_abs_rel(&self) -> f64 {
        self.kept_abs_rel / self.kept.max(1) as f64
    }
    pub fn coverage(&self) -> f64 {
        self.filled as f64 / self.unknown.max(1) as f64
    }
    pub fn abs_rel(&self) -> f64 {
        self.abs_rel / self.filled.max(1) as f64
    }
    pub fn rmse(&self) -> f64 {
        (self.sq / self.filled.max(1) as f64).sqrt()
    }
    pub fn delta(&self) -> f64 {
        self.delta_ok as f64 / self.filled.max(1) as f64
    }
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

/// Scores every (correction, fill) pair over `views`; `on_view` is called after each view.
pub fn evaluate(views: &[View], corrections: &[NamedCorrector], fills: &[NamedFill], range: (f32, f32), mut on_view: impl FnMut()) -> Vec<MethodRow> {
    let mut rows: Vec<MethodRow> = corrections
        .iter()
        .flat_map(|c| fills.iter().map(move |f| MethodRow { correction: c.name.clone(), fill: f.name.clone(), scores: FillScores::default() }))
        .collect();
    for v in views {
        for (ci, c) in corrections.iter().enumerate() {
            let (mut condition, mut known) = (v.condition.clone(), v.known.clone());
            let keep = c.corrector.keep_mask(&condition);
            apply_keep_mask(&mut condition, &mut known, &keep);
            let ctx = InpaintContext { intrinsics: v.intrinsics, seed: v.seed };
            for (fi, f) in fills.iter().enumerate() {
                let out = f.inpainter.inpaint(&condition, &known, &ctx);
                rows[ci * fills.len() + fi].scores.add(&known, &out, &v.captured, range);
            }
        }
        on_view();
    }
    rows
}

/// The rows as an aligned table.
pub fn format_table(rows: &[MethodRow]) -> String {
    let mut s = format!(
        "{:<12} {:<14} {:>6} {:>9} {:>11} {:>10} {:>9} {:>9} {:>8} {:>9}\n",
        "correction", "fill", "views", "kept/map", "wrong/map", "kept AbsR", "coverage", "AbsRel", "RMSE m", "d<1.25"
    );
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{:<12} {:<14} {:>6} {:>9.0} {:>11.1} {:>10.4} {:>8.1}% {:>9.4} {:>8.4} {:>8.1}%\n",
            r.correction,
            r.fill,
            c.views,
            c.kept_per_view(),
            c.wrong_kept_per_view(),
            c.kept_abs_rel(),
            100.0 * c.coverage(),
            c.abs_rel(),
            c.rmse(),
            100.0 * c.delta()
        );
    }
    s
}

/// The rows as CSV.
pub fn to_csv(rows: &[MethodRow]) -> String {
    let mut s = String::from("correction,fill,views,kept_per_map,wrong_kept_per_map,kept_abs_rel,fill_coverage,fill_abs_rel,fill_rmse_m,fill_delta_1_25\n");
    for r in rows {
        let c = &r.scores;
        s += &format!(
            "{},{},{},{:.3},{:.3},{:.6},{:.6},{:.6},{:.6},{:.6}\n",
            r.correction,
            r.fill,
            c.views,
            c.kept_per_view(),
            c.wrong_kept_per_view(),
            c.kept_abs_rel(),
            c.coverage(),
            c.abs_rel(),
            c.rmse(),
            c.delta()
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_count_penetrations_and_fill_errors_by_hand() {
        // 4 pixels: kept right, kept 10 cm too far (penetration), unknown filled 10% too near, unknown empty.
        let captured = DepthMap::new(4, 1, vec![2.0, 2.0, 2.0, 2.0]).unwrap();
        let filled = DepthMap::new(4, 1, vec![2.0, 2.1, 1.8, 0.0]).unwrap();
        let known = [true, true, false, false];
        let mut s = FillScores::default();
        s.add(&known, &filled, &captured, (0.5, 10.0));
        assert_eq!((s.kept, s.kept_wrong, s.unknown, s.filled), (2, 1, 2, 1));
        assert!((s.kept_abs_rel() - 0.025).abs() < 1e-6);
        assert!((s.coverage() - 0.5).abs() < 1e-12);
        assert!((s.abs_rel() - 0.1).abs() < 1e-6);
        assert!((s.rmse() - 0.2).abs() < 1e-6);
        assert_eq!(s.delta(), 1.0);
    }
}
