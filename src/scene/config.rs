//! The `[scene]` section of a build config: which posed frames around a source frame are fused into the
//! scene that `scene` correction and fill ray-cast, and the TSDF they are fused with.

use crate::error::{Error, Result};
use crate::tsdf::TsdfConfig;
use serde::{Deserialize, Serialize};

/// How the scene of a source frame is made (only read when a method is `scene`).
///
/// Source frames are grouped in blocks of `block` consecutive sequence positions (block `b` holds
/// positions `b·block .. (b+1)·block`); every source frame of a block shares one fusion, made once. That
/// fusion takes the posed frames at positions `b·block − reach .. (b+1)·block + reach` that are multiples
/// of `every`, within the span of the selected frames of the sequence (so a build restricted to some
/// frames never reads the frames around them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Source positions that share one fusion.
    pub block: usize,
    /// Frames before and after a block that its fusion takes, in sequence positions.
    pub reach: usize,
    /// Fuse every `every`-th sequence position (1 = every frame).
    pub every: usize,
    /// The volume the frames are fused into (full-resolution frames, their own cameras).
    pub tsdf: TsdfConfig,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig { block: 30, reach: 60, every: 3, tsdf: TsdfConfig::coarse() }
    }
}

impl SceneConfig {
    /// Whether the section holds only defaults (then it is not written into a config's canonical TOML,
    /// so configs made before it existed keep their hashes).
    pub fn is_default(&self) -> bool {
        *self == SceneConfig::default()
    }

    /// Checks ranges; errors name the key under `scene`.
    pub fn validate(&self) -> Result<()> {
        if self.block == 0 || self.block > 100_000 {
            return Err(Error::config("scene.block", "must be 1..=100000 frames"));
        }
        if self.reach > 100_000 {
            return Err(Error::config("scene.reach", "must be 0..=100000 frames"));
        }
        if self.every == 0 || self.every > 1000 {
            return Err(Error::config("scene.every", "must be 1..=1000"));
        }
        self.tsdf.validate().map_err(|e| Error::config("scene.tsdf", e.to_string()))
    }
}
