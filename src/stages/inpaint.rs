//! Inpaint: fill the unknown target pixels, keeping the known ones bit-exact.

use super::PairUnit;
use crate::error::Result;
use crate::inpainting::{InpaintContext, Inpainter};
use crate::rng::Rng;
use crate::runtime::Stage;

/// The stream of the unit's generator that stochastic inpainters draw from.
const NOISE_STREAM: u64 = 0x1a9a_1f00;

pub struct Inpaint {
    pub inpainter: Box<dyn Inpainter>,
}

impl Stage<PairUnit> for Inpaint {
    fn name(&self) -> &'static str {
        "inpaint"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let condition = unit.condition.as_ref().expect("reproject sets the condition");
        // A sub-stream of the unit's seed, apart from the pose sampler's.
        let seed = Rng::new(unit.seed).fork(NOISE_STREAM).next_u64();
        let ctx = InpaintContext { intrinsics: unit.k.expect("ingest sets the intrinsics"), seed };
        unit.target_depth = Some(self.inpainter.inpaint(condition, &unit.known, &ctx));
        Ok(())
    }
}
