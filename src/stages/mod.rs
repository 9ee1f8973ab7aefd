//! The build pipeline's operators, one file each: thin adapters from the pure functions of
//! `geometry`, `correction` and `inpainting` to the runtime's [`Stage`](crate::runtime::Stage) trait.
//!
//! ingest (with the frame cache its workers share) → pose → reproject → [scene] → correct(condition) → inpaint → correct(output) →
//! [successive] → voxelize → validate → pack → sink (scene only when a method is `scene`, successive only
//! when a pair has several target views)

pub mod correct;
pub mod frame_cache;
pub mod ingest;
pub mod inpaint;
pub mod pack;
pub mod pose;
pub mod reproject;
pub mod scene;
pub mod sink;
pub mod successive;
pub mod unit;
pub mod validate;
pub mod voxelize;

pub use unit::PairUnit;

/// Sub-streams of a unit's RNG, one per stage that draws, so adding draws to one stage never shifts
/// another's.
pub mod streams {
    pub const POSE: u64 = 1;
    /// The inpainting noise (its value predates this list; changing it changes every diffusion-filled pair).
    pub const INPAINT: u64 = 0x1a9a_1f00;
}
