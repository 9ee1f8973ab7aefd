//! Correct: drop penetrating pixels, on the condition (before inpainting) or on the output (after).

use super::PairUnit;
use crate::correction::{apply_keep_mask, Corrector};
use crate::error::Result;
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
                let keep = self.corrector.keep_mask(depth);
                apply_keep_mask(depth, &mut unit.known, &keep);
            }
            Target::Output => {
                let depth = unit.target_depth.as_mut().expect("inpaint sets the target");
                let keep = self.corrector.keep_mask(depth);
                let mut all = vec![true; keep.len()];
                apply_keep_mask(depth, &mut all, &keep);
            }
        }
        Ok(())
    }
}
