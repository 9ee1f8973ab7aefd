//! A static 3-d tree over points for exact nearest-neighbour distances (median splits, pruned search).

use super::Point;

/// The points, reordered so every subtree is a contiguous slice split at its median on one axis.
pub struct KdTree {
    points: Vec<[f32; 3]>,
}

impl KdTree {
    pub fn new(points: &[Point]) -> Self {
        let mut points: Vec<[f32; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        build(&mut points, 0);
        KdTree { points }
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The Euclidean distance from `q` to the nearest point (∞ for an empty tree).
    pub fn nearest_distance(&self, q: [f32; 3]) -> f32 {
        let mut best = f32::INFINITY;
        search(&self.points, 0, q, &mut best);
        best.sqrt()
    }
}

fn build(points: &mut [[f32; 3]], axis: usize) {
    if points.len() <= 1 {
        return;
    }
    let mid = points.len() / 2;
    points.select_nth_unstable_by(mid, |a, b| a[axis].total_cmp(&b[axis]));
    let (lo, hi) = points.split_at_mut(mid);
    build(lo, (axis + 1) % 3);
    build(&mut hi[1..], (axis + 1) % 3);
}

/// Updates `best` (a squared distance) with the points of the subtree `points` split on `axis`.
fn search(points: &[[f32; 3]], axis: usize, q: [f32; 3], best: &mut f32) {
    if points.is_empty() {
        return;
    }
    let mid = points.len() / 2;
    let p = points[mid];
    let d2 = (0..3).map(|i| (p[i] - q[i]) * (p[i] - q[i])).sum::<f32>();
    if d2 < *best {
        *best = d2;
    }
    let diff = q[axis] - p[axis];
    let (near, far) = if diff < 0.0 { (&points[..mid], &points[mid + 1..]) } else { (&points[mid + 1..], &points[..mid]) };
    search(near, (axis + 1) % 3, q, best);
    if diff * diff < *best {
        search(far, (axis + 1) % 3, q, best);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn nearest_distances_match_brute_force() {
        let mut r = Rng::new(2);
        let mut p = |s: f64| Point::new(r.uniform_range(-s, s) as f32, r.uniform_range(-s, s) as f32, r.uniform_range(0.0, s) as f32);
        let cloud: Vec<Point> = (0..500).map(|_| p(1.0)).collect();
        let queries: Vec<Point> = (0..200).map(|_| p(1.5)).collect();
        let tree = KdTree::new(&cloud);
        for q in &queries {
            let brute = cloud.iter().map(|c| ((c.x - q.x).powi(2) + (c.y - q.y).powi(2) + (c.z - q.z).powi(2)).sqrt()).fold(f32::INFINITY, f32::min);
            assert_eq!(tree.nearest_distance([q.x, q.y, q.z]), brute);
        }
        assert_eq!(KdTree::new(&[]).nearest_distance([0.0; 3]), f32::INFINITY);
    }
}
