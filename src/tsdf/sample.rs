//! Volume queries for ray casting: a trilinear TSDF sampler and a dense block-occupancy grid.

use super::volume::{floor_i32, TsdfVolume, Voxel};

/// Trilinear TSDF lookup with a one-block cache.
pub(crate) struct Sampler<'a> {
    vol: &'a TsdfVolume,
    side: i32,
    inv_side: f32,
    inv_voxel: f32,
    key: [i32; 3],
    block: Option<&'a [Voxel]>,
}

impl<'a> Sampler<'a> {
    pub(crate) fn new(vol: &'a TsdfVolume) -> Self {
        let key = [i32::MIN; 3];
        Sampler {
            vol,
            side: vol.side as i32,
            inv_side: 1.0 / vol.side as f32,
            inv_voxel: 1.0 / vol.config.voxel_size_m,
            key,
            block: None,
        }
    }

    #[inline]
    fn block(&mut self, b: [i32; 3]) -> Option<&'a [Voxel]> {
        if b != self.key {
            self.key = b;
            self.block = self.vol.slot(b).map(|s| self.vol.block(s));
        }
        self.block
    }

    /// The TSDF at `p` (metres) interpolated between the 8 surrounding voxel centres; `None` when
    /// one of them is unallocated or unobserved.
    #[inline]
    pub(crate) fn trilinear(&mut self, p: [f32; 3]) -> Option<f32> {
        let q = p.map(|c| c * self.inv_voxel - 0.5);
        let i0 = q.map(floor_i32);
        let f = [0, 1, 2].map(|a| q[a] - i0[a] as f32);
        // Block and local index of the first corner, without integer division.
        let s = self.side;
        let (mut b, mut l) = ([0i32; 3], [0i32; 3]);
        for a in 0..3 {
            b[a] = floor_i32(i0[a] as f32 * self.inv_side);
            l[a] = i0[a] - b[a] * s;
            if l[a] < 0 {
                b[a] -= 1;
                l[a] += s;
            } else if l[a] >= s {
                b[a] += 1;
                l[a] -= s;
            }
        }
        let su = s as usize;
        let first = self.block(b)?;
        let mut c = [0.0f32; 8];
        if l.iter().all(|&v| v < s - 1) {
            // All 8 corners in one block.
            let base = (l[0] + s * (l[1] + s * l[2])) as usize;
            for (n, c) in c.iter_mut().enumerate() {
                let v = first[base + (n & 1) + su * ((n >> 1 & 1) + su * (n >> 2 & 1))];
                if v.weight <= 0.0 {
                    return None;
                }
                *c = v.tsdf;
            }
        } else {
            // Corners spill into the next block along the axes where the first corner is last.
            let mut blocks: [Option<&[Voxel]>; 8] = [None; 8];
            blocks[0] = Some(first);
            for (n, c) in c.iter_mut().enumerate() {
                let (mut spill, mut local) = (0usize, [0usize; 3]);
                for a in 0..3 {
                    let o = (n >> a & 1) as i32;
                    if o == 1 && l[a] == s - 1 {
                        spill |= 1 << a;
                    } else {
                        local[a] = (l[a] + o) as usize;
                    }
                }
                let block = match blocks[spill] {
                    Some(block) => block,
                    None => {
                        let nb = [0, 1, 2].map(|a| b[a] + (spill >> a & 1) as i32);
                        let block = self.vol.block(self.vol.slot(nb)?);
                        blocks[spill] = Some(block);
                        block
                    }
                };
                let v = block[local[0] + su * (local[1] + su * local[2])];
                if v.weight <= 0.0 {
                    return None;
                }
                *c = v.tsdf;
            }
        }
        let x = [0, 2, 4, 6].map(|i| c[i] + (c[i + 1] - c[i]) * f[0]);
        let y = [x[0] + (x[1] - x[0]) * f[1], x[2] + (x[3] - x[2]) * f[1]];
        Some(y[0] + (y[1] - y[0]) * f[2])
    }
}

/// The Chebyshev distance, in blocks, from every block of the volume's bounding box to the nearest
/// allocated block (0 = allocated), capped at [`BlockDistance::MAX`]: a ray in a block at distance
/// `k` can advance `(k − 1)` blocks along every axis without meeting an allocated block.
pub(crate) struct BlockDistance<'a> {
    vol: &'a TsdfVolume,
    /// Block coordinate of the grid's first cell, cells along x, y, z, and the distances (x fastest);
    /// `None` when the box is too large, and then only "allocated or not" is known.
    grid: Option<([i32; 3], [usize; 3], Vec<u8>)>,
}

impl<'a> BlockDistance<'a> {
    /// Distances are capped here.
    pub(crate) const MAX: u8 = 8;
    /// Boxes with more cells (bytes) than this are not gridded.
    const MAX_CELLS: usize = 1 << 26;

