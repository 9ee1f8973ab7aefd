//! Radius-bounded neighbour queries on a uniform grid, and the overlap ratio of two clouds.

use super::{transform_points, Point};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// A uniform-grid index over a point cloud that answers "is there a point within `radius` of q?",
/// "which points are?" and "which one is nearest?".
///
/// The grid spans the cloud's bounding box with cubic cells of edge `max(radius, ...)`, capped at
/// about 8 cells per point, so a query checks at most the 3×3×3 cells around its own. Distances are
/// compared as `|q − p|² < radius²` in f32 (strict, as Open3D's radius search).
pub struct RadiusIndex {
    points: Vec<Point>,
    /// `order[i]`: the index in the input cloud of `points[i]` (the points are stored by cell).
    order: Vec<u32>,
    starts: Vec<u32>,
    origin: [f32; 3],
    dims: [usize; 3],
    inv_cell: f32,
    radius2: f32,
}

impl RadiusIndex {
    /// Builds the index; `radius` must be positive.
    pub fn new(points: &[Point], radius: f32) -> Self {
        assert!(radius.is_finite() && radius > 0.0, "radius must be positive, got {radius}");
        if points.is_empty() {
            return RadiusIndex { points: Vec::new(), order: Vec::new(), starts: vec![0, 0], origin: [0.0; 3], dims: [1, 1, 1], inv_cell: 1.0, radius2: radius * radius };
        }
        let mut lo = [f32::MAX; 3];
        let mut hi = [f32::MIN; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let extent = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let max_cells = (points.len() as f64 * 8.0).max(4096.0);
        let mut cell = radius as f64;
        let cells_at = |c: f64| extent.iter().map(|e| (*e as f64 / c).floor() + 1.0).product::<f64>();
        if cells_at(cell) > max_cells {
            let volume: f64 = extent.iter().map(|e| *e as f64 + radius as f64).product();
            cell = cell.max((volume / max_cells).cbrt());
            while cells_at(cell) > max_cells {
                cell *= 1.1;
            }
        }
        let inv_cell = (1.0 / cell) as f32;
        let dims = [0, 1, 2].map(|a| (extent[a] * inv_cell).floor() as usize + 1);
        let cell_of = |p: &Point| -> usize {
            let gx = (((p.x - lo[0]) * inv_cell) as usize).min(dims[0] - 1);
            let gy = (((p.y - lo[1]) * inv_cell) as usize).min(dims[1] - 1);
            let gz = (((p.z - lo[2]) * inv_cell) as usize).min(dims[2] - 1);
            (gx * dims[1] + gy) * dims[2] + gz
        };
        let ids: Vec<u32> = points.iter().map(|p| cell_of(p) as u32).collect();
        let ncells = dims[0] * dims[1] * dims[2];
        let mut starts = vec![0u32; ncells + 1];
        for &c in &ids {
            starts[c as usize + 1] += 1;
        }
        for i in 0..ncells {
            starts[i + 1] += starts[i];
        }
        let mut fill = starts.clone();
        let mut sorted = vec![Point::origin(); points.len()];
        let mut order = vec![0u32; points.len()];
        for (i, (p, &c)) in points.iter().zip(&ids).enumerate() {
            sorted[fill[c as usize] as usize] = *p;
            order[fill[c as usize] as usize] = i as u32;
            fill[c as usize] += 1;
        }
        RadiusIndex { points: sorted, order, starts, origin: lo, dims, inv_cell, radius2: radius * radius }
    }

    /// Calls `visit(index in the input cloud, squared distance)` for every indexed point strictly within
    /// the radius of `q`, in storage order, until `visit` returns false.
    fn visit_within(&self, q: &Point, mut visit: impl FnMut(usize, f32) -> bool) {
        if self.points.is_empty() {
            return;
        }
        let mut range = [(0usize, 0usize); 3];
        for a in 0..3 {
            let g = ((q[a] - self.origin[a]) * self.inv_cell).floor();
            if !(g >= -1.0 && g <= self.dims[a] as f32) {
                return; // more than one cell outside the box: nothing within the radius
            }
            let g = g as i64;
            range[a] = ((g - 1).max(0) as usize, ((g + 1).min(self.dims[a] as i64 - 1)) as usize);
            if range[a].0 > range[a].1 {
                return;
            }
        }
        for gx in range[0].0..=range[0].1 {
            for gy in range[1].0..=range[1].1 {
                let base = (gx * self.dims[1] + gy) * self.dims[2];
                let (s, e) = (self.starts[base + range[2].0] as usize, self.starts[base + range[2].1 + 1] as usize);
                for (p, &i) in self.points[s..e].iter().zip(&self.order[s..e]) {
                    let d = (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) + (p.z - q.z) * (p.z - q.z);
                    if d < self.radius2 && !visit(i as usize, d) {
                        return;
                    }
                }
            }
        }
    }

    /// Whether some indexed point lies strictly within the radius of `q`.
    pub fn has_neighbor(&self, q: &Point) -> bool {
        let mut found = false;
        self.visit_within(q, |_, _| {
            found = true;
            false
        });
        found
    }

    /// The input-cloud indices of the points strictly within the radius of `q` (in no particular order).
    pub fn within(&self, q: &Point, out: &mut Vec<usize>) {
        out.clear();
        self.visit_within(q, |i, _| {
            out.push(i);
            true
        });
    }

    /// The input-cloud index and distance of the point nearest to `q` among those strictly within the
    /// radius (ties: the lower index).
    pub fn nearest(&self, q: &Point) -> Option<(usize, f32)> {
        let mut best: Option<(usize, f32)> = None;
        self.visit_within(q, |i, d| {
            if best.is_none_or(|(j, e)| d < e || (d == e && i < j)) {
                best = Some((i, d));
            }
            true
        });
        best.map(|(i, d)| (i, d.sqrt()))
    }

    /// How many of `queries` have a neighbour within the radius.
    pub fn count_with_neighbor(&self, queries: &[Point]) -> usize {
        queries.par_chunks(4096).map(|c| c.iter().filter(|q| self.has_neighbor(q)).count()).sum()
    }
}

/// Overlap of two clouds: the fraction of each cloud's points that have a neighbour in the other
/// within the radius, after moving the source into the target frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Overlap {
    /// Fraction of source points with a target neighbour (0 when the source is empty).
    pub source: f64,
    /// Fraction of target points with a source neighbour (0 when the target is empty).
    pub target: f64,
}

