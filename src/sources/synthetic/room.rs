//! A room's proportions: the ranges rooms are drawn from ([`SceneConfig`]), and the heights and the
//! camera zone that furniture placement and camera trajectories both respect.

use crate::error::{Error, Result};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Highest top (m above the floor) of anything standing away from the walls: cameras fly above it.
pub const LOW_TOP_M: f64 = 1.05;
/// Deepest reach (m from its wall) of anything that rises above [`LOW_TOP_M`].
pub const WALL_BAND_M: f64 = 0.62;

/// Half extents (m) of the open rectangle, centred in a room of interior `size`, that cameras move in:
/// `L/2 − clamp(0.3·L, 1.2, 1.8)` per horizontal axis. Nothing above [`LOW_TOP_M`] reaches into it
/// and free-standing pieces stand outside it, where the cameras look.
pub fn camera_zone(size: &Vector3<f64>) -> (f64, f64) {
    let half = |l: f64| (l / 2.0 - (0.3 * l).clamp(WALL_BAND_M + 0.58, 1.8)).max(0.0);
    (half(size.x), half(size.y))
}

/// How rooms are drawn. Ranges are `[min, max]`, sampled uniformly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Room extent along world x, metres (at least 2.6 so a camera fits away from the furniture).
    pub room_length_m: [f64; 2],
    /// Room extent along world y, metres (at least 2.6).
    pub room_width_m: [f64; 2],
    /// Floor-to-ceiling height, metres (at least 2.2).
    pub room_height_m: [f64; 2],
    /// Number of furniture pieces against the walls (cabinets, shelves, desks); a piece that finds no
    /// free spot is left out.
    pub wall_pieces: [u32; 2],
    /// Number of pictures, wall cabinets and radiators hanging on the walls; likewise.
    pub wall_fixtures: [u32; 2],
    /// Number of free-standing pieces (tables, crates, stools, balls); likewise.
    pub free_pieces: [u32; 2],
    /// Probability (0–1) that a table, desk, cabinet, crate or stool carries an object on top.
    pub stack_probability: f64,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            room_length_m: [3.0, 7.0],
            room_width_m: [3.0, 7.0],
            room_height_m: [2.4, 3.0],
            wall_pieces: [6, 12],
            wall_fixtures: [4, 10],
            free_pieces: [4, 10],
            stack_probability: 0.6,
        }
    }
}

impl SceneConfig {
    /// Checks ranges: ordered, finite, rooms large enough, probability in [0, 1].
    pub fn validate(&self) -> Result<()> {
        let ranges = [
            ("room_length_m", self.room_length_m, 2.6),
            ("room_width_m", self.room_width_m, 2.6),
            ("room_height_m", self.room_height_m, 2.2),
        ];
        for (field, [lo, hi], least) in ranges {
            if !(lo.is_finite() && hi.is_finite() && lo >= least && lo <= hi && hi <= 100.0) {
                return Err(Error::config(field, format!("needs {least} <= min <= max <= 100 m, got [{lo}, {hi}]")));
            }
        }
        for (field, [lo, hi]) in [("wall_pieces", self.wall_pieces), ("wall_fixtures", self.wall_fixtures), ("free_pieces", self.free_pieces)] {
            if lo > hi || hi > 100 {
                return Err(Error::config(field, format!("needs min <= max <= 100, got [{lo}, {hi}]")));
            }
        }
        if !(0.0..=1.0).contains(&self.stack_probability) {
            return Err(Error::config("stack_probability", "must lie in [0, 1]"));
        }
        Ok(())
    }
}
