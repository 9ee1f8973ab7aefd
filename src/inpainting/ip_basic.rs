//! IP-Basic (Ku, Harakeh & Waslander 2018, "In Defense of Classical Image Processing: Fast Depth
//! Completion on the CPU"), its fast pipeline as the paper describes it, written here from that
//! description: depths are inverted (`MAX_DEPTH − z`, so that max filters keep the nearer surface and
//! empty stays 0), dilated with a 5×5 diamond, closed with a 5×5 square, small holes filled by a 7×7
//! dilation, each column's topmost value extended to the top of the image, large holes filled by a 31×31
//! dilation, then a 5×5 median and a 5×5 Gaussian blur smooth the result, which is inverted back. Unlike
//! the paper's pipeline (made for sparse LiDAR), the known pixels are kept bit for bit.
//!
//! It is here as the classical CPU depth completion a practitioner would pick (issue 17's peer; the same
//! scores as `benchmarks/peers/fill_peers.py`'s OpenCV version). On re-projection holes it fills only the
//! pixels its 31×31 dilation reaches, a quarter to a half of a large hole, and scores below
//! [`super::Background`] on those same pixels (docs/lab/2026-12-03-fills-against-peers.md).

use super::{InpaintContext, Inpainter};
use crate::geometry::DepthMap;

/// Depths are inverted against this, metres (the paper's 100 m; any bound above the working range).
pub const MAX_DEPTH: f32 = 100.0;
/// An inverted value below this is empty.
const EMPTY: f32 = 0.1;

/// The IP-Basic fill (see the module docs); pixels no dilation reaches stay 0.
#[derive(Clone, Copy, Debug, Default)]
pub struct IpBasic;

impl Inpainter for IpBasic {
    fn name(&self) -> &'static str {
        "ip_basic"
    }

    fn inpaint(&self, depth: &DepthMap, known: &[bool], _: &InpaintContext) -> DepthMap {
        let (w, h) = (depth.width() as usize, depth.height() as usize);
        let filled = ip_basic_fill(depth.data(), known, w, h);
        DepthMap::new(depth.width(), depth.height(), filled).expect("filled depths are valid")
    }
}

/// The fill of a row-major `w`×`h` map: known pixels as they are (those without depth are not grown
/// from), the others IP-Basic's estimate, 0 where none.
pub fn ip_basic_fill(depth: &[f32], known: &[bool], w: usize, h: usize) -> Vec<f32> {
    let source = |j: usize| known[j] && depth[j] > 0.0;
    let mut d: Vec<f32> = (0..w * h).map(|j| if source(j) { MAX_DEPTH - depth[j] } else { 0.0 }).collect();
    d = max_filter(&d, w, h, &diamond(5));
    let square5 = square(5);
    d = min_filter(&max_filter(&d, w, h, &square5), w, h, &square5);
    let grown = max_filter(&d, w, h, &square(7));
    fill_empty(&mut d, &grown);
    extend_to_top(&mut d, w, h);
    let grown = max_filter(&d, w, h, &square(31));
    fill_empty(&mut d, &grown);
    let median = median5(&d, w, h);
    d.iter_mut().zip(&median).filter(|(v, _)| **v > EMPTY).for_each(|(v, m)| *v = *m);
    let blurred = gaussian5(&d, w, h);
    d.iter_mut().zip(&blurred).filter(|(v, _)| **v > EMPTY).for_each(|(v, b)| *v = *b);
    (0..w * h).map(|j| if known[j] { depth[j] } else if d[j] > EMPTY { MAX_DEPTH - d[j] } else { 0.0 }).collect()
}

/// Offsets `(dr, dc)` of a `n`×`n` square kernel.
fn square(n: i64) -> Vec<(i64, i64)> {
    let r = n / 2;
    (-r..=r).flat_map(|dr| (-r..=r).map(move |dc| (dr, dc))).collect()
}

/// Offsets of a `n`×`n` diamond kernel (|dr| + |dc| ≤ n/2).
fn diamond(n: i64) -> Vec<(i64, i64)> {
    square(n).into_iter().filter(|(dr, dc)| dr.abs() + dc.abs() <= n / 2).collect()
}

