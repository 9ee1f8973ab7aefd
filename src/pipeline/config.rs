//! The build pipeline's configuration: one struct per stage, nested under [`BuildConfig`].
//!
//! Every field is documented with its unit; defaults are the official settings (reference §2–§6).
//! Unknown keys are rejected. [`BuildConfig::validate`] checks ranges and names the offending key.

use crate::correction::CorrectionConfig;
use crate::error::{Error, Result};
use crate::geometry::{AxisBox, DepthRange, PivotPoseSampler};
use crate::inpainting::InpaintConfig;
use crate::sources::synthetic::SyntheticConfig;
use crate::sources::Layout;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The whole build pipeline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildConfig {
    /// Build seed: every unit's seed is a hash of (seed, frame key, sample index).
    #[serde(default)]
    pub seed: u64,
    /// Target views (pairs) drawn per source frame.
    #[serde(default = "one")]
    pub samples_per_frame: u32,
    /// Work units per shard. Fixed for a dataset (it defines which units each shard holds).
    #[serde(default = "default_shard_size")]
    pub shard_size: u64,
    /// Where the frames come from.
    pub source: SourceConfig,
    /// Which frames of each sequence become sources.
    #[serde(default)]
    pub select: SelectConfig,
    /// Working resolution, depth range and crop box.
    #[serde(default)]
    pub working: WorkingConfig,
    /// How the target camera pose is drawn.
    #[serde(default)]
    pub pose: PoseConfig,
    /// Depth correction of the re-projected condition and of the inpainted output.
    #[serde(default)]
    pub correct: CorrectConfig,
    /// How unknown target pixels are filled.
    #[serde(default = "default_inpaint")]
    pub inpaint: InpaintConfig,
    /// The official "successive" mode: several target views per pair sharing a growing scene memory,
    /// fused into one target cloud. Off (one view) by default, as in the authors' dataset generation.
    #[serde(default, skip_serializing_if = "SuccessiveConfig::is_off")]
    pub successive: SuccessiveConfig,
    /// Point-cloud voxelization and the minimum size of a cloud.
    #[serde(default)]
    pub voxelize: VoxelizeConfig,
    /// The overlap check that decides whether a pair is kept.
    #[serde(default)]
    pub validate: ValidateConfig,
    /// What each row stores besides the clouds.
    #[serde(default)]
    pub output: OutputConfig,
}

fn one() -> u32 {
    1
}
fn default_shard_size() -> u64 {
    64
}
fn default_inpaint() -> InpaintConfig {
    InpaintConfig::PushPull
}

/// Frame sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceConfig {
    /// Procedural indoor scenes rendered in memory (the exact oracle).
    Synthetic {
        /// Number of scenes (seeds `first_seed`, `first_seed + 1`, ...).
        scenes: u32,
        /// Seed of the first scene.
        #[serde(default)]
        first_seed: u64,
        /// Scene, sensor, intrinsics and trajectory length of every scene.
        #[serde(default)]
        synthetic: SyntheticConfig,
    },
    /// Depth sequences on disk.
    Directory {
        /// Folder holding the sequences (relative paths are relative to the working directory).
        path: PathBuf,
        /// Folder layout; `auto` decides from marker files.
        #[serde(default = "auto_layout")]
        layout: Layout,
    },
}

fn auto_layout() -> Layout {
    Layout::Auto
}

/// Frame selection within each sequence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SelectConfig {
    /// Take every `every`-th frame (50 = the first frame of each 50-frame 3DMatch fragment).
    pub every: usize,
    /// Index of the first frame taken.
    pub offset: usize,
    /// At most this many frames per sequence (0 = no limit).
    pub max_per_sequence: usize,
}

impl Default for SelectConfig {
    fn default() -> Self {
        SelectConfig { every: 1, offset: 0, max_per_sequence: 0 }
    }
}

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

    /// A frame's depth and intrinsics at the working resolution: the official resize and centre crop,
    /// intrinsics mapped as `intrinsics` says.
    pub fn map_frame(&self, frame: &crate::sources::Frame) -> Result<(crate::geometry::DepthMap, crate::geometry::Intrinsics)> {
        let k0 = &frame.intrinsics;
        let rc = crate::geometry::ResizeCrop::official(k0.width, k0.height, self.size)?;
        let k = match self.intrinsics {
            IntrinsicsMap::Official => rc.official_intrinsics(k0)?,
            IntrinsicsMap::Exact => rc.exact_intrinsics(k0)?,
        };
        Ok((frame.depth.resize_crop(&rc)?, k))
    }
}

