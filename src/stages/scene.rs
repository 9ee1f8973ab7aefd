//! Scene: for a unit whose source frame has a pose, its scene (the fused frames of its block, made once and
//! shared by every unit of the block, [`crate::scene`]) seen from the sampled target camera. Units without
//! a pose pass through: the `scene` methods fall back to their configured ones.

use super::frame_cache::FrameCache;
use super::PairUnit;
use crate::error::Result;
use crate::runtime::Stage;
use crate::scene::{block_of, fuse_scene, window_frames, Scene, SceneConfig};
use crate::sources::Catalog;
use std::sync::Arc;

pub struct SceneStage {
    pub catalog: Arc<Catalog>,
    pub config: SceneConfig,
    /// The scenes made last, by [`scene_key`]; shared by the stage's workers.
    pub scenes: Arc<FrameCache<Scene>>,
}

/// The cache key of block `block` of sequence `sequence`.
pub fn scene_key(sequence: usize, block: usize) -> usize {
    (sequence << 32) | block
}

impl SceneStage {
    /// The scene of the block of catalog frame `frame`, fused unless it is among the scenes kept.
    pub fn scene_of(&self, frame: usize) -> Result<Arc<Scene>> {
        let f = &self.catalog.frames[frame];
        let seq = &self.catalog.sequences[f.sequence];
        let block = block_of(f.position, &self.config);
        self.scenes.get(scene_key(f.sequence, block), || {
            let frames = window_frames(&self.config, block, seq.span, |p| seq.frames[p].has_pose(), &[]);
            fuse_scene(&frames, |p| self.catalog.load_at(f.sequence, p), &self.config.tsdf)
        })
    }
}

impl Stage<PairUnit> for SceneStage {
    fn name(&self) -> &'static str {
        "scene"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let Some(t_world_from_source) = unit.t_world_from_source else { return Ok(()) };
        let scene = self.scene_of(unit.frame_index)?;
        if scene.frames == 0 {
            return Ok(());
        }
        let k = unit.k.expect("ingest sets the intrinsics");
        let t_world_from_target = t_world_from_source * unit.t_target_from_source.inverse();
        unit.scene_depth = Some(scene.depth_at(&k, &t_world_from_target)?);
        unit.scene_frames = scene.frames;
        Ok(())
    }
}
