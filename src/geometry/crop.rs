//! Axis-aligned box crops of point clouds.

use super::Point;
use serde::{Deserialize, Serialize};

/// An axis-aligned box `[min, max]` (inclusive on both ends), metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisBox {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl AxisBox {
    /// The official crop (reference §3.3): x, y ∈ [−1.5, 1.5], z ∈ [0.5, 3.5] m in the camera frame,
    /// the 3DMatch fragment volume.
    pub const OFFICIAL: AxisBox = AxisBox { min: [-1.5, -1.5, 0.5], max: [1.5, 1.5, 3.5] };

    /// Whether `p` lies inside the box.
    pub fn contains(&self, p: &Point) -> bool {
        p.x >= self.min[0]
            && p.x <= self.max[0]
            && p.y >= self.min[1]
            && p.y <= self.max[1]
            && p.z >= self.min[2]
            && p.z <= self.max[2]
    }

    /// The points inside the box, in input order.
    pub fn crop(&self, points: &[Point]) -> Vec<Point> {
        points.iter().filter(|p| self.contains(p)).copied().collect()
    }

    /// The points inside the box with their companions in `with` (one per point), in input order.
    pub fn crop_with<T: Copy>(&self, points: &[Point], with: &[T]) -> (Vec<Point>, Vec<T>) {
        assert_eq!(points.len(), with.len(), "one companion per point");
        points.iter().zip(with).filter(|(p, _)| self.contains(p)).map(|(p, t)| (*p, *t)).unzip()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_inside_and_boundary_points_in_order() {
        let pts = vec![
            Point::new(0.0, 0.0, 1.0),
            Point::new(1.5, -1.5, 3.5),
            Point::new(1.6, 0.0, 1.0),
            Point::new(0.0, 0.0, 0.4),
            Point::new(-1.0, 1.0, 2.0),
        ];
        let c = AxisBox::OFFICIAL.crop(&pts);
        assert_eq!(c, vec![pts[0], pts[1], pts[4]]);
    }
}
