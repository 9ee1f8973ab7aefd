//! Fixed-radius neighbour search in 3D on a uniform grid: "is there a point within the radius?", "which
//! points are?", "which one is nearest?" and Open3D's hybrid search (the `max_nn` nearest within the
//! radius, for normals and FPFH, where it is several times faster than a k-d tree's k-nearest search).

use super::Point;
use rayon::prelude::*;

/// Cap on the grid's cells per indexed point (a sparse cloud in a large box gets cells larger than the
/// radius rather than a huge grid; answers stay exact).
const MAX_CELLS_PER_POINT: f64 = 64.0;

/// A uniform-grid index over a point cloud that answers "is there a point within `radius` of q?",
/// "which points are?" and "which one is nearest?".
///
/// The grid spans the cloud's bounding box with cubic cells of edge `max(radius, ...)`, capped at
/// about [`MAX_CELLS_PER_POINT`] cells per point, so a query checks at most the 3×3×3 cells around its own. Distances are
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
        let max_cells = (points.len() as f64 * MAX_CELLS_PER_POINT).max(4096.0);
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

    /// The `max_nn` nearest indexed points strictly within the radius of `q`, as (input-cloud index,
    /// squared distance) sorted by distance, ties by the lower index (Open3D's hybrid search, the same
    /// answers as the k-d tree's `hybrid`); `out` is cleared first.
    pub fn hybrid(&self, q: &Point, max_nn: usize, out: &mut Vec<(u32, f32)>) {
        out.clear();
        if max_nn == 0 {
            return;
        }
        self.visit_within(q, |i, d| {
            out.push((i as u32, d));
            true
        });
        let cmp = |a: &(u32, f32), b: &(u32, f32)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
        if out.len() > max_nn {
            out.select_nth_unstable_by(max_nn - 1, cmp);
            out.truncate(max_nn);
        }
        out.sort_unstable_by(cmp);
    }

    /// How many of `queries` have a neighbour within the radius.
    pub fn count_with_neighbor(&self, queries: &[Point]) -> usize {
        queries.par_chunks(4096).map(|c| c.iter().filter(|q| self.has_neighbor(q)).count()).sum()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rng::Rng;

    /// How many `queries` have a point within `r` (brute force; also used by the overlap tests).
    pub(crate) fn brute_count(queries: &[Point], points: &[Point], r: f32) -> usize {
        queries
            .iter()
            .filter(|q| points.iter().any(|p| (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) + (p.z - q.z) * (p.z - q.z) < r * r))
            .count()
    }

    /// `n` random points in a 2 m × 2 m × 0.2 m slab 1 m ahead, shifted by `offset` along x.
    pub(crate) fn cloud(r: &mut Rng, n: usize, offset: f64) -> Vec<Point> {
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
    fn hybrid_equals_brute_force() {
        // Points on a few planes (a layered cloud, many equal distances along z) and random queries.
        let mut rng = Rng::new(9);
        let pts: Vec<Point> = (0..3000)
            .map(|_| Point::new(rng.uniform() as f32 - 0.5, rng.uniform() as f32 * 2.0, (rng.uniform() as f32 * 20.0).floor() * 0.05))
            .collect();
        let d2 = |p: &Point, q: &Point| (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) + (p.z - q.z) * (p.z - q.z);
        let mut got = Vec::new();
        for radius in [0.05f32, 0.1] {
            let index = RadiusIndex::new(&pts, radius);
            for q in pts.iter().step_by(7) {
                let mut want: Vec<(u32, f32)> = (0..pts.len()).filter(|&i| d2(&pts[i], q) < radius * radius).map(|i| (i as u32, d2(&pts[i], q))).collect();
                want.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                for nn in [0, 1, 10, 100] {
                    index.hybrid(q, nn, &mut got);
                    assert_eq!(got, want[..want.len().min(nn)]);
                }
            }
        }
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
