//! Correct: drop penetrating pixels, on the condition (before inpainting) or on the output (after); and
//! the `[correct]` config section naming the method for each.

use super::PairUnit;
use crate::correction::{apply_keep_mask, CorrectionConfig, Corrector};
use crate::error::Result;
use crate::geometry::DepthMap;
use crate::runtime::Stage;
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
        CorrectConfig { condition: official, output: official }
    }
}

impl CorrectConfig {
    /// Checks both methods (loading U-Net checkpoints); errors name `correct.condition` or `correct.output`.
    pub fn validate(&self) -> Result<()> {
        self.condition.validate("correct.condition")?;
        self.output.validate("correct.output")
    }

    /// The stage correcting `target` (call [`Self::validate`] first).
    pub fn build(&self, target: Target) -> Correct {
        let method = match target {
            Target::Condition => &self.condition,
            Target::Output => &self.output,
        };
        Correct { target, corrector: method.build() }
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
    pub corrector: Box<dyn Corrector>,
}

impl Stage<PairUnit> for Correct {
    fn name(&self) -> &'static str {
        match self.target {
            Target::Condition => "correct_condition",
            Target::Output => "correct_output",
        }
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        match self.target {
            Target::Condition => {
                let depth = unit.condition.as_mut().expect("reproject sets the condition");
                correct_condition(self.corrector.as_ref(), depth, &mut unit.known);
            }
            Target::Output => correct_output(self.corrector.as_ref(), unit.target_depth.as_mut().expect("inpaint sets the target")),
        }
        Ok(())
    }
}

/// Drops the penetrating pixels of a re-projected condition: their depth becomes 0 and they turn unknown.
pub fn correct_condition(corrector: &dyn Corrector, depth: &mut DepthMap, known: &mut [bool]) {
    let keep = corrector.keep_mask(depth);
    apply_keep_mask(depth, known, &keep);
}

/// Drops the pixels of an inpainted output that the corrector rejects (their depth becomes 0).
pub fn correct_output(corrector: &dyn Corrector, depth: &mut DepthMap) {
    let keep = corrector.keep_mask(depth);
    let mut all = vec![true; keep.len()];
    apply_keep_mask(depth, &mut all, &keep);
}
