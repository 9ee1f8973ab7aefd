//! `InpaintConfig`: the inpainting methods a pipeline config can name (the `[inpaint]` section), their
//! checks and the inpainter each builds.

use super::{Background, DiffusionInpaintConfig, DiffusionInpainter, Inpainter, IpBasic, Nearest, NoInpainting, PushPull};
use serde::{Deserialize, Serialize};

/// The inpainting methods a pipeline config can name. The methods without settings are empty struct
/// variants, not unit variants: serde then refuses a key such as `steps` beside `method = "background"`
/// (it silently ignores extra keys of a unit variant of an internally tagged enum); the config loader
/// adds which method has that setting ([`crate::pipeline::config::method_setting_hint`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum InpaintConfig {
    /// No filling: the target keeps only the re-projected pixels.
    None {},
    /// Classical push–pull pyramid fill (smooth, fast; blends the two sides of a depth edge).
    PushPull {},
    /// Copies the nearest known pixel (exact Euclidean distance).
    Nearest {},
    /// Occlusion-aware: copies the farther of the two hole borders along the epipolar direction of the
    /// camera motion (the uncovered background of a disocclusion).
    Background {},
    /// IP-Basic (Ku et al. 2018): morphological completion of inverted depth (nearer surfaces grow).
    IpBasic {},
    /// The diffusion model with the exact range–null-space step (paper §3.2, reference §5.4).
    Diffusion(DiffusionInpaintConfig),
    /// For posed sequences: unknown pixels where the scene fused from the frames around the source frame
    /// (`[scene]`) shows a surface get its ray-cast depth; `fallback` (any other method) fills the rest,
    /// and fills everything for frames without a pose.
    Scene { fallback: Box<InpaintConfig> },
}

impl InpaintConfig {
    /// Checks the settings (and that a diffusion checkpoint loads); `field` names the config in errors.
    pub fn validate(&self, field: &str) -> crate::Result<()> {
        match self {
            InpaintConfig::Diffusion(c) => c.validate(field),
            InpaintConfig::Scene { fallback } if fallback.is_scene() => Err(crate::Error::config(field, "the fallback of `scene` must be another method")),
            InpaintConfig::Scene { fallback } => fallback.validate(&format!("{field}.fallback")),
            _ => Ok(()),
        }
    }

    /// Whether the method is `scene`.
    pub fn is_scene(&self) -> bool {
        matches!(self, InpaintConfig::Scene { .. })
    }

    /// Calls `visit` on the checkpoint path, if any, as `<field>.checkpoint` (`<field>.fallback.checkpoint`).
    pub fn for_each_path(&mut self, field: &str, visit: &mut dyn FnMut(&str, &mut std::path::PathBuf)) {
        match self {
            InpaintConfig::Diffusion(c) => crate::config_paths::visit_model(visit, &format!("{field}.checkpoint"), &mut c.checkpoint),
            InpaintConfig::Scene { fallback } => fallback.for_each_path(&format!("{field}.fallback"), visit),
            _ => {}
        }
    }

    /// The model file this method reads, if any (the fallback's, for `scene`).
    pub fn checkpoint(&self) -> Option<crate::nn::ModelPath> {
        match self {
            InpaintConfig::Diffusion(c) => Some(c.checkpoint),
            InpaintConfig::Scene { fallback } => fallback.checkpoint(),
            _ => None,
        }
    }

    /// The inpainter this config describes, on the CPU ([`Self::build_on`]).
    pub fn build(&self) -> crate::Result<Box<dyn Inpainter>> {
        self.build_on(tch::Device::Cpu)
    }

    /// The inpainter this config describes (call [`Self::validate`] first), its network (if any) on
    /// `device`; for `scene`, its fallback's (the scene's own fill needs the scene, which
    /// [`crate::stages::inpaint`] pastes first: [`crate::scene::paste_scene`]).
    pub fn build_on(&self, device: tch::Device) -> crate::Result<Box<dyn Inpainter>> {
        Ok(match self {
            InpaintConfig::Scene { fallback } => fallback.build_on(device)?,
            InpaintConfig::None {} => Box::new(NoInpainting),
            InpaintConfig::PushPull {} => Box::new(PushPull),
            InpaintConfig::Nearest {} => Box::new(Nearest),
            InpaintConfig::Background {} => Box::new(Background),
            InpaintConfig::IpBasic {} => Box::new(IpBasic),
            InpaintConfig::Diffusion(c) => Box::new(DiffusionInpainter::load(c, device)?),
        })
    }
}
