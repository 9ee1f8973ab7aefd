//! Median-filter baseline for depth correction.

use super::Corrector;
use crate::geometry::DepthMap;
use rayon::prelude::*;

/// Drops a pixel whose depth is at least `threshold` metres behind the median of the valid depths in its
/// `window`×`window` neighbourhood (itself included).
#[derive(Clone, Copy, Debug)]
pub struct MedianFilter {
    pub window: u32,
    pub threshold: f32,
}

impl Corrector for MedianFilter {
    fn name(&self) -> &'static str {
        "median"
    }

    fn keep_mask(&self, depth: &DepthMap) -> Vec<bool> {
        let (w, h) = (depth.width() as i64, depth.height() as i64);
        let half = (self.window / 2) as i64;
        let d = depth.data();
        (0..h)
            .into_par_iter()
            .flat_map_iter(|r| {
                let mut buf = Vec::with_capacity((self.window * self.window) as usize);
                (0..w).map(move |c| {
                    let z = d[(r * w + c) as usize];
                    if z <= 0.0 {
                        return true;
                    }
                    buf.clear();
                    for y in (r - half).max(0)..=(r + half).min(h - 1) {
                        for x in (c - half).max(0)..=(c + half).min(w - 1) {
                            let v = d[(y * w + x) as usize];
                            if v > 0.0 {
                                buf.push(v);
                            }
                        }
                    }
                    // Lower median of the valid depths.
                    let mid = (buf.len() - 1) / 2;
                    let (_, m, _) = buf.select_nth_unstable_by(mid, f32::total_cmp);
                    z - *m < self.threshold
                })
                .collect::<Vec<_>>()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_isolated_far_pixels_and_keeps_a_step_edge() {
        // Left half 1 m, right half 2 m (a real depth edge), one 3 m outlier inside the left half.
        let (w, h) = (10u32, 8u32);
        let mut data: Vec<f32> = (0..w * h).map(|i| if i % w < 5 { 1.0 } else { 2.0 }).collect();
        data[(3 * w + 2) as usize] = 3.0;
        let d = DepthMap::new(w, h, data).unwrap();
        let keep = MedianFilter { window: 3, threshold: 0.0375 }.keep_mask(&d);
        let dropped: Vec<usize> = keep.iter().enumerate().filter(|(_, k)| !**k).map(|(i, _)| i).collect();
        // Only the outlier goes: a 2 m pixel on the edge sees three 1 m and six 2 m depths (median 2 m).
        assert_eq!(dropped, vec![(3 * w + 2) as usize]);
    }
}
