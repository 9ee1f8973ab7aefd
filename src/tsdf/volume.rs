//! [`TsdfVolume`]: hashed blocks of `(tsdf, weight)` voxels, voxel lookup, and analytic filling.
//!
//! Storage: a hash map from a block's integer coordinate to its slot; slot `i` owns voxels
//! `[i·n, (i+1)·n)` of one flat array (`n = block_side³`, x fastest, then y, then z). Block `b` holds
//! the voxels `b·block_side .. (b+1)·block_side` along each axis.

use super::config::TsdfConfig;
use crate::error::Result;
use crate::geometry::Point;
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// One voxel: truncated signed distance in units of the truncation (−1..1, positive in front of
/// the surface) and the number of observations averaged into it (0 = never observed).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Voxel {
    /// Truncated signed distance / truncation, in [−1, 1].
    pub tsdf: f32,
    /// Accumulated weight (observations), 0 when unobserved.
    pub weight: f32,
}

/// Block coordinates must lie in `[−KEY_BIAS, KEY_BIAS)` along each axis (21 bits each in a key).
pub(crate) const KEY_BIAS: i32 = 1 << 20;

/// The hash-map key of block coordinate `c` (three 21-bit fields; never `u64::MAX`).
#[inline]
pub(crate) fn pack(c: [i32; 3]) -> u64 {
    let f = |v: i32| (v + KEY_BIAS) as u64 & 0x1F_FFFF;
    f(c[0]) | f(c[1]) << 21 | f(c[2]) << 42
}

/// The inverse of [`pack`].
#[inline]
pub(crate) fn unpack(k: u64) -> [i32; 3] {
    let f = |s: u32| ((k >> s) & 0x1F_FFFF) as i32 - KEY_BIAS;
    [f(0), f(21), f(42)]
}

/// `floor(x)` as an integer, for |x| ≤ 10⁹ (beyond, it saturates there; NaN gives −10⁹).
/// Written so that loops over it vectorise: no libm call, no saturating-cast fix-ups.
#[inline]
#[allow(clippy::manual_clamp)] // clamp keeps a NaN, and a NaN must not reach to_int_unchecked
pub(crate) fn floor_i32(x: f32) -> i32 {
    let x = x.max(-1.0e9).min(1.0e9);
    // SAFETY: x is finite (max/min drop a NaN) and within i32's range.
    let i = unsafe { x.to_int_unchecked::<i32>() };
    i - ((i as f32) > x) as i32
}

/// A bit mixer (MurmurHash3's finaliser) for block keys; also picks direct-mapped cache slots.
#[inline]
pub(crate) fn mix(mut x: u64) -> u64 {
    x ^= x >> 33;
    x = x.wrapping_mul(0xff51_afd7_ed55_8ccd);
    x ^= x >> 33;
    x = x.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    x ^ (x >> 33)
}

