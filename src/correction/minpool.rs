//! The official hand-crafted occlusion filter: 3×3 minimum over valid neighbours.

use super::Corrector;
use crate::geometry::{valid_min3x3, DepthMap};

/// Drops a pixel whose depth is at least `threshold` metres behind the smallest valid depth in its 3×3
/// neighbourhood (reference §3.3 `occlusion_filter`; the official code *replaces* such depths by that
/// minimum, here they are dropped so the inpainting refills them).
#[derive(Clone, Copy, Debug)]
pub struct MinPoolFilter {
    pub threshold: f32,
}

impl Corrector for MinPoolFilter {
    fn name(&self) -> &'static str {
        "min_pool"
    }

    fn keep_mask(&self, depth: &DepthMap) -> Vec<bool> {
        let mins = valid_min3x3(depth);
        depth.data().iter().zip(&mins).map(|(&z, &m)| !(z > 0.0 && z - m >= self.threshold)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_a_background_point_seen_through_a_hole() {
        // A 1 m surface with one pixel showing the 3 m background: only that pixel is dropped.
        let mut data = vec![1.0f32; 25];
        data[12] = 3.0;
        data[3] = 0.0;
        let d = DepthMap::new(5, 5, data).unwrap();
        let keep = MinPoolFilter { threshold: 0.0375 }.keep_mask(&d);
        assert_eq!(keep.iter().filter(|k| !**k).count(), 1);
        assert!(!keep[12]);
    }
}
