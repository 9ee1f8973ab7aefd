//! The official hand-crafted occlusion filter: 3×3 minimum over valid neighbours.

use super::Corrector;
use crate::geometry::DepthMap;

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

/// Smallest valid (> 0) depth of each pixel's 3×3 neighbourhood, itself included; `+inf` where none.
pub fn valid_min3x3(depth: &DepthMap) -> Vec<f32> {
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let d = depth.data();
    let v = |z: f32| if z > 0.0 { z } else { f32::INFINITY };
    // Separable: horizontal min, then vertical min.
    let mut horiz = vec![f32::INFINITY; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut m = v(d[r * w + c]);
            if c > 0 {
                m = m.min(v(d[r * w + c - 1]));
            }
            if c + 1 < w {
                m = m.min(v(d[r * w + c + 1]));
            }
            horiz[r * w + c] = m;
        }
    }
    let mut out = vec![f32::INFINITY; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut m = horiz[r * w + c];
            if r > 0 {
                m = m.min(horiz[(r - 1) * w + c]);
            }
            if r + 1 < h {
                m = m.min(horiz[(r + 1) * w + c]);
            }
            out[r * w + c] = m;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn valid_min_matches_brute_force_with_holes() {
        let mut r = Rng::new(4);
        let (w, h) = (23, 17);
        let data: Vec<f32> = (0..w * h).map(|_| if r.uniform() < 0.3 { 0.0 } else { r.uniform_range(0.5, 4.0) as f32 }).collect();
        let d = DepthMap::new(w as u32, h as u32, data.clone()).unwrap();
        let got = valid_min3x3(&d);
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let mut m = f32::INFINITY;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (xx, yy) = (x + dx, y + dy);
                        if xx >= 0 && yy >= 0 && xx < w as i64 && yy < h as i64 {
                            let z = data[(yy * w as i64 + xx) as usize];
                            if z > 0.0 {
                                m = m.min(z);
                            }
                        }
                    }
                }
                assert_eq!(got[(y * w as i64 + x) as usize], m);
            }
        }
    }

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
