//! Fusing a scene's frames into one TSDF volume (world coordinates: the frames' camera-to-world poses), and
//! seeing it from a target camera.

use super::window::SceneFrames;
use crate::error::Result;
use crate::geometry::{DepthMap, Intrinsics};
use crate::sources::Frame;
use crate::tsdf::{TsdfConfig, TsdfVolume};
use nalgebra::Isometry3;

/// The fused frames of one scene.
pub struct Scene {
    pub volume: TsdfVolume,
    /// Frames integrated (frames that failed to load or have no pose are left out).
    pub frames: u32,
}

impl Scene {
    /// The scene's depth seen by a camera with intrinsics `k` at `t_world_from_camera` (metres, 0 where no
    /// fused surface is seen).
    pub fn depth_at(&self, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Result<DepthMap> {
        self.volume.raycast(k, t_world_from_camera)
    }
}

/// Fuses `frames` (at full resolution, each with its own intrinsics and camera-to-world pose) in order.
/// `load` reads the frame at a sequence position; a frame that fails to load or has no pose is left out
/// with a warning naming it (it is the same frame on every run, so the scene is too).
pub fn fuse_scene(frames: &SceneFrames, load: impl Fn(usize) -> Result<Frame>, tsdf: &TsdfConfig) -> Result<Scene> {
    let mut volume = TsdfVolume::new(tsdf.clone())?;
    let mut fused = 0;
    for &p in frames.positions() {
        match load(p) {
            Ok(Frame { depth, intrinsics, t_world_from_camera: Some(pose), .. }) => {
                volume.integrate(&depth, &intrinsics, &pose)?;
                fused += 1;
            }
            Ok(f) => tracing::warn!("{}: no camera pose, left out of its scene", f.depth_path.display()),
            Err(e) => tracing::warn!("left out of its scene: {e}"),
        }
    }
    Ok(Scene { volume, frames: fused })
}
