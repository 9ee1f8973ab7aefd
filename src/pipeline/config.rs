//! The build pipeline's configuration: [`BuildConfig`] nests one section per stage. Each section's
//! struct lives beside the code that uses it (`[source]`/`[select]` in [`crate::sources::catalog`],
//! `[working]` in [`crate::stages::ingest`], `[pose]` in [`crate::stages::pose`], `[correct]` in
//! [`crate::stages::correct`], `[inpaint]` in [`crate::inpainting::config`], `[successive]`,
//! `[voxelize]`, `[validate]` and `[output]` in their stages), with its documented fields, defaults
//! (the official settings, reference §2–§6) and checks.
//!
//! Unknown keys are rejected. [`BuildConfig::validate`] checks every section and names the offending key.
//! Relative paths resolve against the config file's folder ([`crate::config_paths`]).

use crate::config_paths::{identity_toml, ConfigIdentity, ConfigPaths};
use crate::error::{Error, Result};
use crate::inpainting::InpaintConfig;
use crate::nn::ModelPath;
use crate::scene::SceneConfig;
use crate::sources::{SelectConfig, SourceConfig};
use crate::stages::correct::CorrectConfig;
use crate::stages::ingest::WorkingConfig;
use crate::stages::pack::OutputConfig;
use crate::stages::pose::PoseConfig;
use crate::stages::successive::SuccessiveConfig;
use crate::stages::validate::ValidateConfig;
use crate::stages::voxelize::VoxelizeConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    /// For posed sequences: the frames around each source frame fused into the scene that the `scene`
    /// methods of `[correct]` and `[inpaint]` ray-cast. Written out only when not the default.
    #[serde(default, skip_serializing_if = "SceneConfig::is_default")]
    pub scene: SceneConfig,
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
    /// The folder of the config file its relative paths were resolved against (not a key: `None` for a
    /// config made in code, whose relative paths are relative to the working directory).
    #[serde(skip)]
    pub folder: Option<PathBuf>,
}

fn one() -> u32 {
    1
}
fn default_shard_size() -> u64 {
    64
}
fn default_inpaint() -> InpaintConfig {
    InpaintConfig::Background {}
}

/// The settings of the methods of the `[inpaint]` and `[correct.*]` sections (a method not listed has
/// none), for the hint of [`method_setting_hint`]; `tests::setting_lists_match_the_config_types` keeps
/// them equal to the config types' fields.
const METHOD_SETTINGS: [(&str, &[&str]); 6] = [
    ("inpaint method \"diffusion\"", &["checkpoint", "steps", "eta", "start", "start_step", "batch", "resample"]),
    ("correction method \"min_pool\"", &["threshold"]),
    ("correction method \"median\"", &["window", "threshold"]),
    ("correction method \"unet\"", &["checkpoint", "threshold", "preset"]),
    ("correction method \"scene\"", &["margin", "fallback", "fallback_everywhere", "behind_only"]),
    ("inpaint method \"scene\"", &["fallback"]),
];

/// For a config error about an unknown field (`unknown field `steps``), which methods have that setting:
/// a key given beside a method that does not use it (`--set inpaint.steps=5` with `method =
/// "background"`) is refused, and the message says where it belongs.
pub fn method_setting_hint(message: &str) -> Option<String> {
    let key = message.split("unknown field `").nth(1)?.split('`').next()?;
    let owners: Vec<&str> = METHOD_SETTINGS.iter().filter(|(_, keys)| keys.contains(&key)).map(|(m, _)| *m).collect();
    if owners.is_empty() {
        return None;
    }
    Some(format!("`{key}` is a setting of {} only: remove it, or choose that method", owners.join(", ")))
}

/// A config error for `origin`, with [`method_setting_hint`] added when it applies.
pub fn config_error(origin: &str, e: &toml::de::Error) -> Error {
    let message = e.to_string();
    match method_setting_hint(&message) {
        Some(hint) => Error::config(origin, format!("{message}\n{hint}")),
        None => Error::config(origin, message),
    }
}

impl BuildConfig {
    /// Parses TOML text; errors name the offending key.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self> {
        toml::from_str(text).map_err(|e| config_error(origin, &e))
    }

    /// The config as canonical TOML (every default written out).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("the config serialises")
    }

    /// The config's identity ([`crate::config_paths::identity_toml`]: paths as the config file wrote
    /// them, checkpoints by content): the text the dataset records, its hash (a resume must match it) and
    /// the hash of everything that determines a row's content (without `shard_size`, which changes which
    /// file a row lands in, not the row). `output.row_group_rows` is in neither: it changes only how a file
    /// is laid out. Reads the checkpoints.
    pub fn identity(&self) -> Result<ConfigIdentity> {
        let output = OutputConfig { row_group_rows: crate::shards::ROW_GROUP_ROWS, ..self.output.clone() };
        let dataset = BuildConfig { output, ..self.clone() };
        let content = BuildConfig { shard_size: 0, ..dataset.clone() };
        Ok(ConfigIdentity::new(identity_toml(&dataset)?, &identity_toml(&content)?))
    }

    /// Whether a correction or the fill is `scene` (the build then fuses scenes for posed frames).
    pub fn uses_scene(&self) -> bool {
        self.correct.uses_scene() || self.inpaint.is_scene()
    }

    /// Checks every range before any work starts (and that model checkpoints load); the error names the key.
    pub fn validate(&self) -> Result<()> {
        if self.samples_per_frame == 0 || self.samples_per_frame > 10_000 {
            return Err(Error::config("samples_per_frame", "must be 1..=10000"));
        }
        if self.shard_size == 0 || self.shard_size > 100_000 {
            return Err(Error::config("shard_size", "must be 1..=100000 units"));
        }
        self.source.validate()?;
        self.select.validate()?;
        self.working.validate()?;
        self.pose.validate()?;
        self.correct.validate()?;
        self.inpaint.validate("inpaint")?;
        self.scene.validate()?;
        self.successive.validate()?;
        if self.uses_scene() && !self.successive.is_off() {
            return Err(Error::config("successive.views", "successive views do not combine with `scene` methods: use one view per pair"));
        }
        self.output.validate()?;
        self.voxelize.validate()?;
        self.validate.validate()
    }
}

