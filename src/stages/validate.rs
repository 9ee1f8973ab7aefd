//! Validate overlap: the radius overlap in both directions and the keep rule.

use super::PairUnit;
use crate::error::Result;
use crate::geometry::overlap;
use crate::pipeline::config::{KeepRule, ValidateConfig};
use crate::runtime::Stage;
use crate::shards::row::Status;

pub struct ValidateOverlap {
    pub config: ValidateConfig,
}

impl Stage<PairUnit> for ValidateOverlap {
    fn name(&self) -> &'static str {
        "validate"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        let c = &self.config;
        let ov = overlap(&unit.source_points, &unit.target_points, &unit.t_target_from_source, c.radius);
        unit.overlap = ov;
        let kept = match c.rule {
            KeepRule::Max => ov.source.max(ov.target) >= c.min_overlap,
            KeepRule::Min => ov.source.min(ov.target) >= c.min_overlap,
        };
        if !kept {
            unit.reject(Status::LowOverlap, format!("overlap {:.4} / {:.4} fails the {:?} rule at {}", ov.source, ov.target, c.rule, c.min_overlap));
        }
        Ok(())
    }
}
