//! Subsampling pairs so that their overlap histogram matches another set's: the real pairs of C1 drawn
//! to the generated pairs' overlap distribution, at a given count or as many as the scarcest bin allows.

use crate::registration::evaluate::sample_indices;
use crate::rng::Rng;

/// Overlap bin edges: 10 % wide from 10 % (the validate stage's and the benchmark's minimum) to 100 %.
pub const EDGES: [f64; 10] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0 + 1e-9];

/// The bin of `x` (`edges[b] ≤ x < edges[b + 1]`), none outside.
pub fn bin_of(x: f64, edges: &[f64]) -> Option<usize> {
    (0..edges.len().saturating_sub(1)).find(|&b| edges[b] <= x && x < edges[b + 1])
}

/// Counts per bin.
pub fn histogram(values: &[f64], edges: &[f64]) -> Vec<usize> {
    let mut h = vec![0; edges.len().saturating_sub(1)];
    values.iter().filter_map(|&v| bin_of(v, edges)).for_each(|b| h[b] += 1);
    h
}

/// `total` split over bins in proportion to `weights` by largest remainders (ties: the lower bin).
pub fn quotas(weights: &[usize], total: usize) -> Vec<usize> {
    let sum: usize = weights.iter().sum();
    if sum == 0 {
        return vec![0; weights.len()];
    }
    let exact: Vec<f64> = weights.iter().map(|&w| total as f64 * w as f64 / sum as f64).collect();
    let mut q: Vec<usize> = exact.iter().map(|e| e.floor() as usize).collect();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| (exact[b] - q[b] as f64).total_cmp(&(exact[a] - q[a] as f64)).then(a.cmp(&b)));
    let short = total - q.iter().sum::<usize>();
    order.iter().take(short).for_each(|&b| q[b] += 1);
    q
}

/// What [`match_histogram`] chose.
#[derive(Clone, Debug, PartialEq)]
pub struct Matched {
    /// Indices into the candidates, ascending.
    pub indices: Vec<usize>,
    /// Pairs wanted per bin (the reference histogram scaled to the count reached).
    pub quotas: Vec<usize>,
    /// Whether the count asked for was reached (false: the scarcest bin limited it).
    pub complete: bool,
}

/// Indices of at most `n` of `candidates` (overlaps) whose histogram over `edges` is the reference's
/// (`reference` overlaps) scaled to the count: the largest count ≤ `n` whose largest-remainder quotas
/// every bin can fill, drawn per bin without replacement from `rng`.
pub fn match_histogram(candidates: &[f64], reference: &[f64], edges: &[f64], n: usize, rng: &mut Rng) -> Matched {
    let want = histogram(reference, edges);
    let mut by_bin: Vec<Vec<usize>> = vec![Vec::new(); want.len()];
    for (i, &c) in candidates.iter().enumerate() {
        if let Some(b) = bin_of(c, edges) {
            by_bin[b].push(i);
        }
    }
    let mut count = n;
    let q = loop {
        let q = quotas(&want, count);
        if count == 0 || q.iter().zip(&by_bin).all(|(q, have)| *q <= have.len()) {
            break q;
        }
        count -= 1;
    };
    let mut indices: Vec<usize> = Vec::new();
    for (b, have) in by_bin.iter().enumerate() {
        indices.extend(sample_indices(have.len(), q[b], &mut rng.fork(b as u64)).into_iter().map(|k| have[k]));
    }
    indices.sort_unstable();
    Matched { complete: indices.len() == n, indices, quotas: q }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quotas_by_hand() {
        assert_eq!(quotas(&[1, 1, 1], 10), vec![4, 3, 3]);
        assert_eq!(quotas(&[3, 0, 1], 8), vec![6, 0, 2]);
        assert_eq!(quotas(&[0, 0], 5), vec![0, 0]);
    }

    #[test]
    fn matches_the_reference_shape_and_stops_at_the_scarcest_bin() {
        let edges = [0.0, 0.5, 1.0];
        // Reference: 3 low for every high. Candidates: 100 low (0.2), 10 high (0.7).
        let reference: Vec<f64> = [0.1, 0.2, 0.3, 0.8].repeat(5);
        let candidates: Vec<f64> = std::iter::repeat(0.2).take(100).chain(std::iter::repeat(0.7).take(10)).collect();
        let m = match_histogram(&candidates, &reference, &edges, 20, &mut Rng::new(1));
        assert!(m.complete);
        let low = m.indices.iter().filter(|&&i| i < 100).count();
        assert_eq!((low, m.indices.len() - low), (15, 5));
        // 60 asked: 45 + 15 would need 15 high pairs. 42 gives 31.5 + 10.5, rounded 32 + 10 (the tie to
        // the lower bin): feasible; 43 gives 32.25 + 10.75 → 32 + 11: not.
        let m = match_histogram(&candidates, &reference, &edges, 60, &mut Rng::new(1));
        assert!(!m.complete);
        assert_eq!(m.indices.len(), 42);
        assert_eq!(m.indices.iter().filter(|&&i| i >= 100).count(), 10);
        let mut dedup = m.indices.clone();
        dedup.dedup();
        assert_eq!(dedup, m.indices, "no pair twice");
    }
}
