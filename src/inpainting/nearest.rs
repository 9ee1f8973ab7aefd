//! Nearest-valid-pixel fill: every unknown pixel copies the depth of the known pixel nearest to it in
//! Euclidean pixel distance (exact, by the separable distance transform of Felzenszwalb & Huttenlocher).

use super::{InpaintContext, Inpainter};
use crate::geometry::DepthMap;

/// Copies the nearest known depth into each unknown pixel. Never blends two surfaces, so it makes no
/// flying point, but the copy stays constant across the hole (a slanted surface gets a step).
#[derive(Clone, Copy, Debug, Default)]
pub struct Nearest;

impl Inpainter for Nearest {
    fn name(&self) -> &'static str {
        "nearest"
    }

    fn inpaint(&self, depth: &DepthMap, known: &[bool], _: &InpaintContext) -> DepthMap {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let d = depth.data();
        let sources: Vec<bool> = d.iter().zip(known).map(|(z, k)| *k && *z > 0.0).collect();
        let nearest = nearest_source_indices(&sources, w, h);
        let out = (0..w * h)
            .map(|j| if known[j] { d[j] } else { nearest[j].map_or(0.0, |i| d[i]) })
            .collect();
        DepthMap::new(depth.width(), depth.height(), out).expect("copies of valid depths are valid")
    }
}

/// For every pixel of a row-major `w`×`h` grid, the index of a `source` pixel at the least Euclidean
/// distance (itself when it is a source; `None` when there is no source). Ties go to the smaller column,
/// then the smaller row.
pub fn nearest_source_indices(source: &[bool], w: usize, h: usize) -> Vec<Option<usize>> {
    // Pass 1, per column: the nearest source row (squared distance, row).
    let mut col_d2 = vec![f64::INFINITY; w * h];
    let mut col_row = vec![0usize; w * h];
    for c in 0..w {
        let mut last: Option<usize> = None;
        for r in 0..h {
            if source[r * w + c] {
                last = Some(r);
            }
            if let Some(s) = last {
                col_d2[r * w + c] = ((r - s) * (r - s)) as f64;
                col_row[r * w + c] = s;
            }
        }
        let mut next: Option<usize> = None;
        for r in (0..h).rev() {
            if source[r * w + c] {
                next = Some(r);
            }
            if let Some(s) = next {
                let d2 = ((s - r) * (s - r)) as f64;
                if d2 < col_d2[r * w + c] {
                    col_d2[r * w + c] = d2;
                    col_row[r * w + c] = s;
                }
            }
        }
    }
    // Pass 2, per row: the lower envelope of the parabolas (c − q)² + col_d2[q].
    let mut out = vec![None; w * h];
    let (mut v, mut z) = (vec![0usize; w], vec![0f64; w + 1]);
    for r in 0..h {
        let f = &col_d2[r * w..(r + 1) * w];
        let mut k: Option<usize> = None;
        for q in 0..w {
            if !f[q].is_finite() {
                continue;
            }
            let Some(mut kk) = k else {
                k = Some(0);
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                continue;
            };
            let meet = |p: usize| ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
            let mut s = meet(v[kk]);
            // z[0] is −∞, so the walk stops at the first parabola at the latest.
            while s <= z[kk] {
                kk -= 1;
                s = meet(v[kk]);
            }
            kk += 1;
            v[kk] = q;
            z[kk] = s;
            z[kk + 1] = f64::INFINITY;
            k = Some(kk);
        }
        if k.is_none() {
            continue;
        }
        let mut kk = 0;
        for c in 0..w {
            while z[kk + 1] < c as f64 {
                kk += 1;
            }
            let q = v[kk];
            out[r * w + c] = Some(col_row[r * w + q] * w + q);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn the_chosen_source_is_at_the_brute_force_least_distance() {
        let mut rng = Rng::new(11);
        for (w, h, share) in [(23usize, 17usize, 0.05), (31, 9, 0.3), (8, 40, 0.01), (12, 12, 0.0)] {
            let source: Vec<bool> = (0..w * h).map(|_| rng.uniform() < share).collect();
            let got = nearest_source_indices(&source, w, h);
            for j in 0..w * h {
                let (r, c) = ((j / w) as i64, (j % w) as i64);
                let best = (0..w * h)
                    .filter(|i| source[*i])
                    .map(|i| ((i / w) as i64 - r).pow(2) + ((i % w) as i64 - c).pow(2))
                    .min();
                match (best, got[j]) {
                    (None, None) => {}
                    (Some(b), Some(i)) => {
                        assert!(source[i], "pixel {j} copies a non-source {i}");
                        let d2 = ((i / w) as i64 - r).pow(2) + ((i % w) as i64 - c).pow(2);
                        assert_eq!(d2, b, "pixel {j} of {w}x{h}");
                    }
                    other => panic!("pixel {j}: {other:?}"),
                }
            }
        }
    }

    #[test]
    fn a_hole_between_two_depths_splits_at_its_middle() {
        // Left half 1 m, right half 3 m, columns 4..12 unknown: columns 4..8 copy 1 m, 8..12 copy 3 m.
        let (w, h) = (16u32, 3u32);
        let data: Vec<f32> = (0..w * h).map(|i| if i % w < 8 { 1.0 } else { 3.0 }).collect();
        let known: Vec<bool> = (0..w * h).map(|i| !(4..12).contains(&(i % w))).collect();
        let d = DepthMap::new(w, h, data).unwrap();
        let out = Nearest.inpaint(&d, &known, &super::super::test_context(&d));
        for i in 0..(w * h) as usize {
            let c = i as u32 % w;
            assert_eq!(out.data()[i], if c < 8 { 1.0 } else { 3.0 }, "column {c}");
        }
    }
}
