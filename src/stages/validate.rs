//! Validate overlap: the radius overlap in both directions and the keep rule; and the `[validate]`
//! config section.

use super::PairUnit;
use crate::error::{Error, Result};
use crate::geometry::overlap;
use crate::runtime::Stage;
use crate::shards::row::Status;
use serde::{Deserialize, Serialize};

/// Which overlap values must pass the threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KeepRule {
    /// Keep when max(overlap_source, overlap_target) ≥ threshold (official).
    Max,
    /// Keep when both are ≥ threshold.
    Min,
}

/// The overlap check.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidateConfig {
    /// Neighbour radius, metres (official 0.0375 = 1.5 voxels).
    pub radius: f32,
    /// Overlap threshold (official 0.1).
    pub min_overlap: f64,
    /// Which overlaps must pass.
    pub rule: KeepRule,
}

impl Default for ValidateConfig {
    fn default() -> Self {
        ValidateConfig { radius: 0.0375, min_overlap: 0.1, rule: KeepRule::Max }
    }
}

impl ValidateConfig {
    /// Checks ranges; errors name the key under `validate`.
    pub fn validate(&self) -> Result<()> {
        if !(self.radius.is_finite() && self.radius > 0.0 && self.radius <= 1.0) {
            return Err(Error::config("validate.radius", "must be in (0, 1] metres"));
        }
        if !(0.0..=1.0).contains(&self.min_overlap) {
            return Err(Error::config("validate.min_overlap", "must be in [0, 1]"));
        }
        Ok(())
    }

    /// The stage.
    pub fn build(&self) -> ValidateOverlap {
        ValidateOverlap { config: self.clone() }
    }

    /// Whether a pair with these overlaps is kept.
    pub fn keeps(&self, ov: &crate::geometry::Overlap) -> bool {
        match self.rule {
            KeepRule::Max => ov.source.max(ov.target) >= self.min_overlap,
            KeepRule::Min => ov.source.min(ov.target) >= self.min_overlap,
        }
    }
}

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
        if !c.keeps(&ov) {
            unit.reject(Status::LowOverlap, format!("overlap {:.4} / {:.4} fails the {:?} rule at {}", ov.source, ov.target, c.rule, c.min_overlap));
        }
        Ok(())
    }
}
