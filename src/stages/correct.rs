//! Correct: drop penetrating pixels, on the condition (before inpainting) or on the output (after); and
//! the `[correct]` config section naming the method for each.

use super::PairUnit;
use crate::correction::{apply_keep_mask, CorrectionConfig, Corrector, SceneRule};
use crate::error::Result;
use crate::geometry::DepthMap;
use crate::runtime::Stage;
use crate::scene::scene_keep_mask;
use serde::{Deserialize, Serialize};

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
        CorrectConfig { condition: official.clone(), output: official }
    }
}

impl CorrectConfig {
    /// Checks both methods (loading U-Net checkpoints); errors name `correct.condition` or `correct.output`.
    pub fn validate(&self) -> Result<()> {
        self.condition.validate("correct.condition")?;
        self.output.validate("correct.output")
    }

    /// The stage correcting `target` (call [`Self::validate`] first), its network (if any) on `device`.
    pub fn build(&self, target: Target, device: tch::Device) -> Correct {
        let method = match target {
            Target::Condition => &self.condition,
            Target::Output => &self.output,
        };
        Correct { target, corrector: method.build_on(device), scene_rule: method.scene_rule() }
    }

    /// Whether either correction is `scene`.
    pub fn uses_scene(&self) -> bool {
        self.condition.scene_rule().is_some() || self.output.scene_rule().is_some()
    }
}

/// Which map a correction stage works on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The re-projected condition; dropped pixels become unknown, so inpainting refills them.
    Condition,
    /// The inpainted output; dropped pixels become empty.
    Output,
}

pub struct Correct {
    pub target: Target,
    /// The method's corrector (for `scene`, its fallback's).
    pub corrector: Box<dyn Corrector>,
    /// For `scene`: the scene's rule, applied where the unit has a scene.
    pub scene_rule: Option<SceneRule>,
}

impl Stage<PairUnit> for Correct {
    fn name(&self) -> &'static str {
        match self.target {
            Target::Condition => "correct_condition",
            Target::Output => "correct_output",
        }
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let scene = self.scene_rule.and_then(|r| unit.scene_depth.as_ref().map(|s| (s, r)));
        match self.target {
            Target::Condition => {
                let depth = unit.condition.as_mut().expect("reproject sets the condition");
                correct_condition(self.corrector.as_ref(), scene, depth, &mut unit.known);
            }
            Target::Output => correct_output(self.corrector.as_ref(), scene, unit.target_depth.as_mut().expect("inpaint sets the target")),
        }
        Ok(())
    }
}

/// The pixels of `depth` to keep: `corrector`'s mask, or, given a scene (its depth from the same camera
/// and its rule), the scene's decision where it has a surface ([`scene_keep_mask`]).
pub fn keep_mask(corrector: &dyn Corrector, scene: Option<(&DepthMap, SceneRule)>, depth: &DepthMap) -> Vec<bool> {
    let keep = corrector.keep_mask(depth);
    match scene {
        Some((scene, rule)) => scene_keep_mask(depth, scene, rule, &keep),
        None => keep,
    }
}

/// Drops the penetrating pixels of a re-projected condition ([`keep_mask`]): their depth becomes 0 and
/// they turn unknown.
pub fn correct_condition(corrector: &dyn Corrector, scene: Option<(&DepthMap, SceneRule)>, depth: &mut DepthMap, known: &mut [bool]) {
    let keep = keep_mask(corrector, scene, depth);
    apply_keep_mask(depth, known, &keep);
}

/// Drops the pixels of an inpainted output that [`keep_mask`] rejects (their depth becomes 0).
pub fn correct_output(corrector: &dyn Corrector, scene: Option<(&DepthMap, SceneRule)>, depth: &mut DepthMap) {
    let keep = keep_mask(corrector, scene, depth);
    let mut all = vec![true; keep.len()];
    apply_keep_mask(depth, &mut all, &keep);
}