/// The largest value under the kernel at each pixel (pixels outside the image are ignored).
fn max_filter(d: &[f32], w: usize, h: usize, kernel: &[(i64, i64)]) -> Vec<f32> {
    extremum_filter(d, w, h, kernel, f32::max, f32::NEG_INFINITY)
}

/// The smallest value under the kernel at each pixel (pixels outside the image are ignored).
fn min_filter(d: &[f32], w: usize, h: usize, kernel: &[(i64, i64)]) -> Vec<f32> {
    extremum_filter(d, w, h, kernel, f32::min, f32::INFINITY)
}

fn extremum_filter(d: &[f32], w: usize, h: usize, kernel: &[(i64, i64)], pick: fn(f32, f32) -> f32, init: f32) -> Vec<f32> {
    // A square kernel is separable: a row pass, then a column pass.
    let side = (kernel.len() as f64).sqrt() as i64;
    if side * side == kernel.len() as i64 {
        let r = side / 2;
        let rows = line_filter(d, w, h, r, true, pick, init);
        return line_filter(&rows, w, h, r, false, pick, init);
    }
    (0..w * h)
        .map(|j| {
            let (r, c) = ((j / w) as i64, (j % w) as i64);
            kernel.iter().fold(init, |acc, (dr, dc)| {
                let (rr, cc) = (r + dr, c + dc);
                if rr < 0 || cc < 0 || rr >= h as i64 || cc >= w as i64 {
                    acc
                } else {
                    pick(acc, d[rr as usize * w + cc as usize])
                }
            })
        })
        .collect()
}

/// The extremum over `±radius` along rows (`along_rows`) or columns.
fn line_filter(d: &[f32], w: usize, h: usize, radius: i64, along_rows: bool, pick: fn(f32, f32) -> f32, init: f32) -> Vec<f32> {
    (0..w * h)
        .map(|j| {
            let (r, c) = ((j / w) as i64, (j % w) as i64);
            (-radius..=radius).fold(init, |acc, o| {
                let (rr, cc) = if along_rows { (r, c + o) } else { (r + o, c) };
                if rr < 0 || cc < 0 || rr >= h as i64 || cc >= w as i64 {
                    acc
                } else {
                    pick(acc, d[rr as usize * w + cc as usize])
                }
            })
        })
        .collect()
}

fn fill_empty(d: &mut [f32], with: &[f32]) {
    d.iter_mut().zip(with).filter(|(v, _)| **v <= EMPTY).for_each(|(v, x)| *v = *x);
}

/// Copies each column's topmost non-empty value to the pixels above it.
fn extend_to_top(d: &mut [f32], w: usize, h: usize) {
    for c in 0..w {
        if let Some(top) = (0..h).find(|r| d[r * w + c] > EMPTY) {
            let v = d[top * w + c];
            (0..top).for_each(|r| d[r * w + c] = v);
        }
    }
}

/// Clamped (edge-replicated) index.
fn clamp(i: i64, n: usize) -> usize {
    i.clamp(0, n as i64 - 1) as usize
}

/// 5×5 median, the image edge replicated.
fn median5(d: &[f32], w: usize, h: usize) -> Vec<f32> {
    (0..w * h)
        .map(|j| {
            let (r, c) = ((j / w) as i64, (j % w) as i64);
            let mut v = [0f32; 25];
            for (k, (dr, dc)) in square(5).into_iter().enumerate() {
                v[k] = d[clamp(r + dr, h) * w + clamp(c + dc, w)];
            }
            v.sort_unstable_by(f32::total_cmp);
            v[12]
        })
        .collect()
}