impl ConfigPaths for BuildConfig {
    fn for_each_path(&mut self, visit: &mut dyn FnMut(&str, &mut PathBuf)) {
        self.source.for_each_path(visit);
        self.correct.condition.for_each_path("correct.condition", visit);
        self.inpaint.for_each_path("inpaint", visit);
        self.correct.output.for_each_path("correct.output", visit);
    }

    fn checkpoints(&self) -> Vec<(&'static str, ModelPath)> {
        let c = &self.correct;
        [("correct.condition.checkpoint", c.condition.checkpoint()), ("inpaint.checkpoint", self.inpaint.checkpoint()), ("correct.output.checkpoint", c.output.checkpoint())]
            .into_iter()
            .filter_map(|(k, m)| m.map(|m| (k, m)))
            .collect()
    }

    fn folder(&self) -> Option<&Path> {
        self.folder.as_deref()
    }

    fn set_folder(&mut self, folder: PathBuf) {
        self.folder = Some(folder);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correction::CorrectionConfig;
    use crate::geometry::AxisBox;
    use crate::stages::pose::OverlapTarget;

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
        assert_ne!(c.identity().unwrap().content_hash, s.identity().unwrap().content_hash);
    }

    #[test]
    fn canonical_toml_round_trips_and_shard_size_is_not_content() {
        let c = BuildConfig::from_toml(MINIMAL, "t").unwrap();
        let back = BuildConfig::from_toml(&c.to_toml(), "t").unwrap();
        assert_eq!(back, c);
        let mut d = c.clone();
        d.shard_size = 7;
        let (ic, id) = (c.identity().unwrap(), d.identity().unwrap());
        assert_eq!(ic.content_hash, id.content_hash);
        assert_ne!(ic.dataset_hash, id.dataset_hash);
        // Without paths and checkpoints the identity is the canonical TOML (hashes of older datasets hold).
        assert_eq!(ic.toml, c.to_toml());
        d.seed = 1;
        assert_ne!(ic.content_hash, d.identity().unwrap().content_hash);
    }
}

#[cfg(test)]
mod method_setting_tests {
    use super::*;
    use crate::correction::CorrectionConfig;
    use crate::inpainting::DiffusionInpaintConfig;

    fn keys(v: impl Serialize) -> Vec<String> {
        match toml::Value::try_from(v).unwrap() {
            toml::Value::Table(t) => t.keys().filter(|k| *k != "method").cloned().collect(),
            other => panic!("{other}"),
        }
    }

    #[test]
    fn setting_lists_match_the_config_types() {
        let diffusion = DiffusionInpaintConfig {
            checkpoint: crate::nn::ModelPath::new("m.safetensors"),
            steps: 2,
            eta: 0.0,
            start: Default::default(),
            start_step: 0,
            batch: 2,
            resample: Some(crate::diffusion::sampler::Resample { jump: 2, repeats: 2 }),
        };
        let mut got = keys(InpaintConfig::Diffusion(diffusion));
        let unet = CorrectionConfig::Unet { checkpoint: crate::nn::ModelPath::new("c"), threshold: 0.5, preset: Some(crate::nn::Preset::Tiny) };
        let lists = [
            keys(CorrectionConfig::MinPool { threshold: 0.1 }),
            keys(CorrectionConfig::Median { window: 3, threshold: 0.1 }),
            keys(unet),
        ];
        let lists = [lists[0].clone(), lists[1].clone(), lists[2].clone(), keys(CorrectionConfig::scene(CorrectionConfig::OFFICIAL_MIN_POOL))];
        let mut scene_fill = keys(InpaintConfig::Scene { fallback: Box::new(InpaintConfig::None {}) });
        let mut want: Vec<Vec<String>> = METHOD_SETTINGS.iter().map(|(_, k)| k.iter().map(|s| s.to_string()).collect()).collect();
        want.iter_mut().for_each(|w| w.sort());
        got.sort();
        assert_eq!(got, want[0]);
        for (i, mut l) in lists.into_iter().enumerate() {
            l.sort();
            assert_eq!(l, want[i + 1]);
        }
        scene_fill.sort();
        assert_eq!(scene_fill, want[5]);
        for m in [InpaintConfig::None {}, InpaintConfig::Background {}, InpaintConfig::Nearest {}, InpaintConfig::PushPull {}, InpaintConfig::IpBasic {}] {
            assert!(keys(m).is_empty());
        }
    }

    #[test]
    fn a_setting_beside_a_method_without_it_is_refused_naming_its_method() {
        let base = "[source]\nkind = \"synthetic\"\nscenes = 1\n";
        let e = BuildConfig::from_toml(&format!("{base}[inpaint]\nmethod = \"background\"\nsteps = 5\n"), "t").unwrap_err().to_string();
        assert!(e.contains("steps") && e.contains("diffusion"), "{e}");
        let e = BuildConfig::from_toml(&format!("{base}[correct.condition]\nmethod = \"none\"\nthreshold = 0.1\n"), "t").unwrap_err().to_string();
        assert!(e.contains("threshold") && e.contains("min_pool") && e.contains("unet"), "{e}");
        assert!(BuildConfig::from_toml(&format!("{base}[inpaint]\nmethod = \"background\"\n"), "t").is_ok());
    }
}