    pub(crate) fn new(vol: &'a TsdfVolume) -> Self {
        let Some(first) = vol.coords.first() else { return BlockDistance { vol, grid: None } };
        let (mut min, mut max) = (*first, *first);
        for c in &vol.coords {
            for a in 0..3 {
                min[a] = min[a].min(c[a]);
                max[a] = max[a].max(c[a]);
            }
        }
        let dims = [0, 1, 2].map(|a| (max[a] - min[a] + 1) as usize);
        let Some(cells) = dims.iter().try_fold(1usize, |n, d| n.checked_mul(*d)).filter(|n| *n <= Self::MAX_CELLS)
        else {
            return BlockDistance { vol, grid: None };
        };
        let mut reached = vec![0u8; cells];
        for c in &vol.coords {
            reached[index(min, dims, *c).expect("inside its own box")] = 1;
        }
        let mut dist: Vec<u8> = reached.iter().map(|r| if *r == 1 { 0 } else { Self::MAX }).collect();
        // Grow the allocated set by one block in L∞ per round (a separable 3×3×3 dilation).
        let (row, slab) = (dims[0], dims[0] * dims[1]);
        for k in 1..Self::MAX {
            let mut next = reached.clone();
            for (dst, src) in next.chunks_mut(row).zip(reached.chunks(row)) {
                for x in 0..row {
                    dst[x] |= src[x.saturating_sub(1)] | src[(x + 1).min(row - 1)];
                }
            }
            for stride in [row, slab] {
                let src = next.clone();
                let span = if stride == row { slab } else { cells };
                for (dst, src) in next.chunks_mut(span).zip(src.chunks(span)) {
                    for i in 0..span {
                        let lo = if i >= stride { src[i - stride] } else { 0 };
                        let hi = if i + stride < span { src[i + stride] } else { 0 };
                        dst[i] |= lo | hi;
                    }
                }
            }
            for (d, r) in dist.iter_mut().zip(&next) {
                if *r == 1 && *d == Self::MAX {
                    *d = k;
                }
            }
            reached = next;
        }
        BlockDistance { vol, grid: Some((min, dims, dist)) }
    }

    /// The distance of block `c` (see the type); outside the box, its distance to the box (a lower
    /// bound); without a grid, 0 for an allocated block and 1 otherwise.
    #[inline]
    pub(crate) fn get(&self, c: [i32; 3]) -> u8 {
        match &self.grid {
            None => self.vol.slot(c).is_none() as u8,
            Some((min, dims, dist)) => match index(*min, *dims, c) {
                Some(i) => dist[i],
                None => {
                    let out =
                        (0..3).map(|a| (min[a] - c[a]).max(c[a] - (min[a] + dims[a] as i32 - 1))).max().unwrap_or(0);
                    out.clamp(1, Self::MAX as i32) as u8
                }
            },
        }
    }

    /// The gridded box of blocks: first block and one past the last, if gridded.
    pub(crate) fn bounds(&self) -> Option<([i32; 3], [i32; 3])> {
        self.grid.as_ref().map(|(min, dims, _)| (*min, [0, 1, 2].map(|a| min[a] + dims[a] as i32)))
    }
}

#[inline]
fn index(min: [i32; 3], dims: [usize; 3], c: [i32; 3]) -> Option<usize> {
    let l = [0, 1, 2].map(|a| c[a].wrapping_sub(min[a]) as u32 as usize);
    (l[0] < dims[0] && l[1] < dims[1] && l[2] < dims[2]).then(|| l[0] + dims[0] * (l[1] + dims[1] * l[2]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Point;
    use crate::tsdf::TsdfConfig;

    #[test]
    fn trilinear_is_exact_for_linear_fields_and_block_distances_are_chebyshev() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        v.set_from_sdf(&Point::new(-0.1, -0.1, -0.1), &Point::new(0.1, 0.1, 0.1), 2.0, |p| {
            0.1 * p.x - 0.1 * p.y + 0.05 * p.z
        });
        let mut s = Sampler::new(&v);
        for p in [[0.0f32, 0.0, 0.0], [0.0123, -0.0456, 0.0789], [-0.0799, 0.0801, 0.0]] {
            let expect = (0.1 * p[0] - 0.1 * p[1] + 0.05 * p[2]) / 0.04;
            assert!((s.trilinear(p).unwrap() - expect).abs() < 1e-5, "{p:?}");
        }
        assert_eq!(s.trilinear([0.5, 0.0, 0.0]), None, "unallocated");
        assert_eq!(s.trilinear([0.0995, 0.0, 0.0]), None, "a corner outside the filled box is unobserved");
        // A second, one-voxel fill in block (6, −1, −1).
        v.set_from_sdf(&Point::new(0.49, -0.01, -0.01), &Point::new(0.5, 0.0, 0.0), 1.0, |_| 0.0);
        let occ = BlockDistance::new(&v);
        assert_eq!(occ.bounds(), Some(([-2, -2, -2], [7, 2, 2])));
        for x in -2..7 {
            for y in -2..2 {
                for z in -2..2 {
                    assert_eq!(occ.get([x, y, z]) == 0, v.slot([x, y, z]).is_some(), "{x} {y} {z}");
                    let a = (x - 1).max(0).max(y.abs() - 2).max(z.abs() - 2);
                    let b = (6 - x).max((y + 1).abs()).max((z + 1).abs());
                    assert_eq!(occ.get([x, y, z]) as i32, a.min(b), "{x} {y} {z}");
                }
            }
        }
        assert_eq!(occ.get([-5, 0, 0]), 3, "outside the box: the distance to the box");
    }
}
