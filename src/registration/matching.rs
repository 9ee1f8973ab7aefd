//! Correspondences in feature space: each source descriptor's nearest target descriptor, optionally
//! kept only when the match is mutual.

use super::kdtree::KdTree;
use rayon::prelude::*;

/// Rows of `dim` floats.
#[derive(Clone, Debug, PartialEq)]
pub struct Features {
    pub dim: usize,
    pub data: Vec<f32>,
}

impl Features {
    pub fn len(&self) -> usize {
        self.data.len() / self.dim.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    pub fn row(&self, i: usize) -> &[f32] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }

    /// The rows at `indices`, in that order.
    pub fn select(&self, indices: &[usize]) -> Features {
        Features { dim: self.dim, data: indices.iter().flat_map(|&i| self.row(i).iter().copied()).collect() }
    }
}

/// For every source row, the index of its nearest target row (ties to the lower index).
pub fn nearest(source: &Features, target: &Features) -> Vec<u32> {
    assert_eq!(source.dim, target.dim, "descriptor dimensions differ");
    if target.is_empty() {
        return Vec::new();
    }
    let tree = KdTree::new(&target.data, target.dim);
    (0..source.len()).into_par_iter().map(|i| tree.nearest(source.row(i)).expect("non-empty").0).collect()
}

/// Correspondences (source index, target index): every source row with its nearest target row, or with
/// `mutual` only the pairs that are each other's nearest.
pub fn match_features(source: &Features, target: &Features, mutual: bool) -> Vec<(u32, u32)> {
    let forward = nearest(source, target);
    if !mutual {
        return forward.into_iter().enumerate().map(|(i, j)| (i as u32, j)).collect();
    }
    let backward = nearest(target, source);
    forward
        .into_iter()
        .enumerate()
        .filter(|&(i, j)| backward[j as usize] as usize == i)
        .map(|(i, j)| (i as u32, j))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_keeps_only_reciprocal_pairs() {
        let s = Features { dim: 1, data: vec![0.0, 0.1, 5.0] };
        let t = Features { dim: 1, data: vec![0.05, 4.0] };
        assert_eq!(match_features(&s, &t, false), vec![(0, 0), (1, 0), (2, 1)]);
        // Target 0's nearest source is 0 (0.05 < 0.05 ties to the lower index), target 1's is 2.
        assert_eq!(match_features(&s, &t, true), vec![(0, 0), (2, 1)]);
    }
}