/// A fast hasher for `u64` block keys (the default SipHash costs more than the TSDF update).
#[derive(Clone, Copy, Default)]
pub(crate) struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = mix(self.0 ^ *b as u64);
        }
    }
    fn write_u64(&mut self, k: u64) {
        self.0 = mix(k);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

pub(crate) type BlockMap = HashMap<u64, u32, BuildHasherDefault<KeyHasher>>;

/// A sparse TSDF volume in voxel-hashed blocks (see the module docs). Coordinates are metres in
/// whatever frame the integrated poses map cameras into (the world, or a base camera).
#[derive(Clone, Debug)]
pub struct TsdfVolume {
    pub(crate) config: TsdfConfig,
    /// Voxels per block side.
    pub(crate) side: usize,
    pub(crate) map: BlockMap,
    /// Block coordinate of each slot.
    pub(crate) coords: Vec<[i32; 3]>,
    /// Voxels of all blocks, slot after slot.
    pub(crate) voxels: Vec<Voxel>,
    /// The last update (frame) that touched each slot.
    pub(crate) stamps: Vec<u32>,
    /// Updates so far (integrated frames and analytic fills).
    pub(crate) updates: u32,
    /// Depth frames integrated.
    pub(crate) frames: u32,
}

impl TsdfVolume {
    /// An empty volume; fails, naming the field, when `config` is invalid.
    pub fn new(config: TsdfConfig) -> Result<Self> {
        config.validate()?;
        let side = config.block_side as usize;
        Ok(TsdfVolume {
            config,
            side,
            map: BlockMap::default(),
            coords: Vec::new(),
            voxels: Vec::new(),
            stamps: Vec::new(),
            updates: 0,
            frames: 0,
        })
    }

    /// Forgets everything integrated (keeps the configuration).
    pub fn reset(&mut self) {
        self.map.clear();
        self.coords.clear();
        self.voxels.clear();
        self.stamps.clear();
        self.updates = 0;
        self.frames = 0;
    }

    /// The configuration the volume was made with.
    pub fn config(&self) -> &TsdfConfig {
        &self.config
    }

    /// Number of depth frames integrated since creation or the last [`reset`](Self::reset).
    pub fn frame_count(&self) -> u32 {
        self.frames
    }

    /// Number of allocated blocks.
    pub fn block_count(&self) -> usize {
        self.coords.len()
    }

    /// Allocated memory of the voxels, bytes.
    pub fn voxel_bytes(&self) -> usize {
        self.voxels.len() * std::mem::size_of::<Voxel>()
    }

    /// The voxel with global index `index` (voxel `i` spans `[i·s, (i+1)·s)` metres along each axis),
    /// `None` when its block is not allocated.
    pub fn voxel(&self, index: [i32; 3]) -> Option<Voxel> {
        let s = self.side as i32;
        let b = index.map(|i| i.div_euclid(s));
        let l = index.map(|i| i.rem_euclid(s) as usize);
        let slot = self.slot(b)?;
        Some(self.block(slot)[l[0] + self.side * (l[1] + self.side * l[2])])
    }

    /// The global index of the voxel containing `p` (metres): `floor(p / voxel_size)`.
    pub fn voxel_index(&self, p: &Point) -> [i32; 3] {
        let s = self.config.voxel_size_m;
        [(p.x / s).floor() as i32, (p.y / s).floor() as i32, (p.z / s).floor() as i32]
    }

    /// The centre of voxel `index`, metres: `(index + ½)·voxel_size`.
    pub fn voxel_center(&self, index: [i32; 3]) -> Point {
        let s = self.config.voxel_size_m;
        Point::new((index[0] as f32 + 0.5) * s, (index[1] as f32 + 0.5) * s, (index[2] as f32 + 0.5) * s)
    }

    /// Writes `clamp(sdf(c) / truncation, −1, 1)` with weight `weight` into every voxel whose centre
    /// `c` lies in the box `[min, max]` (metres), allocating the blocks it needs; `sdf` returns a
    /// signed distance in metres, positive outside (in front of) the surface. For tests and for
    /// building volumes from analytic shapes.
    pub fn set_from_sdf<F>(&mut self, min: &Point, max: &Point, weight: f32, sdf: F)
    where
        F: Fn(&Point) -> f32 + Sync,
    {
        let s = self.config.voxel_size_m;
        let lo: [i32; 3] = [0, 1, 2].map(|a| (min[a] / s - 0.5).ceil() as i32);
        let hi: [i32; 3] = [0, 1, 2].map(|a| (max[a] / s - 0.5).floor() as i32);
        if (0..3).any(|a| lo[a] > hi[a]) {
            return;
        }
        let n = self.side as i32;
        let (blo, bhi) = (lo.map(|i| i.div_euclid(n)), hi.map(|i| i.div_euclid(n)));
        self.updates += 1;
        let stamp = self.updates;
        for bz in blo[2]..=bhi[2] {
            for by in blo[1]..=bhi[1] {
                for bx in blo[0]..=bhi[0] {
                    let slot = self.allocate([bx, by, bz]) as usize;
                    self.stamps[slot] = stamp;
                }
            }
        }
        let (side, trunc) = (self.side, self.config.truncation_m);
        let blocks =
            self.voxels.par_chunks_mut(side * side * side).zip(self.coords.par_iter()).zip(self.stamps.par_iter());
        blocks.filter(|(_, st)| **st == stamp).for_each(|((vox, c), _)| {
            for (i, v) in vox.iter_mut().enumerate() {
                let g = [
                    c[0] * n + (i % side) as i32,
                    c[1] * n + (i / side % side) as i32,
                    c[2] * n + (i / (side * side)) as i32,
                ];
                if (0..3).all(|a| lo[a] <= g[a] && g[a] <= hi[a]) {
                    let p = Point::new((g[0] as f32 + 0.5) * s, (g[1] as f32 + 0.5) * s, (g[2] as f32 + 0.5) * s);
                    *v = Voxel { tsdf: (sdf(&p) / trunc).clamp(-1.0, 1.0), weight };
                }
            }
        });
    }

    // --------------------------------------------------------------------------------------------
    // Crate-internal block access

    /// The slot of block `b`, if allocated.
    #[inline]
    pub(crate) fn slot(&self, b: [i32; 3]) -> Option<u32> {
        if b.iter().any(|v| !(-KEY_BIAS..KEY_BIAS).contains(v)) {
            return None;
        }
        self.map.get(&pack(b)).copied()
    }

    /// The voxels of slot `slot`.
    #[inline]
    pub(crate) fn block(&self, slot: u32) -> &[Voxel] {
        let n = self.side * self.side * self.side;
        &self.voxels[slot as usize * n..(slot as usize + 1) * n]
    }

    /// The slot of block `b`, allocating it (all voxels unobserved) when missing.
    pub(crate) fn allocate(&mut self, b: [i32; 3]) -> u32 {
        let next = self.coords.len() as u32;
        let slot = *self.map.entry(pack(b)).or_insert(next);
        if slot == next {
            self.coords.push(b);
            self.stamps.push(0);
            self.voxels.resize(self.voxels.len() + self.side * self.side * self.side, Voxel::default());
        }
        slot
    }

    /// Allocated slots ordered by block coordinate (x, then y, then z): the deterministic order of
    /// every extraction, whatever the order blocks were allocated in.
    pub(crate) fn sorted_slots(&self) -> Vec<u32> {
        let mut slots: Vec<u32> = (0..self.coords.len() as u32).collect();
        slots.par_sort_unstable_by_key(|&s| self.coords[s as usize]);
        slots
    }

    /// Slots of block `b` and its neighbours at offsets `{0,1}³` (index `dx | dy<<1 | dz<<2`).
    pub(crate) fn neighbour_slots(&self, b: [i32; 3]) -> [Option<u32>; 8] {
        std::array::from_fn(|i| {
            self.slot([b[0] + (i & 1) as i32, b[1] + (i >> 1 & 1) as i32, b[2] + (i >> 2 & 1) as i32])
        })
    }

    /// Block `b` and its neighbours at offsets `{0,1}³`, as voxel slices.
    pub(crate) fn neighbourhood(&self, b: [i32; 3]) -> Neighbourhood<'_> {
        Neighbourhood { blocks: self.neighbour_slots(b).map(|s| s.map(|s| self.block(s))), side: self.side }
    }
}

