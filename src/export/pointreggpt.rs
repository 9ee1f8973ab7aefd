//! The PointRegGPT authors' layout (reference §6.1–6.2), read unchanged by their mixture dataloaders:
//!
//! ```text
//! <out>/data/scene-XXXXXX/sample-000000.cloud.ply   source cloud, source camera frame
//! <out>/data/scene-XXXXXX/sample-000001.cloud.ply   target cloud moved into the source frame (inv(T)·p), with
//!                                                   the vertex properties `known_share` and `view` (provenance)
//! <out>/data/scene-XXXXXX/sample-000001.pose.txt    inv(T): the target camera's pose in the source frame
//! <out>/data/scene-XXXXXX/camera-intrinsics.txt     3×3 working intrinsics
//! <out>/metadata/gt.log                             "scene-XXXXXX\t0\t1\t%.4f\t%.4f\n" per kept pair
//! <out>/metadata/pairs.tsv                          scene folder → pair key, unit index (provenance)
//! ```
//!
//! `XXXXXX` is the export order. `gt.log` lists the pairs the official `generate_gt.py` keeps: both
//! clouds with at least [`MIN_POINTS`] points and `max(overlap_source, overlap_target) ≥` [`MIN_OVERLAP`]
//! (overlaps as stored in the row).

use super::{is_ok, matrix_text, row_pose, write_text, PairWriter};
use crate::error::Result;
use crate::geometry::{pose_to_rows, transform_points};
use crate::shards::row::PairRow;
use crate::ply::{write_points, write_points_with_provenance, Provenance};
use std::path::{Path, PathBuf};

/// The official keep rule's minimum cloud size.
pub const MIN_POINTS: usize = 1000;
/// The official keep rule's minimum of the larger overlap.
pub const MIN_OVERLAP: f64 = 0.1;

/// Whether `generate_gt.py` keeps a pair (both clouds ≥ 1000 points, max overlap ≥ 0.1, no NaN).
pub fn official_keep(row: &PairRow) -> bool {
    let (s, t) = (row.overlap_source, row.overlap_target);
    row.source_points.len() >= MIN_POINTS && row.target_points.len() >= MIN_POINTS && !s.is_nan() && !t.is_nan() && s.max(t) >= MIN_OVERLAP
}

/// The `gt.log` line of pair `index`.
pub fn gt_log_line(index: u64, row: &PairRow) -> String {
    format!("scene-{index:06}\t0\t1\t{:.4}\t{:.4}\n", row.overlap_source, row.overlap_target)
}

/// Writes the authors' layout; see the module documentation.
pub struct PointRegGptWriter {
    out: PathBuf,
    gt_log: String,
    gt_lines: u64,
    tsv: String,
}

impl PointRegGptWriter {
    /// A writer into `out` (which exists and is empty).
    pub fn new(out: &Path) -> Self {
        PointRegGptWriter {
            out: out.to_path_buf(),
            gt_log: String::new(),
            gt_lines: 0,
            tsv: "scene\tpair_key\tunit_index\tin_gt_log\n".into(),
        }
    }
}

impl PairWriter for PointRegGptWriter {
    fn accepts(&self, row: &PairRow) -> bool {
        is_ok(row)
    }

    fn write(&mut self, index: u64, row: &PairRow) -> Result<()> {
        let scene = format!("scene-{index:06}");
        let dir = self.out.join("data").join(&scene);
        let t_source_from_target = row_pose(row)?.inverse();
        write_points(&dir.join("sample-000000.cloud.ply"), &row.source_points)?;
        let target = transform_points(&row.target_points, &t_source_from_target);
        write_points_with_provenance(&dir.join("sample-000001.cloud.ply"), &target, Provenance::of(row))?;
        write_text(&dir.join("sample-000001.pose.txt"), &matrix_text(&pose_to_rows(&t_source_from_target), 4))?;
        let [fx, fy, cx, cy] = row.source_intrinsics;
        write_text(&dir.join("camera-intrinsics.txt"), &matrix_text(&[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0], 3))?;
        let keep = official_keep(row);
        if keep {
            self.gt_log.push_str(&gt_log_line(index, row));
            self.gt_lines += 1;
        }
        self.tsv.push_str(&format!("{scene}\t{}\t{}\t{}\n", row.pair_key, row.unit_index, keep as u8));
        Ok(())
    }

    fn finish(&mut self) -> Result<Option<u64>> {
        let meta = self.out.join("metadata");
        write_text(&meta.join("gt.log"), &self.gt_log)?;
        write_text(&meta.join("pairs.tsv"), &self.tsv)?;
        Ok(Some(self.gt_lines))
    }
}
