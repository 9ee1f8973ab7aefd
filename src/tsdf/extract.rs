//! Surface points: zero crossings of the TSDF between neighbouring voxels, linearly interpolated.

use super::volume::{TsdfVolume, Voxel};
use crate::geometry::Point;
use rayon::prelude::*;

/// Crossings between a voxel at or beyond this |tsdf| and its neighbour are not surface: a jump from
/// free space (+1) to the back of a surface seen from elsewhere (silhouettes, depth edges).
pub const MAX_CROSSING_TSDF: f32 = 0.99;

/// Where the TSDF crosses zero between voxel values `a` and `b` (different signs), as a fraction of
/// the way from `a` to `b`.
#[inline]
pub(crate) fn crossing(a: f32, b: f32) -> f32 {
    a / (a - b)
}

impl TsdfVolume {
    /// Surface points, metres: for every pair of voxels adjacent along x, y or z whose weights both
    /// exceed `weight_threshold`, whose TSDF values have opposite signs (0 counts as positive) and
    /// both have |tsdf| < [`MAX_CROSSING_TSDF`], the point where the linear interpolation between
    /// their centres is 0. Order: blocks by coordinate (x, then y, then z), then voxels (x fastest),
    /// then the axis (x, y, z); the same volume gives the same points whatever the thread count.
    pub fn extract_points(&self, weight_threshold: f32) -> Vec<Point> {
        let side = self.side;
        let s = self.config.voxel_size_m;
        let per_block: Vec<Vec<Point>> = self
            .sorted_slots()
            .par_iter()
            .map(|&slot| {
                let b = self.coords[slot as usize];
                let nb = self.neighbourhood(b);
                let mut out = Vec::new();
                let usable = |v: &Voxel| v.weight > weight_threshold && v.tsdf.abs() < MAX_CROSSING_TSDF;
                for z in 0..side {
                    for y in 0..side {
                        for x in 0..side {
                            let v = nb.get(x, y, z).expect("own block");
                            if !usable(v) {
                                continue;
                            }
                            let g = [0, 1, 2].map(|a| (b[a] * side as i32) as f32 + [x, y, z][a] as f32 + 0.5);
                            for (axis, n) in
                                [nb.get(x + 1, y, z), nb.get(x, y + 1, z), nb.get(x, y, z + 1)].into_iter().enumerate()
                            {
                                let Some(n) = n.filter(|n| usable(n)) else { continue };
                                if (v.tsdf < 0.0) != (n.tsdf < 0.0) {
                                    let mut p = g;
                                    p[axis] += crossing(v.tsdf, n.tsdf);
                                    out.push(Point::new(p[0] * s, p[1] * s, p[2] * s));
                                }
                            }
                        }
                    }
                }
                out
            })
            .collect();
        per_block.concat()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tsdf::TsdfConfig;

    #[test]
    fn plane_crossings_are_interpolated_exactly_and_ordered() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        // A plane z = 0.2033 m sampled exactly: the linear interpolation is exact for a plane.
        v.set_from_sdf(&Point::new(0.0, 0.0, 0.1), &Point::new(0.159, 0.159, 0.3), 5.0, |p| p.z - 0.2033);
        let pts = v.extract_points(1.0);
        // Voxel centres x, y in 0..=15 (16×16), one crossing along z each.
        assert_eq!(pts.len(), 16 * 16);
        for p in &pts {
            assert!((p.z - 0.2033).abs() < 1e-5, "{p:?}");
        }
        assert_eq!(pts, v.extract_points(1.0));
        // Weight threshold at or above the weight: nothing.
        assert!(v.extract_points(5.0).is_empty());
    }

    #[test]
    fn jumps_from_free_space_are_not_surface() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        // +1 (free space) directly against −0.5: a silhouette artefact, not a surface.
        v.set_from_sdf(&Point::new(0.0, 0.0, 0.0), &Point::new(0.079, 0.079, 0.079), 3.0, |p| {
            if p.x < 0.04 {
                1.0
            } else {
                -0.02
            }
        });
        assert!(v.extract_points(0.0).is_empty());
    }
}