/// [`Overlap`] of `source` (in its own frame) and `target` under `t_target_from_source`.
pub fn overlap(source: &[Point], target: &[Point], t_target_from_source: &Isometry3<f64>, radius: f32) -> Overlap {
    let moved = transform_points(source, t_target_from_source);
    let (n_source, n_target) = rayon::join(
        || RadiusIndex::new(target, radius).count_with_neighbor(&moved),
        || RadiusIndex::new(&moved, radius).count_with_neighbor(target),
    );
    let ratio = |n: usize, d: usize| if d == 0 { 0.0 } else { n as f64 / d as f64 };
    Overlap { source: ratio(n_source, source.len()), target: ratio(n_target, target.len()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use nalgebra::Vector3;

    fn brute_count(queries: &[Point], points: &[Point], r: f32) -> usize {
        queries
            .iter()
            .filter(|q| points.iter().any(|p| (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) + (p.z - q.z) * (p.z - q.z) < r * r))
            .count()
    }

    fn cloud(r: &mut Rng, n: usize, offset: f64) -> Vec<Point> {
        (0..n)
            .map(|_| Point::new((r.uniform_range(-1.0, 1.0) + offset) as f32, r.uniform_range(-1.0, 1.0) as f32, r.uniform_range(1.0, 1.2) as f32))
            .collect()
    }

    #[test]
    fn within_and_nearest_equal_brute_force() {
        let mut r = Rng::new(4);
        let points = cloud(&mut r, 3000, 0.0);
        let queries = cloud(&mut r, 300, 0.3);
        let d2 = |p: &Point, q: &Point| (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) + (p.z - q.z) * (p.z - q.z);
        for radius in [0.03f32, 0.1, 0.4] {
            let index = RadiusIndex::new(&points, radius);
            let mut got = Vec::new();
            for q in &queries {
                index.within(q, &mut got);
                got.sort_unstable();
                let want: Vec<usize> = (0..points.len()).filter(|&i| d2(&points[i], q) < radius * radius).collect();
                assert_eq!(got, want);
                let nearest = want.iter().copied().min_by(|&a, &b| d2(&points[a], q).total_cmp(&d2(&points[b], q)).then(a.cmp(&b)));
                assert_eq!(index.nearest(q).map(|(i, _)| i), nearest);
            }
        }
    }

    #[test]
    fn overlap_is_exact_against_brute_force() {
        let mut r = Rng::new(9);
        for (n, m, offset, radius) in [(2000, 1500, 0.0, 0.0375f32), (3000, 3000, 1.0, 0.05), (500, 4000, 0.5, 0.2), (100, 100, 5.0, 0.0375)] {
            let s = cloud(&mut r, n, 0.0);
            let t = cloud(&mut r, m, offset);
            let pose = Isometry3::new(Vector3::new(0.02, -0.01, 0.0), Vector3::new(0.0, 0.0, 0.03));
            let ov = overlap(&s, &t, &pose, radius);
            let moved = transform_points(&s, &pose);
            assert_eq!(ov.source, brute_count(&moved, &t, radius) as f64 / n as f64);
            assert_eq!(ov.target, brute_count(&t, &moved, radius) as f64 / m as f64);
        }
    }

    #[test]
    fn identical_clouds_overlap_fully_and_empty_gives_zero() {
        let mut r = Rng::new(1);
        let s = cloud(&mut r, 1000, 0.0);
        let ov = overlap(&s, &s, &Isometry3::identity(), 0.01);
        assert_eq!((ov.source, ov.target), (1.0, 1.0));
        let ov = overlap(&s, &[], &Isometry3::identity(), 0.01);
        assert_eq!((ov.source, ov.target), (0.0, 0.0));
    }

    #[test]
    fn coarse_grid_cap_still_exact() {
        // Two tiny clusters 100 m apart force cells much larger than the radius.
        let mut r = Rng::new(2);
        let mut pts = cloud(&mut r, 300, 0.0);
        pts.extend(cloud(&mut r, 300, 100.0));
        let q = cloud(&mut r, 2000, 0.0);
        let idx = RadiusIndex::new(&pts, 0.01);
        assert_eq!(idx.count_with_neighbor(&q), brute_count(&q, &pts, 0.01));
    }
}