/// Pose sampling: the official pivot sampler, optionally steered towards a target overlap histogram.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseConfig {
    /// Largest rotation about the camera x axis, degrees (official 7.5).
    pub max_pitch_deg: f64,
    /// Largest rotation about the camera y axis, degrees (official 15).
    pub max_yaw_deg: f64,
    /// Distance of the pivot ahead of the source camera, metres (official 3).
    pub pivot_distance: f64,
    /// Standard deviation of the lateral x/y jitter, metres (official 1/3).
    pub lateral_sigma: f64,
    /// When set, redraw poses until the cheap coverage estimate falls in the bin assigned to the unit.
    pub target: Option<OverlapTarget>,
}

impl Default for PoseConfig {
    fn default() -> Self {
        let p = PivotPoseSampler::default();
        PoseConfig {
            max_pitch_deg: p.max_pitch.to_degrees(),
            max_yaw_deg: p.max_yaw.to_degrees(),
            pivot_distance: p.pivot_distance,
            lateral_sigma: p.lateral_sigma,
            target: None,
        }
    }
}

impl PoseConfig {
    pub fn pivot_sampler(&self) -> PivotPoseSampler {
        PivotPoseSampler {
            max_pitch: self.max_pitch_deg.to_radians(),
            max_yaw: self.max_yaw_deg.to_radians(),
            pivot_distance: self.pivot_distance,
            lateral_sigma: self.lateral_sigma,
        }
    }
}

/// A target overlap histogram: each unit is assigned a bin (by its seed, with the given weights), and
/// poses are redrawn until the estimated overlap falls in that bin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OverlapTarget {
    /// Bin edges of the overlap ratio, increasing, in [0, 1] (e.g. [0.1, 0.3, 1.0] for 3DLoMatch + 3DMatch).
    pub bin_edges: Vec<f64>,
    /// Relative share of pairs wanted in each bin (one fewer than the edges).
    pub weights: Vec<f64>,
    /// Most poses drawn per unit; the closest draw is kept when none lands in the bin.
    #[serde(default = "default_max_draws")]
    pub max_draws: u32,
}

fn default_max_draws() -> u32 {
    32
}

/// The correction applied to the condition (before inpainting) and to the output (after).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrectConfig {
    pub condition: CorrectionConfig,
    pub output: CorrectionConfig,
}

impl Default for CorrectConfig {
    fn default() -> Self {
        let official = CorrectionConfig::OFFICIAL_MIN_POOL;
        CorrectConfig { condition: official, output: official }
    }
}

/// The official `num_samples > 1` generation (reference §2, §3.3): the pair's target is several views at
/// independently drawn poses (each relative to the source camera); every view is re-projected from a scene
/// memory that holds the source points and the views generated so far (voxel-downsampled), corrected and
/// inpainted like the first, and the views are fused into one target cloud in the first view's camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SuccessiveConfig {
    /// Target views fused into the target cloud (1 = off, one view per pair).
    pub views: u32,
    /// Voxel of the scene memory after each view is added, metres (official `memory_voxel_size` 0.002).
    pub memory_voxel: f32,
}

impl SuccessiveConfig {
    pub fn is_off(&self) -> bool {
        self.views <= 1
    }
}

impl Default for SuccessiveConfig {
    fn default() -> Self {
        SuccessiveConfig { views: 1, memory_voxel: 0.002 }
    }
}

/// Voxelization of both clouds (each in its own camera frame, after the crop box).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VoxelizeConfig {
    /// Voxel edge, metres (official 0.025).
    pub voxel: f32,
    /// A pair is rejected (`too_few_points`) when either cloud has fewer points (official 1000).
    pub min_points: usize,
}

impl Default for VoxelizeConfig {
    fn default() -> Self {
        VoxelizeConfig { voxel: 0.025, min_points: 1000 }
    }
}

/// Which overlap values must pass the threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeepRule {
    /// Keep when max(overlap_source, overlap_target) ≥ threshold (official).
    Max,
    /// Keep when both are ≥ threshold.
    Min,
}

