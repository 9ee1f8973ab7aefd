//! Re-project: z-buffer the scene memory into the sampled target camera.

use super::PairUnit;
use crate::error::Result;
use crate::geometry::project_zbuffer;
use crate::runtime::Stage;

/// Produces the condition depth and its known-pixel mask.
pub struct Reproject;

impl Stage<PairUnit> for Reproject {
    fn name(&self) -> &'static str {
        "reproject"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let k = unit.k.expect("ingest sets the intrinsics");
        let proj = project_zbuffer(&unit.memory, &unit.t_target_from_source, &k, false);
        unit.condition = Some(proj.depth);
        unit.known = proj.known;
        Ok(())
    }
}
