//! Inpaint: fill the unknown target pixels, keeping the known ones bit-exact.

use super::PairUnit;
use crate::error::Result;
use crate::inpainting::Inpainter;
use crate::runtime::Stage;

pub struct Inpaint {
    pub inpainter: Box<dyn Inpainter>,
}

impl Stage<PairUnit> for Inpaint {
    fn name(&self) -> &'static str {
        "inpaint"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let condition = unit.condition.as_ref().expect("reproject sets the condition");
        unit.target_depth = Some(self.inpainter.inpaint(condition, &unit.known));
        Ok(())
    }
}
