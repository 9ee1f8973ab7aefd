//! Neighbourhood filters over depth maps shared by the correction filters and the correction network's
//! DepthAugment input.

use super::DepthMap;

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
}
