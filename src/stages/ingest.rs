//! Ingest: decode the unit's frame, map it to the working resolution, back-project the scene memory and
//! voxelize it into the source cloud (once per frame: every sample of a frame has the same source); and
//! the `[working]` config section (resolution, intrinsics map, depth range, crop box) that every later
//! stage also reads.

use super::frame_cache::FrameCache;
use super::PairUnit;
use crate::error::{Error, Result};
use crate::geometry::{backproject, voxel_downsample, AxisBox, DepthMap, DepthRange, Intrinsics, Point, ResizeCrop};
use crate::runtime::Stage;
use crate::shards::row::Status;
use crate::sources::depth_png::encode_depth_png;
use crate::sources::{Catalog, Frame};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// How intrinsics follow the resize-and-crop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntrinsicsMap {
    /// The official map: principal point assumed at the image centre (`cx' = W'/2 − left`).
    Official,
    /// Exact pixel-centre scaling of the stored principal point.
    Exact,
}

/// Working resolution and the region of space that becomes points.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorkingConfig {
    /// Side of the square working image, pixels (official 256: shorter side resized, centre crop).
    pub size: u32,
    /// How intrinsics follow the resize and crop.
    pub intrinsics: IntrinsicsMap,
    /// Depths kept when back-projecting, metres, open interval (official 0.5–10).
    pub depth_range: [f32; 2],
    /// Crop box in each camera's own frame, metres (official x, y ±1.5, z 0.5–3.5).
    pub crop_box: AxisBox,
}

impl Default for WorkingConfig {
    fn default() -> Self {
        WorkingConfig { size: 256, intrinsics: IntrinsicsMap::Official, depth_range: [0.5, 10.0], crop_box: AxisBox::OFFICIAL }
    }
}

impl WorkingConfig {
    pub fn depth_range(&self) -> DepthRange {
        DepthRange { near: self.depth_range[0], far: self.depth_range[1] }
    }

    /// The official resize and centre crop of an image with intrinsics `k0`, and the intrinsics at the
    /// working resolution, mapped as `intrinsics` says.
    pub fn map_intrinsics(&self, k0: &Intrinsics) -> Result<(ResizeCrop, Intrinsics)> {
        let rc = ResizeCrop::official(k0.width, k0.height, self.size)?;
        let k = match self.intrinsics {
            IntrinsicsMap::Official => rc.official_intrinsics(k0)?,
            IntrinsicsMap::Exact => rc.exact_intrinsics(k0)?,
        };
        Ok((rc, k))
    }

    /// A frame's depth and intrinsics at the working resolution ([`Self::map_intrinsics`]).
    pub fn map_frame(&self, frame: &Frame) -> Result<(DepthMap, Intrinsics)> {
        let (rc, k) = self.map_intrinsics(&frame.intrinsics)?;
        Ok((frame.depth.resize_crop(&rc)?, k))
    }

    /// Checks ranges; errors name the key under `working`.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, m: &str| Err(Error::config(k, m));
        if self.size < 16 || self.size > 4096 {
            return bad("working.size", "must be 16..=4096 pixels");
        }
        let [near, far] = self.depth_range;
        if !(near >= 0.0 && far > near && far.is_finite()) {
            return bad("working.depth_range", "must be [near, far] metres with 0 <= near < far");
        }
        let b = &self.crop_box;
        if (0..3).any(|a| !(b.min[a] < b.max[a]) || !b.min[a].is_finite() || !b.max[a].is_finite()) {
            return bad("working.crop_box", "min must be below max on every axis");
        }
        Ok(())
    }
}

/// A frame as every sample of it starts: decoded, at the working resolution, back-projected, and its
/// working-resolution depth encoded as the rows' `source_depth_png` (once for all its samples).
pub struct PreparedFrame {
    source_path: String,
    source_hash: String,
    /// The 16-bit millimetre PNG of the working-resolution depth (empty when the rows store no depth maps).
    depth_png: Vec<u8>,
    k: Intrinsics,
    memory: Vec<Point>,
    /// `memory` voxel-downsampled: the pair's source cloud.
    source_points: Vec<Point>,
    t_world_from_camera: Option<Isometry3<f64>>,
}

/// Decodes frames; bad input becomes an `input_error` unit (or a fatal error under `--strict`). The
/// workers share `frames`, so a frame's samples decode it once.
pub struct Ingest {
    pub catalog: Arc<Catalog>,
    pub working: WorkingConfig,
    pub strict: bool,
    pub frames: Arc<FrameCache<PreparedFrame>>,
    /// Voxel edge of the source cloud, metres (`voxelize.voxel`).
    pub voxel: f32,
    /// Whether the rows store the depth maps (`output.depth_maps`): the source's PNG is encoded here.
    pub depth_maps: bool,
}

impl Ingest {
    fn prepare_frame(&self, index: usize) -> Result<PreparedFrame> {
        let frame = self.catalog.load(index)?;
        let (depth, k) = self.working.map_frame(&frame)?;
        let memory = self.working.crop_box.crop(&backproject(&depth, &k, self.working.depth_range()));
        if memory.is_empty() {
            return Err(Error::input(&frame.depth_path, "depth map has no valid pixel inside the depth range and crop box"));
        }
        let source_points = voxel_downsample(&memory, self.voxel);
        let depth_png = match self.depth_maps {
            true => encode_depth_png(depth.width(), depth.height(), &depth.to_raw(1000.0))?,
            false => Vec::new(),
        };
        let t_world_from_camera = frame.t_world_from_camera;
        Ok(PreparedFrame { source_path: frame.depth_path.display().to_string(), source_hash: frame.content_hash, depth_png, k, memory, source_points, t_world_from_camera })
    }

    fn prepare(&self, unit: &mut PairUnit) -> Result<()> {
        let f = match self.frames.get(unit.frame_index, || self.prepare_frame(unit.frame_index)) {
            Ok(f) => f,
            Err(e) => {
                // A frame that decodes but makes no pair (e.g. no valid depth) still names its file and
                // content in the input_error row (failures are not cached: read again, rare).
                if let Ok(frame) = self.catalog.load(unit.frame_index) {
                    unit.source_path = frame.depth_path.display().to_string();
                    unit.source_hash = frame.content_hash;
                }
                return Err(e);
            }
        };
        unit.source_path = f.source_path.clone();
        unit.source_hash = f.source_hash.clone();
        unit.k = Some(f.k);
        unit.source_depth_png = f.depth_png.clone();
        unit.memory = f.memory.clone();
        unit.source_points = f.source_points.clone();
        unit.t_world_from_source = f.t_world_from_camera;
        Ok(())
    }
}

impl Stage<PairUnit> for Ingest {
    fn name(&self) -> &'static str {
        "ingest"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        match self.prepare(unit) {
            Ok(()) => Ok(()),
            Err(e @ (Error::InputData { .. } | Error::Io { .. })) if !self.strict => {
                unit.reject(Status::InputError, e.to_string());
                Ok(())
            }
            Err(e) => Err(e),
        }
    }
}
