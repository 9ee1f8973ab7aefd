//! `CorrectionConfig`: the correction methods a pipeline config can name, their checks, and the corrector
//! each builds.

use super::{Corrector, MedianFilter, MinPoolFilter, NoCorrection, UnetCorrector};
use serde::{Deserialize, Serialize};

/// The correction methods a pipeline config can name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum CorrectionConfig {
    /// Keep every pixel. (An empty struct variant, so that serde refuses settings beside it.)
    None {},
    /// The official hand-crafted filter: drop a pixel at least `threshold` metres behind the nearest
    /// valid depth of its 3×3 neighbourhood (official 0.0375 m).
    MinPool { threshold: f32 },
    /// Baseline: drop a pixel at least `threshold` metres behind the median valid depth of its
    /// `window`×`window` neighbourhood.
    Median { window: u32, threshold: f32 },
    /// The trained correction U-Net (reference §4): drop a pixel whose keep probability is at most
    /// `threshold` (τ_m, official 0.99). `checkpoint` is a safetensors file (`pointreggpt train
    /// correction`, or the authors' converted weights; in a config file relative to the file's folder) or
    /// a built-in model (`builtin:models/correction-tiny.safetensors`); `preset`, when given, must match
    /// the checkpoint's.
    Unet {
        checkpoint: crate::nn::ModelPath,
        threshold: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        preset: Option<crate::nn::Preset>,
    },
    /// For posed sequences: the scene fused from the frames around the source frame (`[scene]`), ray-cast
    /// at the target pose, decides by the correction labels' rule (drop a pixel `margin` metres or more off
    /// the fused surface: τ_gt, official 0.05); where the scene saw no surface, and for frames without a
    /// pose, `fallback` decides (any other method). With `fallback_everywhere` (the default), the fallback
    /// also drops pixels where the scene saw a surface (a pixel is dropped when either says so): on
    /// redkitchen's tune frames it kept half the penetrating pixels of either alone (58 per map against
    /// 141 for the scene's rule alone and 116 for min-pool) and 2 % fewer pixels in all
    /// (docs/lab/2026-12-07-scene-targets.md). By default only pixels behind the surface are dropped
    /// (`behind_only`).
    Scene {
        margin: f32,
        fallback: Box<CorrectionConfig>,
        #[serde(default = "yes")]
        fallback_everywhere: bool,
        /// Drop only the pixels behind the scene's surface (penetrating it), keep those in front of it
        /// (the default): the scene may not have seen a nearer surface (its rays pass through space no
        /// frame observed). On the tune frames it kept as few penetrating pixels as the two-sided rule
        /// (within 3 %) and 2 % more pixels, and scored 3.5–5 mIoU points higher on tune labels.
        #[serde(default = "yes")]
        behind_only: bool,
    },
}

fn yes() -> bool {
    true
}

/// How a `scene` correction decides where the scene saw a surface ([`crate::scene::scene_keep_mask`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneRule {
    /// Drop a pixel this far (metres) or more off the scene's surface.
    pub margin: f32,
    /// Also drop the pixels the fallback drops where the scene saw a surface.
    pub fallback_everywhere: bool,
    /// Drop only pixels behind the scene's surface, not those in front of it.
    pub behind_only: bool,
}

impl CorrectionConfig {
    /// The official hand-crafted filter: min-pool at 3.75 cm (reference §3.3).
    pub const OFFICIAL_MIN_POOL: CorrectionConfig = CorrectionConfig::MinPool { threshold: 0.0375 };

    /// The scene method with the official label margin (τ_gt 0.05 m) over `fallback`, with the defaults:
    /// the fallback everywhere, only pixels behind the scene's surface dropped.
    pub fn scene(fallback: CorrectionConfig) -> CorrectionConfig {
        CorrectionConfig::Scene { margin: 0.05, fallback: Box::new(fallback), fallback_everywhere: true, behind_only: true }
    }

    /// The scene's rule when the method is `scene`.
    pub fn scene_rule(&self) -> Option<SceneRule> {
        match self {
            CorrectionConfig::Scene { margin, fallback_everywhere, behind_only, .. } => {
                Some(SceneRule { margin: *margin, fallback_everywhere: *fallback_everywhere, behind_only: *behind_only })
            }
            _ => None,
        }
    }

