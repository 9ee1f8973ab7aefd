//! Procedural indoor scenes: the project's default input and its exact oracle.
//!
//! A [`Scene`] is a box-shaped room (walls, floor, ceiling) furnished with cabinets, bookshelves, desks,
//! tables, crates, stools and balls, some stacked, some touching, all drawn from a seed
//! ([`Scene::generate`]). Surfaces are analytic, so [`Scene::render_depth`] gives the *exact* z-depth of
//! any view (the pixel convention of [`crate::geometry`]: pixel (c, r) looks along
//! `((c − cx)/fx, (r − cy)/fy, 1)`). A [`trajectory`] is a smooth hand-held path through the room, and a
//! [`SensorConfig`] turns exact depth into Kinect-v1-like readings (axial noise, dropouts at grazing
//! angles and depth edges, 1 mm quantisation, range limits).
//!
//! A [`SyntheticSequence`] bundles the four and serves frames in memory ([`SyntheticSequence::frame`]),
//! the noise-free truth for any pose ([`SyntheticSequence::true_depth_at`]), and writes itself in the
//! 3DMatch layout ([`SyntheticSequence::write_3dmatch`]).
//!
//! World frame: metres, z up, the room spanning `[0, L] × [0, W] × [0, H]`. Poses are camera-to-world
//! (`t_world_from_camera`), camera frame x right, y down, z forward (OpenCV / 3DMatch). Everything is
//! deterministic for a seed, whatever the thread count.

mod furnish;
mod render;
mod room;
mod scene;
mod sensor;
mod shapes;
mod trajectory;
mod writer;

pub use render::Render;
pub use room::{camera_zone, SceneConfig, LOW_TOP_M, WALL_BAND_M};
pub use scene::Scene;
pub use sensor::SensorConfig;
pub use shapes::{Aabb, Hit, Shape};
pub use trajectory::{look_pose, trajectory, CAMERA_CLEARANCE_M};

use super::Frame;
use crate::error::{Error, Result};
use crate::geometry::{DepthMap, Intrinsics};
use crate::rng::Rng;
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Kinect v1 / 7-Scenes depth intrinsics: 640×480 pixels, fx = fy = 585, principal point (320, 240).
pub const DEFAULT_INTRINSICS: Intrinsics = Intrinsics { fx: 585.0, fy: 585.0, cx: 320.0, cy: 240.0, width: 640, height: 480 };

/// Everything that defines a synthetic sequence besides its seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticConfig {
    /// How rooms are drawn.
    pub scene: SceneConfig,
    /// How exact depth becomes sensor readings.
    pub sensor: SensorConfig,
    /// Camera intrinsics (pixels) and image size of every frame.
    pub intrinsics: Intrinsics,
    /// Number of frames along the trajectory (30 per second of hand-held motion).
    pub frames: usize,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        SyntheticConfig {
            scene: SceneConfig::default(),
            sensor: SensorConfig::default(),
            intrinsics: DEFAULT_INTRINSICS,
            frames: 300,
        }
    }
}

/// A generated scene seen along a trajectory by a noisy sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct SyntheticSequence {
    pub scene: Scene,
    pub intrinsics: Intrinsics,
    /// Camera-to-world pose of each frame.
    pub poses: Vec<Isometry3<f64>>,
    pub sensor: SensorConfig,
    /// The seed the scene, the trajectory and the noise were drawn from.
    pub seed: u64,
}

impl SyntheticSequence {
    /// Draws the scene, the trajectory and (lazily, per frame) the noise from `seed`. Fails on an
    /// invalid configuration, naming the field.
    pub fn generate(config: &SyntheticConfig, seed: u64) -> Result<Self> {
        config.scene.validate()?;
        config.sensor.validate()?;
        config.intrinsics.validate().map_err(|e| Error::config("intrinsics", e.to_string()))?;
        let scene = Scene::generate(&config.scene, seed);
        let poses = trajectory(&scene, config.frames, seed);
        Ok(SyntheticSequence { scene, intrinsics: config.intrinsics, poses, sensor: config.sensor.clone(), seed })
    }

    /// The sequence name, `synthetic-<seed>`.
    pub fn name(&self) -> String {
        format!("synthetic-{}", self.seed)
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether the sequence has no frames.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Key of frame `i`: `synthetic-<seed>/frame-000042`.
    pub fn key(&self, i: usize) -> String {
        format!("{}/frame-{i:06}", self.name())
    }

    /// Seed of frame `i`'s sensor noise.
    pub fn noise_seed(&self, i: usize) -> u64 {
        Rng::new(self.seed).fork(0x5E45).fork(i as u64).next_u64()
    }

    /// Noise-free depth of frame `i` (metres, exact). Panics when `i >= len()`.
    pub fn true_depth(&self, i: usize) -> DepthMap {
        self.true_depth_at(&self.poses[i])
    }

    /// Noise-free depth (metres, exact) of a camera with this sequence's intrinsics at any
    /// camera-to-world pose: the oracle.
    pub fn true_depth_at(&self, t_world_from_camera: &Isometry3<f64>) -> DepthMap {
        self.scene.render_depth(&self.intrinsics, t_world_from_camera)
    }

    /// The sensor's reading of frame `i` (metres, whole millimetres, 0 where invalid). Panics when
    /// `i >= len()`.
    pub fn noisy_depth(&self, i: usize) -> DepthMap {
        let truth = self.scene.render(&self.intrinsics, &self.poses[i]);
        self.sensor.apply(&truth, self.noise_seed(i))
    }

    /// Frame `i` as ingest serves it: the noisy reading, the intrinsics and the true pose; the path
    /// `synthetic://<seed>/frame-XXXXXX` does not exist, and the hash is blake3 of the millimetre
    /// values (u16 little-endian). Panics when `i >= len()`.
    pub fn frame(&self, i: usize) -> Frame {
        let depth = self.noisy_depth(i);
        let raw = depth.to_raw(1000.0);
        let bytes: Vec<u8> = raw.iter().flat_map(|v| v.to_le_bytes()).collect();
        Frame {
            key: self.key(i),
            depth,
            intrinsics: self.intrinsics,
            t_world_from_camera: Some(self.poses[i]),
            depth_path: PathBuf::from(format!("synthetic://{}/frame-{i:06}", self.seed)),
            content_hash: blake3::hash(&bytes).to_hex().to_string(),
        }
    }

    /// Writes the sequence in the flat 3DMatch layout into `dir` (created if missing):
    /// `camera-intrinsics.txt`, and per frame `frame-XXXXXX.depth.png` (16-bit millimetres) and
    /// `frame-XXXXXX.pose.txt` (camera-to-world, row-major 4×4).
    pub fn write_3dmatch(&self, dir: &std::path::Path) -> Result<()> {
        writer::write_3dmatch(self, dir)
    }
}
