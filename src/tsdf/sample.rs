//! Volume queries for ray casting: a trilinear TSDF sampler and a dense block-occupancy grid.

use super::volume::{floor_i32, TsdfVolume, Voxel};

/// Trilinear TSDF lookup with a one-block cache.
pub(crate) struct Sampler<'a> {
    vol: &'a TsdfVolume,
    side: i32,
    inv_voxel: f32,
    key: [i32; 3],
    block: Option<&'a [Voxel]>,
}

impl<'a> Sampler<'a> {
    pub(crate) fn new(vol: &'a TsdfVolume) -> Self {
        let key = [i32::MIN; 3];
        Sampler { vol, side: vol.side as i32, inv_voxel: 1.0 / vol.config.voxel_size_m, key, block: None }
    }

    #[inline]
    fn block(&mut self, b: [i32; 3]) -> Option<&'a [Voxel]> {
        if b != self.key {
            self.key = b;
            self.block = self.vol.slot(b).map(|s| self.vol.block(s));
        }
        self.block
    }

    #[inline]
    fn voxel(&mut self, g: [i32; 3]) -> Option<Voxel> {
        let s = self.side;
        let block = self.block(g.map(|v| v.div_euclid(s)))?;
        let l = g.map(|v| v.rem_euclid(s) as usize);
        Some(block[l[0] + s as usize * (l[1] + s as usize * l[2])])
    }

    /// The TSDF at `p` (metres) interpolated between the 8 surrounding voxel centres; `None` when
    /// one of them is unallocated or unobserved.
    #[inline]
    pub(crate) fn trilinear(&mut self, p: [f32; 3]) -> Option<f32> {
        let q = p.map(|c| c * self.inv_voxel - 0.5);
        let i0 = q.map(floor_i32);
        let f = [0, 1, 2].map(|a| q[a] - i0[a] as f32);
        let s = self.side;
        let b = i0.map(|v| v.div_euclid(s));
        let l = [0, 1, 2].map(|a| i0[a] - b[a] * s);
        let mut c = [0.0f32; 8];
        if l.iter().all(|&v| v < s - 1) {
            // All 8 corners in one block.
            let block = self.block(b)?;
            let (su, base) = (s as usize, (l[0] + s * (l[1] + s * l[2])) as usize);
            for (n, c) in c.iter_mut().enumerate() {
                let v = block[base + (n & 1) + su * ((n >> 1 & 1) + su * (n >> 2 & 1))];
                if v.weight <= 0.0 {
                    return None;
                }
                *c = v.tsdf;
            }
        } else {
            for (n, c) in c.iter_mut().enumerate() {
                let v = self.voxel([i0[0] + (n & 1) as i32, i0[1] + (n >> 1 & 1) as i32, i0[2] + (n >> 2 & 1) as i32])?;
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

/// Which blocks are allocated, as a bit per block over the bounding box of all blocks: a lookup
/// costs a few instructions where the hash map costs a hash and a probe.
pub(crate) struct Occupancy {
    /// Block coordinate of the grid's first cell.
    pub(crate) min: [i32; 3],
    /// Cells along x, y, z.
    pub(crate) dims: [usize; 3],
    bits: Vec<u64>,
}

impl Occupancy {
    /// Grids larger than this many cells (32 MB of bits) are not built.
    const MAX_CELLS: usize = 1 << 28;

    /// The grid of `vol`'s blocks; `None` when the volume is empty or its blocks spread too far.
    pub(crate) fn new(vol: &TsdfVolume) -> Option<Occupancy> {
        let first = *vol.coords.first()?;
        let (mut min, mut max) = (first, first);
        for c in &vol.coords {
            for a in 0..3 {
                min[a] = min[a].min(c[a]);
                max[a] = max[a].max(c[a]);
            }
        }
        let dims = [0, 1, 2].map(|a| (max[a] - min[a] + 1) as usize);
        let cells = dims.iter().try_fold(1usize, |n, d| n.checked_mul(*d)).filter(|n| *n <= Self::MAX_CELLS)?;
        let mut grid = Occupancy { min, dims, bits: vec![0; cells.div_ceil(64)] };
        for c in &vol.coords {
            let i = grid.index(*c).expect("inside its own bounds");
            grid.bits[i / 64] |= 1 << (i % 64);
        }
        Some(grid)
    }

    #[inline]
    fn index(&self, c: [i32; 3]) -> Option<usize> {
        let l = [0, 1, 2].map(|a| c[a].wrapping_sub(self.min[a]) as u32 as usize);
        (l[0] < self.dims[0] && l[1] < self.dims[1] && l[2] < self.dims[2])
            .then(|| l[0] + self.dims[0] * (l[1] + self.dims[1] * l[2]))
    }

    /// Whether block `c` is allocated.
    #[inline]
    pub(crate) fn get(&self, c: [i32; 3]) -> bool {
        self.index(c).is_some_and(|i| self.bits[i / 64] >> (i % 64) & 1 == 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Point;
    use crate::tsdf::TsdfConfig;

    #[test]
    fn trilinear_is_exact_for_a_linear_field_within_and_across_blocks_and_occupancy_matches_the_map() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        v.set_from_sdf(&Point::new(-0.1, -0.1, -0.1), &Point::new(0.1, 0.1, 0.1), 2.0, |p| 0.1 * p.x - 0.1 * p.y + 0.05 * p.z);
        let mut s = Sampler::new(&v);
        for p in [[0.0f32, 0.0, 0.0], [0.0123, -0.0456, 0.0789], [-0.0799, 0.0801, 0.0]] {
            let expect = (0.1 * p[0] - 0.1 * p[1] + 0.05 * p[2]) / 0.04;
            assert!((s.trilinear(p).unwrap() - expect).abs() < 1e-5, "{p:?}");
        }
        assert_eq!(s.trilinear([0.5, 0.0, 0.0]), None, "unallocated");
        assert_eq!(s.trilinear([0.0995, 0.0, 0.0]), None, "a corner outside the filled box is unobserved");
        let occ = Occupancy::new(&v).unwrap();
        assert_eq!(occ.dims, [4, 4, 4]);
        for x in -4..4 {
            for y in -3..3 {
                assert_eq!(occ.get([x, y, 0]), v.slot([x, y, 0]).is_some(), "{x} {y}");
            }
        }
    }
}
