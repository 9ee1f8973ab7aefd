//! Correct: drop penetrating pixels, on the condition (before inpainting) or on the output (after).

use super::PairUnit;
use crate::correction::{apply_keep_mask, Corrector};
use crate::error::Result;
use crate::geometry::DepthMap;
use crate::runtime::Stage;

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
