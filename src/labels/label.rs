//! The label formula of the correction network (reference §4.2).

use crate::geometry::DepthMap;

/// `M_gt[p] = |I_s[p] − I_d[p]| < τ_gt`, with empty pixels as 0 (the official formula): a pixel empty in
/// both is kept; a sparse depth where the dense map is empty, or more than τ_gt off, is dropped.
/// `true` = keep.
pub fn keep_label(sparse: &DepthMap, dense: &DepthMap, tau_gt: f32) -> Vec<bool> {
    assert_eq!(sparse.data().len(), dense.data().len(), "label maps differ in size");
    sparse.data().iter().zip(dense.data()).map(|(&s, &d)| (s - d).abs() < tau_gt).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn follows_the_reference_cases() {
        let s = DepthMap::new(5, 1, vec![0.0, 2.0, 2.0, 2.0, 0.0]).unwrap();
        let d = DepthMap::new(5, 1, vec![0.0, 0.0, 2.04, 1.5, 1.0]).unwrap();
        // both empty: keep; sparse only: drop; within 5 cm: keep; 50 cm behind: drop; dense only: 0 vs 1 m -> 0.
        assert_eq!(keep_label(&s, &d, 0.05), vec![true, false, true, false, false]);
    }
}