/// The overlap check.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidateConfig {
    /// Neighbour radius, metres (official 0.0375 = 1.5 voxels).
    pub radius: f32,
    /// Overlap threshold (official 0.1).
    pub min_overlap: f64,
    /// Which overlaps must pass.
    pub rule: KeepRule,
}

impl Default for ValidateConfig {
    fn default() -> Self {
        ValidateConfig { radius: 0.0375, min_overlap: 0.1, rule: KeepRule::Max }
    }
}

/// What each row stores besides the clouds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// Store the source, condition and target depth maps and the known mask as PNG bytes.
    pub depth_maps: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig { depth_maps: true }
    }
}

impl BuildConfig {
    /// Parses TOML text; errors name the offending key.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| Error::config(origin, e.to_string()))
    }

    /// The config as canonical TOML (every default written out).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("the config serialises")
    }

    /// blake3 of everything that determines a row's content (the canonical TOML without `shard_size`),
    /// hex. The shard size changes which file a row lands in, not the row.
    pub fn content_hash(&self) -> String {
        let mut c = self.clone();
        c.shard_size = 0;
        blake3::hash(c.to_toml().as_bytes()).to_hex().to_string()
    }

    /// blake3 of the whole resolved config (the dataset's identity: a resume must match it), hex.
    pub fn dataset_hash(&self) -> String {
        blake3::hash(self.to_toml().as_bytes()).to_hex().to_string()
    }

    /// Checks every range before any work starts; the error names the key.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, m: &str| Err(Error::config(k, m));
        if self.samples_per_frame == 0 || self.samples_per_frame > 10_000 {
            return bad("samples_per_frame", "must be 1..=10000");
        }
        if self.shard_size == 0 || self.shard_size > 100_000 {
            return bad("shard_size", "must be 1..=100000 units");
        }
        match &self.source {
            SourceConfig::Synthetic { scenes, synthetic, .. } => {
                if *scenes == 0 || *scenes > 1_000_000 {
                    return bad("source.scenes", "must be 1..=1000000");
                }
                if synthetic.frames == 0 || synthetic.frames > 100_000 {
                    return bad("source.synthetic.frames", "must be 1..=100000");
                }
                synthetic.scene.validate()?;
                synthetic.sensor.validate()?;
                synthetic.intrinsics.validate().map_err(|e| Error::config("source.synthetic.intrinsics", e.to_string()))?;
            }
            SourceConfig::Directory { path, .. } => {
                if path.as_os_str().is_empty() {
                    return bad("source.path", "must name a folder");
                }
            }
        }
        if self.select.every == 0 {
            return bad("select.every", "must be at least 1");
        }
        let w = &self.working;
        if w.size < 16 || w.size > 4096 {
            return bad("working.size", "must be 16..=4096 pixels");
        }
        let [near, far] = w.depth_range;
        if !(near >= 0.0 && far > near && far.is_finite()) {
            return bad("working.depth_range", "must be [near, far] metres with 0 <= near < far");
        }
        if (0..3).any(|a| !(w.crop_box.min[a] < w.crop_box.max[a]) || !w.crop_box.min[a].is_finite() || !w.crop_box.max[a].is_finite()) {
            return bad("working.crop_box", "min must be below max on every axis");
        }
        let p = &self.pose;
        for (k, v) in [("pose.max_pitch_deg", p.max_pitch_deg), ("pose.max_yaw_deg", p.max_yaw_deg)] {
            if !(0.0..=90.0).contains(&v) {
                return bad(k, "must be 0..=90 degrees");
            }
        }
        if !(p.pivot_distance.is_finite() && p.pivot_distance >= 0.0 && p.pivot_distance < 100.0) {
            return bad("pose.pivot_distance", "must be 0..100 metres");
        }
        if !(p.lateral_sigma.is_finite() && p.lateral_sigma >= 0.0 && p.lateral_sigma < 10.0) {
            return bad("pose.lateral_sigma", "must be 0..10 metres");
        }
        if let Some(t) = &p.target {
            let e = &t.bin_edges;
            if e.len() < 2 || e.windows(2).any(|w| !(w[0] < w[1])) || e[0] < 0.0 || e[e.len() - 1] > 1.0 {
                return bad("pose.target.bin_edges", "must be at least two increasing values in [0, 1]");
            }
            if t.weights.len() != e.len() - 1 || t.weights.iter().any(|w| !(*w >= 0.0 && w.is_finite())) || t.weights.iter().sum::<f64>() <= 0.0 {
                return bad("pose.target.weights", "needs one non-negative weight per bin (edges - 1), not all zero");
            }
            if t.max_draws == 0 || t.max_draws > 10_000 {
                return bad("pose.target.max_draws", "must be 1..=10000");
            }
        }
        self.correct.condition.validate("correct.condition")?;
        self.correct.output.validate("correct.output")?;
        self.inpaint.validate("inpaint")?;
        let sv = &self.successive;
        if sv.views == 0 || sv.views > 64 {
            return bad("successive.views", "must be 1..=64");
        }
        if !(sv.memory_voxel.is_finite() && sv.memory_voxel >= 0.0005 && sv.memory_voxel <= 0.1) {
            return bad("successive.memory_voxel", "must be 0.0005..=0.1 metres");
        }
        let v = &self.voxelize;
        if !(v.voxel.is_finite() && v.voxel >= 0.001 && v.voxel <= 1.0) {
            return bad("voxelize.voxel", "must be 0.001..=1 metres");
        }
        let val = &self.validate;
        if !(val.radius.is_finite() && val.radius > 0.0 && val.radius <= 1.0) {
            return bad("validate.radius", "must be in (0, 1] metres");
        }
        if !(0.0..=1.0).contains(&val.min_overlap) {
            return bad("validate.min_overlap", "must be in [0, 1]");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = "[source]\nkind = \"synthetic\"\nscenes = 2\n";

    #[test]
    fn defaults_are_the_official_settings() {
        let c = BuildConfig::from_toml(MINIMAL, "test").unwrap();
        c.validate().unwrap();
        assert_eq!(c.working.size, 256);
        assert_eq!(c.working.crop_box, AxisBox::OFFICIAL);
        assert_eq!(c.voxelize.voxel, 0.025);
        assert_eq!(c.voxelize.min_points, 1000);
        assert_eq!(c.validate.radius, 0.0375);
        assert_eq!(c.validate.min_overlap, 0.1);
        assert!((c.pose.max_pitch_deg - 7.5).abs() < 1e-12 && (c.pose.max_yaw_deg - 15.0).abs() < 1e-12);
        assert_eq!(c.correct.condition, CorrectionConfig::MinPool { threshold: 0.0375 });
    }

    #[test]
    fn unknown_keys_and_bad_ranges_name_the_field() {
        let e = BuildConfig::from_toml(&format!("{MINIMAL}[voxelize]\nvoxle = 0.02\n"), "p.toml").unwrap_err().to_string();
        assert!(e.contains("voxle"), "{e}");
        let mut c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        c.voxelize.voxel = -1.0;
        assert!(c.validate().unwrap_err().to_string().contains("voxelize.voxel"));
        let mut c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        c.working.size = 100_000;
        assert!(c.validate().unwrap_err().to_string().contains("working.size"));
        let mut c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        c.pose.target = Some(OverlapTarget { bin_edges: vec![0.5, 0.2], weights: vec![1.0], max_draws: 4 });
        assert!(c.validate().unwrap_err().to_string().contains("pose.target.bin_edges"));
        let mut c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        c.successive.views = 0;
        assert!(c.validate().unwrap_err().to_string().contains("successive.views"));
        c.successive = SuccessiveConfig { views: 4, memory_voxel: 0.0 };
        assert!(c.validate().unwrap_err().to_string().contains("successive.memory_voxel"));
    }

    #[test]
    fn single_view_configs_serialise_without_a_successive_table() {
        // Datasets made before successive views existed keep their canonical TOML and hashes.
        let c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        assert!(!c.to_toml().contains("successive"));
        let s = BuildConfig::from_toml(&format!("{MINIMAL}[successive]\nviews = 3\n"), "t").unwrap();
        assert!(s.to_toml().contains("[successive]"));
        assert_ne!(c.content_hash(), s.content_hash());
    }

    #[test]
    fn canonical_toml_round_trips_and_shard_size_is_not_content() {
        let c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        let back = BuildConfig::from_toml(&c.to_toml(), "t").unwrap();
        assert_eq!(back, c);
        let mut d = c.clone();
        d.shard_size = 7;
        assert_eq!(c.content_hash(), d.content_hash());
        assert_ne!(c.dataset_hash(), d.dataset_hash());
        d.seed = 1;
        assert_ne!(c.content_hash(), d.content_hash());
    }
}
