//! Pack: turn a finished unit (accepted or rejected) into its shard row, encoding the depth maps; and the
//! `[output]` config section.

use super::PairUnit;
use crate::error::{Error, Result};
use crate::geometry::{pose_to_rows, DepthMap};
use crate::runtime::Stage;
use crate::shards::row::PairRow;
use crate::shards::ROW_GROUP_ROWS;
use crate::sources::depth_png::encode_depth_png;
use serde::{Deserialize, Serialize};

/// What each row stores besides the clouds, and how the shard files are laid out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// Store the source, condition and target depth maps and the known mask as PNG bytes.
    pub depth_maps: bool,
    /// Most rows in one Parquet row group: a reader wanting one pair decodes its whole group, a reader
    /// streaming pays a little per group. Only the file layout depends on it, not the rows, so it is not part
    /// of the dataset's identity (a resume may change it) and is written out only when not the default.
    #[serde(skip_serializing_if = "is_default_row_group_rows")]
    pub row_group_rows: usize,
}

fn is_default_row_group_rows(rows: &usize) -> bool {
    *rows == ROW_GROUP_ROWS
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig { depth_maps: true, row_group_rows: ROW_GROUP_ROWS }
    }
}

impl OutputConfig {
    /// Checks the ranges; the error names the key.
    pub fn validate(&self) -> Result<()> {
        if self.row_group_rows == 0 || self.row_group_rows > 100_000 {
            return Err(Error::config("output.row_group_rows", "must be 1..=100000 rows"));
        }
        Ok(())
    }
}

/// Row-level provenance shared by every row of a build.
pub struct Pack {
    pub config_hash: String,
    pub code_version: String,
    /// JSON array of the stages with their parameters and model hashes.
    pub stages_json: String,
    /// Store the depth maps and the known mask as PNG bytes.
    pub depth_maps: bool,
    pub size: u32,
}

impl Stage<PairUnit> for Pack {
    fn name(&self) -> &'static str {
        "pack"
    }

    fn handles_rejected(&self) -> bool {
        true
    }

    fn process(&mut self, u: &mut PairUnit) -> Result<()> {
        let k = u.k.map(|k| k.as_vector()).unwrap_or([0.0; 4]);
        let raw = |d: &Option<DepthMap>| match d {
            Some(d) if self.depth_maps => Some((d.width(), d.height(), d.to_raw(1000.0))),
            _ => None,
        };
        let png = |r: &Option<(u32, u32, Vec<u16>)>| -> Result<Vec<u8>> {
            match r {
                Some((w, h, raw)) => encode_depth_png(*w, *h, raw),
                None => Ok(Vec::new()),
            }
        };
        let condition_raw = raw(&u.condition);
        let target_raw = raw(&u.target_depth);
        let condition_depth_png = png(&condition_raw)?;
        // Without a fill the target is the condition: its stored millimetres are the same, so are its bytes.
        let target_depth_png =
            if target_raw == condition_raw { condition_depth_png.clone() } else { png(&target_raw)? };
        let known_mask_png = if self.depth_maps && !u.known.is_empty() {
            encode_mask_png(&u.known, self.size, self.size)?
        } else {
            Vec::new()
        };
        u.row = Some(PairRow {
            unit_index: u.unit_index,
            pair_key: format!("{}#{}", u.frame_key, u.sample_index),
            scene: u.scene.clone(),
            frame_key: u.frame_key.clone(),
            sample_index: u.sample_index,
            source_path: std::mem::take(&mut u.source_path),
            source_hash: std::mem::take(&mut u.source_hash),
            status: u.status,
            message: u.message.clone(),
            seed: u.seed,
            width: self.size,
            height: self.size,
            source_intrinsics: k,
            target_intrinsics: k,
            t_target_from_source: pose_to_rows(&u.t_target_from_source),
            pose_draws: u.pose_draws,
            scene_frames: u.scene_frames,
            source_points: std::mem::take(&mut u.source_points),
            target_points: std::mem::take(&mut u.target_points),
            target_known_share: u.target_tags.iter().map(|t| t.known).collect(),
            target_scene_share: u.target_tags.iter().map(|t| t.scene).collect(),
            target_view: std::mem::take(&mut u.target_tags).iter().map(|t| t.view).collect(),
            overlap_source: u.overlap.source,
            overlap_target: u.overlap.target,
            source_depth_png: std::mem::take(&mut u.source_depth_png),
            condition_depth_png,
            target_depth_png,
            known_mask_png,
            config_hash: self.config_hash.clone(),
            code_version: self.code_version.clone(),
            stages: self.stages_json.clone(),
            timings: Vec::new(), // filled by the sink: the pack stage's own timing is recorded after this
        });
        u.condition = None;
        u.target_depth = None;
        u.known = Vec::new();
        u.scene_depth = None;
        u.scene_filled = Vec::new();
        Ok(())
    }
}

/// An 8-bit grayscale PNG of a mask (255 = set).
pub fn encode_mask_png(mask: &[bool], width: u32, height: u32) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        let data: Vec<u8> = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
        enc.write_header()
            .and_then(|mut w| w.write_image_data(&data))
            .map_err(|e| crate::Error::Internal(format!("mask png: {e}")))?;
    }
    Ok(out)
}
