//! The label pipeline's configuration.

use crate::config_paths::{identity_toml, ConfigIdentity, ConfigPaths};
use crate::error::{Error, Result};
use crate::sources::SourceConfig;
use crate::stages::ingest::WorkingConfig;
use crate::stages::pose::PoseConfig;
use crate::tsdf::TsdfConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The whole label pipeline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelsConfig {
    /// Build seed: a window's seed is a hash of (seed, window key, sample index).
    #[serde(default)]
    pub seed: u64,
    /// Target poses (label examples) drawn per fused window.
    #[serde(default = "two")]
    pub samples_per_window: u32,
    /// Windows per shard (fixed for a dataset).
    #[serde(default = "default_shard_size")]
    pub shard_size: u64,
    /// Where the sequences come from (frames need camera-to-world poses).
    pub source: SourceConfig,
    /// How sequences are cut into fused windows.
    #[serde(default)]
    pub window: WindowConfig,
    /// The TSDF volume (default: the 3DMatch fusion, 6 mm voxels, 3 cm truncation, 6 m range).
    #[serde(default)]
    pub tsdf: TsdfConfig,
    /// Surface extraction and the sparse copy.
    #[serde(default)]
    pub clouds: CloudsConfig,
    /// Working resolution, depth range and crop box (the crop applies to the fused clouds in the
    /// reference camera frame).
    #[serde(default)]
    pub working: WorkingConfig,
    /// Target pose sampling relative to the reference frame (the build's pivot sampler).
    #[serde(default)]
    pub pose: PoseConfig,
    /// τ_gt, metres (official 0.05).
    #[serde(default = "default_tau")]
    pub tau_gt: f32,
    /// The folder of the config file its relative paths were resolved against (not a key).
    #[serde(skip)]
    pub folder: Option<PathBuf>,
}

fn two() -> u32 {
    2
}
fn default_shard_size() -> u64 {
    8
}
fn default_tau() -> f32 {
    0.05
}

/// Windows of consecutive frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WindowConfig {
    /// Frames fused per window (3DMatch fragments: 50).
    pub frames: usize,
    /// First frame of window w is `w · stride` (50 = non-overlapping fragments).
    pub stride: usize,
    /// The frame whose camera the clouds and the sampled pose are relative to.
    pub reference: Reference,
    /// Index of the first frame of each sequence that windows use (frames before it are left out, e.g.
    /// to hold them out for validation).
    pub first_frame: usize,
    /// At most this many windows per sequence (0: as many as fit).
    pub max_windows: usize,
}

/// Which frame of a window is the reference.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reference {
    /// The first frame (the 3DMatch fragment convention).
    First,
    /// The middle frame.
    Middle,
}

impl Default for WindowConfig {
    fn default() -> Self {
        WindowConfig { frames: 50, stride: 50, reference: Reference::First, first_frame: 0, max_windows: 0 }
    }
}

/// Dense surface extraction and its sparse copy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CloudsConfig {
    /// Surface points need a TSDF weight above this (3DMatch: 1).
    pub weight_threshold: f32,
    /// Voxel of the sparse copy `P_s`, metres (the authors' value is unknown; 2.5 cm, the build's voxel).
    pub sparse_voxel: f32,
    /// How the dense reference `I_d` is rendered.
    pub dense: DenseMode,
}

/// How `I_d` is rendered from the fused window.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DenseMode {
    /// Ray cast the TSDF volume from the target pose (the fused surface without holes), with the pixels the
    /// rays miss taken from the z-buffered dense points (default).
    Raycast,
    /// Z-buffer the dense surface points `P_d` (leaves holes where points are sparser than pixels).
    Points,
}

impl Default for CloudsConfig {
    fn default() -> Self {
        CloudsConfig { weight_threshold: 1.0, sparse_voxel: 0.025, dense: DenseMode::Raycast }
    }
}

impl LabelsConfig {
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("the config serialises")
    }
    /// The config's identity (paths as the config file wrote them): the text the dataset records, its hash
    /// and the hash of the content-determining part (without `shard_size`).
    pub fn identity(&self) -> Result<ConfigIdentity> {
        let content = LabelsConfig { shard_size: 0, ..self.clone() };
        Ok(ConfigIdentity::new(identity_toml(self)?, &identity_toml(&content)?))
    }

    /// Checks ranges before any work starts, naming the key.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, m: &str| Err(Error::config(k, m));
        if self.samples_per_window == 0 || self.samples_per_window > 1000 {
            return bad("samples_per_window", "must be 1..=1000");
        }
        if self.shard_size == 0 || self.shard_size > 100_000 {
            return bad("shard_size", "must be 1..=100000 windows");
        }
        if self.window.frames == 0 || self.window.frames > 10_000 {
            return bad("window.frames", "must be 1..=10000");
        }
        if self.window.stride == 0 {
            return bad("window.stride", "must be at least 1");
        }
        self.tsdf.validate().map_err(|e| match e {
            Error::Config { field, message } => Error::config(format!("tsdf.{field}"), message),
            other => other,
        })?;
        if !(self.clouds.sparse_voxel.is_finite() && self.clouds.sparse_voxel >= 0.001 && self.clouds.sparse_voxel <= 1.0) {
            return bad("clouds.sparse_voxel", "must be 0.001..=1 metres");
        }
        if !(self.tau_gt.is_finite() && self.tau_gt > 0.0 && self.tau_gt < 10.0) {
            return bad("tau_gt", "must be a positive number of metres");
        }
        // The source, working and pose sections follow the build's rules.
        self.source.validate()?;
        self.working.validate()?;
        self.pose.validate()
    }
}

impl ConfigPaths for LabelsConfig {
    fn for_each_path(&mut self, visit: &mut dyn FnMut(&str, &mut PathBuf)) {
        self.source.for_each_path(visit);
    }

    fn checkpoints(&self) -> Vec<(&'static str, crate::nn::ModelPath)> {
        Vec::new()
    }

    fn folder(&self) -> Option<&Path> {
        self.folder.as_deref()
    }

    fn set_folder(&mut self, folder: PathBuf) {
        self.folder = Some(folder);
    }
}