/// A block and its seven `+x/+y/+z` neighbours, addressed by local voxel coordinates `0..2·side`.
pub(crate) struct Neighbourhood<'a> {
    pub(crate) blocks: [Option<&'a [Voxel]>; 8],
    pub(crate) side: usize,
}

impl Neighbourhood<'_> {
    /// The voxel at local coordinates `(x, y, z)`, each in `0..2·side`; `None` in a missing block.
    #[inline]
    pub(crate) fn get(&self, x: usize, y: usize, z: usize) -> Option<&Voxel> {
        let s = self.side;
        let (bx, by, bz) = ((x >= s) as usize, (y >= s) as usize, (z >= s) as usize);
        let block = self.blocks[bx | by << 1 | bz << 2]?;
        Some(&block[(x - bx * s) + s * ((y - by * s) + s * (z - bz * s))])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_and_stay_distinct() {
        for c in [[0, 0, 0], [-1, 2, -3], [KEY_BIAS - 1, -KEY_BIAS, 7], [-KEY_BIAS, -KEY_BIAS, -KEY_BIAS]] {
            assert_eq!(unpack(pack(c)), c);
            assert_ne!(pack(c), u64::MAX);
        }
        assert_ne!(pack([1, 0, 0]), pack([0, 1, 0]));
        assert_ne!(mix(pack([1, 0, 0])) >> 57, mix(pack([2, 0, 0])) >> 57);
    }

    #[test]
    fn set_from_sdf_fills_the_box_and_voxel_lookup_finds_it() {
        let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
        // Plane z = 0.205 m: tsdf = (z − 0.205)/0.04, clamped.
        v.set_from_sdf(&Point::new(-0.1, -0.1, 0.0), &Point::new(0.1, 0.1, 0.4), 2.0, |p| p.z - 0.205);
        // Voxel centres x, y in -10..=9 (blocks -2..=1), z in 0..=39 (blocks 0..=4).
        assert_eq!(v.block_count(), 4 * 4 * 5);
        let c = v.voxel(v.voxel_index(&Point::new(0.0, 0.0, 0.215))).unwrap();
        assert!((c.tsdf - 0.25).abs() < 1e-5 && c.weight == 2.0, "{c:?}");
        assert_eq!(v.voxel(v.voxel_index(&Point::new(0.05, -0.05, 0.395))).unwrap().tsdf, 1.0);
        assert_eq!(v.voxel(v.voxel_index(&Point::new(0.05, -0.05, 0.005))).unwrap().tsdf, -1.0);
        // Allocated but outside the box: unobserved.
        assert_eq!(v.voxel([-12, 0, 5]).unwrap().weight, 0.0);
        assert!(v.voxel([0, 0, 100]).is_none());
        let sorted = v.sorted_slots();
        assert!(sorted.windows(2).all(|w| v.coords[w[0] as usize] < v.coords[w[1] as usize]));
        v.reset();
        assert_eq!((v.block_count(), v.voxel_bytes()), (0, 0));
    }
}