/// 5×5 Gaussian blur with the binomial weights (1, 4, 6, 4, 1)/16 in each direction, the image edge
/// mirrored.
fn gaussian5(d: &[f32], w: usize, h: usize) -> Vec<f32> {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let mirror = |i: i64, n: usize| -> usize {
        let n = n as i64;
        let i = if i < 0 { -i } else if i >= n { 2 * n - 2 - i } else { i };
        i.clamp(0, n - 1) as usize
    };
    let pass = |src: &[f32], rows: bool| -> Vec<f32> {
        (0..w * h)
            .map(|j| {
                let (r, c) = ((j / w) as i64, (j % w) as i64);
                (0..5)
                    .map(|k| {
                        let o = k as i64 - 2;
                        let i = if rows { r as usize * w + mirror(c + o, w) } else { mirror(r + o, h) * w + c as usize };
                        K[k] * src[i]
                    })
                    .sum()
            })
            .collect()
    };
    pass(&pass(d, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;
    use nalgebra::Isometry3;

    fn ctx(w: u32, h: u32) -> InpaintContext {
        InpaintContext { intrinsics: Intrinsics::new(50.0, 50.0, w as f64 / 2.0, h as f64 / 2.0, w, h).unwrap(), seed: 0, t_target_from_source: Isometry3::identity() }
    }

    #[test]
    fn a_flat_wall_with_holes_is_filled_flat_and_known_pixels_are_kept() {
        let (w, h) = (64usize, 48usize);
        // A wall at 2.5 m with a 20x10 hole, a 3-pixel crack and every pixel of the top 6 rows unknown.
        let known: Vec<bool> = (0..w * h)
            .map(|j| {
                let (r, c) = (j / w, j % w);
                !((20..40).contains(&c) && (15..25).contains(&r)) && !(c == 50 && (30..33).contains(&r)) && r >= 6
            })
            .collect();
        let depth = DepthMap::new(w as u32, h as u32, known.iter().map(|k| if *k { 2.5 } else { 0.0 }).collect()).unwrap();
        let out = IpBasic.inpaint(&depth, &known, &ctx(w as u32, h as u32));
        for (j, z) in out.data().iter().enumerate() {
            assert!((z - 2.5).abs() < 1e-4, "pixel {j}: {z}");
        }
    }

    #[test]
    fn a_gap_between_two_surfaces_is_split_with_the_tie_to_the_nearer_one() {
        // Left of column 27 a surface at 1.5 m, right of column 35 one at 3 m, columns 27..=35 unknown (a
        // 9-pixel gap; every row alike). The diamond grows each side by 2 columns, the 7x7 dilation by 3
        // more, and the middle column, 3 from both fronts, goes to the nearer surface (the larger inverted
        // value). So columns 27-29 are the near surface and 34-35 the far one even after the blurs, and
        // the middle column, blurred across the meeting line, is nearer than the midpoint 2.25 m.
        let (w, h) = (64usize, 32usize);
        let known: Vec<bool> = (0..w * h).map(|j| !(27..=35).contains(&(j % w))).collect();
        let depth: Vec<f32> = (0..w * h).map(|j| if !known[j] { 0.0 } else if j % w < 27 { 1.5 } else { 3.0 }).collect();
        let out = IpBasic.inpaint(&DepthMap::new(w as u32, h as u32, depth.clone()).unwrap(), &known, &ctx(w as u32, h as u32));
        let z = |r: usize, c: usize| out.data()[r * w + c];
        for r in 0..h {
            for c in 27..=29 {
                assert!((z(r, c) - 1.5).abs() < 1e-3, "pixel ({c}, {r}): {}", z(r, c));
            }
            for c in 34..=35 {
                assert!((z(r, c) - 3.0).abs() < 1e-3, "pixel ({c}, {r}): {}", z(r, c));
            }
            assert!(z(r, 31) > 1.5 + 1e-3 && z(r, 31) < 2.25, "middle of row {r}: {}", z(r, 31));
            assert!((27..=35).all(|c| z(r, c) >= 1.5 - 1e-3 && z(r, c) <= 3.0 + 1e-3));
            assert_eq!((z(r, 26), z(r, 36)), (1.5, 3.0), "known pixels beside the gap are kept");
        }
    }

    #[test]
    fn the_separable_square_filter_equals_the_direct_one() {
        let (w, h) = (23usize, 17usize);
        let d: Vec<f32> = (0..w * h).map(|j| ((j * 7919) % 101) as f32).collect();
        // A kernel that is a square but listed with one offset twice is not treated as separable.
        let mut direct = square(7);
        direct.push((0, 0));
        assert_eq!(max_filter(&d, w, h, &square(7)), max_filter(&d, w, h, &direct));
        assert_eq!(min_filter(&d, w, h, &square(5)), min_filter(&d, w, h, &{ let mut k = square(5); k.push((0, 0)); k }));
    }
}
