//! [`TsdfConfig`]: voxel size, truncation, depth range, block size and weight cap of a TSDF volume.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// Parameters of a [`super::TsdfVolume`]. The default is the 3DMatch fragment fusion
/// (`3dmatch-toolbox/depth-fusion`): 6 mm voxels, 3 cm (5-voxel) truncation, depths in (0, 6] m.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TsdfConfig {
    /// Edge length of a voxel, metres. Voxel `i` along an axis spans `[i·s, (i+1)·s)` (origin at 0),
    /// its centre is at `(i + ½)·s`.
    pub voxel_size_m: f32,
    /// Truncation distance, metres: a voxel `z` metres deep along the optical axis of a pixel whose
    /// depth is `d` receives `tsdf = min(1, (d − z)/truncation)` when `d − z ≥ −truncation`
    /// (positive in front of the surface, as in KinectFusion and Open3D) and nothing otherwise.
    pub truncation_m: f32,
    /// Depths at or below this are ignored, metres (exclusive lower bound).
    pub min_depth_m: f32,
    /// Depths above this are ignored, metres (inclusive upper bound).
    pub max_depth_m: f32,
    /// Voxels along each side of a hashed block (a block holds `block_side³` voxels), 1–32.
    pub block_side: u32,
    /// Largest weight a voxel can accumulate (observations, each counting 1); once reached, the
    /// running average becomes a moving average. At least 1.
    pub max_weight: f32,
}

impl Default for TsdfConfig {
    fn default() -> Self {
        TsdfConfig::threedmatch()
    }
}

impl TsdfConfig {
    /// The 3DMatch fusion: voxel 6 mm, truncation 3 cm (5 voxels), depths (0, 6] m, 8³ blocks.
    pub fn threedmatch() -> Self {
        TsdfConfig {
            voxel_size_m: 0.006,
            truncation_m: 0.03,
            min_depth_m: 0.0,
            max_depth_m: 6.0,
            block_side: 8,
            max_weight: 255.0,
        }
    }

    /// A coarse, fast volume: voxel 1 cm, truncation 4 cm, depths (0, 6] m, 8³ blocks.
    pub fn coarse() -> Self {
        TsdfConfig { voxel_size_m: 0.01, truncation_m: 0.04, ..TsdfConfig::threedmatch() }
    }

    /// The Open3D fragment fusion often used for 3DMatch (`ScalableTSDFVolume(voxel_length = 3/512 m,
    /// sdf_trunc = 0.04 m)`, `depth_trunc = 6 m`): voxel ≈ 5.86 mm, truncation 4 cm.
    pub fn open3d_fragments() -> Self {
        TsdfConfig { voxel_size_m: 3.0 / 512.0, truncation_m: 0.04, ..TsdfConfig::threedmatch() }
    }

    /// Edge length of a block, metres (`block_side · voxel_size_m`).
    pub fn block_size_m(&self) -> f32 {
        self.block_side as f32 * self.voxel_size_m
    }

    /// Checks every field; the error names the first invalid one.
    pub fn validate(&self) -> Result<()> {
        let finite_positive = |v: f32| v.is_finite() && v > 0.0;
        if !(finite_positive(self.voxel_size_m) && self.voxel_size_m <= 1.0) {
            return Err(Error::config("voxel_size_m", format!("must be in (0, 1] m, got {}", self.voxel_size_m)));
        }
        if !(self.truncation_m.is_finite()
            && self.truncation_m >= self.voxel_size_m
            && self.truncation_m <= 64.0 * self.voxel_size_m)
        {
            return Err(Error::config(
                "truncation_m",
                format!("must be between 1 and 64 voxels ({} m), got {} m", self.voxel_size_m, self.truncation_m),
            ));
        }
        if !(self.min_depth_m.is_finite() && self.min_depth_m >= 0.0) {
            return Err(Error::config("min_depth_m", format!("must be finite and >= 0, got {}", self.min_depth_m)));
        }
        if !(self.max_depth_m.is_finite() && self.max_depth_m > self.min_depth_m && self.max_depth_m <= 1000.0) {
            return Err(Error::config(
                "max_depth_m",
                format!(
                    "must be above min_depth_m ({}) and at most 1000 m, got {}",
                    self.min_depth_m, self.max_depth_m
                ),
            ));
        }
        if !(1..=32).contains(&self.block_side) {
            return Err(Error::config("block_side", format!("must be 1..=32 voxels, got {}", self.block_side)));
        }
        if !(self.max_weight.is_finite() && self.max_weight >= 1.0) {
            return Err(Error::config("max_weight", format!("must be finite and >= 1, got {}", self.max_weight)));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_default_is_the_3dmatch_fusion() {
        let d = TsdfConfig::default();
        assert_eq!(
            (d.voxel_size_m, d.truncation_m, d.min_depth_m, d.max_depth_m, d.block_side),
            (0.006, 0.03, 0.0, 6.0, 8)
        );
        assert!((d.truncation_m / d.voxel_size_m - 5.0).abs() < 1e-5);
        assert!((d.block_size_m() - 0.048).abs() < 1e-7);
        for c in [TsdfConfig::threedmatch(), TsdfConfig::coarse(), TsdfConfig::open3d_fragments()] {
            c.validate().unwrap();
        }
        assert_eq!((TsdfConfig::coarse().voxel_size_m, TsdfConfig::coarse().truncation_m), (0.01, 0.04));
    }

    #[test]
    fn validate_names_the_field() {
        let bad = |f: fn(&mut TsdfConfig), field: &str| {
            let mut c = TsdfConfig::default();
            f(&mut c);
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(&format!("`{field}`")), "{e}");
        };
        bad(|c| c.voxel_size_m = 0.0, "voxel_size_m");
        bad(|c| c.voxel_size_m = f32::NAN, "voxel_size_m");
        bad(|c| c.truncation_m = 0.001, "truncation_m");
        bad(|c| c.truncation_m = 1.0, "truncation_m");
        bad(|c| c.min_depth_m = -1.0, "min_depth_m");
        bad(|c| c.max_depth_m = 0.0, "max_depth_m");
        bad(|c| c.block_side = 0, "block_side");
        bad(|c| c.block_side = 33, "block_side");
        bad(|c| c.max_weight = 0.5, "max_weight");
    }

    #[test]
    fn serde_denies_unknown_fields_and_fills_defaults() {
        let c: TsdfConfig = toml::from_str("voxel_size_m = 0.01\ntruncation_m = 0.04").unwrap();
        assert_eq!(c, TsdfConfig::coarse());
        let e = toml::from_str::<TsdfConfig>("voxel = 0.01").unwrap_err().to_string();
        assert!(e.contains("unknown field"), "{e}");
    }
}
