//! Ingest: decode the unit's frame, map it to the working resolution, back-project the scene memory.

use super::PairUnit;
use crate::error::{Error, Result};
use crate::geometry::backproject;
use crate::pipeline::catalog::Catalog;
use crate::pipeline::config::WorkingConfig;
use crate::runtime::Stage;
use crate::shards::row::Status;
use std::sync::Arc;

/// Decodes frames; bad input becomes an `input_error` unit (or a fatal error under `--strict`).
pub struct Ingest {
    pub catalog: Arc<Catalog>,
    pub working: WorkingConfig,
    pub strict: bool,
}

impl Ingest {
    fn prepare(&self, unit: &mut PairUnit) -> Result<()> {
        let frame = self.catalog.load(unit.frame_index)?;
        unit.source_path = frame.depth_path.display().to_string();
        unit.source_hash = frame.content_hash.clone();
        if frame.t_world_from_camera.is_none() {
            return Err(Error::input(&frame.depth_path, "frame has no camera pose (missing pose file)"));
        }
        let (depth, k) = self.working.map_frame(&frame)?;
        let memory = self.working.crop_box.crop(&backproject(&depth, &k, self.working.depth_range()));
        if memory.is_empty() {
            return Err(Error::input(&frame.depth_path, "depth map has no valid pixel inside the depth range and crop box"));
        }
        unit.k = Some(k);
        unit.source_depth = Some(depth);
        unit.memory = memory;
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