    /// The model file this method reads, if any (the fallback's, for `scene`).
    pub fn checkpoint(&self) -> Option<crate::nn::ModelPath> {
        match self {
            CorrectionConfig::Unet { checkpoint, .. } => Some(*checkpoint),
            CorrectionConfig::Scene { fallback, .. } => fallback.checkpoint(),
            _ => None,
        }
    }

    /// Calls `visit` on the checkpoint path, if any, as `<field>.checkpoint` (`<field>.fallback.checkpoint`).
    pub fn for_each_path(&mut self, field: &str, visit: &mut dyn FnMut(&str, &mut std::path::PathBuf)) {
        match self {
            CorrectionConfig::Unet { checkpoint, .. } => crate::config_paths::visit_model(visit, &format!("{field}.checkpoint"), checkpoint),
            CorrectionConfig::Scene { fallback, .. } => fallback.for_each_path(&format!("{field}.fallback"), visit),
            _ => {}
        }
    }

    /// Checks parameter ranges; `field` names the config key in errors.
    pub fn validate(&self, field: &str) -> crate::Result<()> {
        let bad = |m: &str| Err(crate::Error::config(field, m));
        match self {
            CorrectionConfig::Scene { fallback, .. } if fallback.scene_rule().is_some() => bad("the fallback of `scene` must be another method"),
            CorrectionConfig::Scene { margin, .. } if !(*margin > 0.0 && margin.is_finite()) => bad("margin must be a positive number of metres"),
            CorrectionConfig::Scene { fallback, .. } => fallback.validate(&format!("{field}.fallback")),
            CorrectionConfig::None {} => Ok(()),
            CorrectionConfig::MinPool { threshold } | CorrectionConfig::Median { threshold, .. } if !(*threshold > 0.0 && threshold.is_finite()) => {
                bad("threshold must be a positive number of metres")
            }
            CorrectionConfig::Median { window, .. } if *window < 3 || window % 2 == 0 || *window > 15 => bad("window must be odd, 3..=15"),
            CorrectionConfig::Unet { threshold, .. } if !(*threshold > 0.0 && *threshold < 1.0) => bad("threshold must be a keep probability in (0, 1)"),
            CorrectionConfig::Unet { checkpoint, preset, .. } => {
                let (_, net, _) = crate::nn::load_correction(checkpoint.as_path(), tch::Device::Cpu)
                    .map_err(|e| crate::Error::config(field, format!("checkpoint `{checkpoint}`: {e}")))?;
                match preset {
                    Some(p) if net.config.preset != Some(*p) => bad(&format!("checkpoint `{checkpoint}` is not the `{}` preset", p.as_str())),
                    _ => Ok(()),
                }
            }
            _ => Ok(()),
        }
    }

    /// The corrector this config describes, on the CPU ([`Self::build_on`]).
    pub fn build(&self) -> Box<dyn Corrector> {
        self.build_on(tch::Device::Cpu)
    }

    /// The corrector this config describes, its network (if any) on `device`; for `scene`, its fallback's
    /// (the scene's own rule needs the scene, which [`crate::stages::correct`] applies on top:
    /// [`crate::scene::scene_keep_mask`]).
    pub fn build_on(&self, device: tch::Device) -> Box<dyn Corrector> {
        match *self {
            CorrectionConfig::Scene { ref fallback, .. } => fallback.build_on(device),
            CorrectionConfig::None {} => Box::new(NoCorrection),
            CorrectionConfig::MinPool { threshold } => Box::new(MinPoolFilter { threshold }),
            CorrectionConfig::Median { window, threshold } => Box::new(MedianFilter { window, threshold }),
            // `validate` loads the checkpoint first, so this only fails if the file changed in between.
            CorrectionConfig::Unet { checkpoint, threshold, .. } => Box::new(
                UnetCorrector::load(checkpoint.as_path(), threshold, device)
                    .unwrap_or_else(|e| panic!("correction checkpoint `{checkpoint}` (validated before the build): {e}")),
            ),
        }
    }
}
