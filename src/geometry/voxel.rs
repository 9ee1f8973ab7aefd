//! Voxel-grid downsampling: one point per occupied voxel, the centroid of the points inside it.

use super::{Point, F64_TO_INT_MAGIC};
use rayon::prelude::*;

/// Bits per axis of a packed voxel key; cells in `[-2^20, 2^20)` pack, wider clouds take the slower path.
const AXIS_BITS: u32 = 21;
const AXIS_BIAS: i64 = 1 << (AXIS_BITS - 1);
/// Fewest points worth a thread of their own.
const MIN_POINTS_PER_PART: usize = 32_768;

/// Downsamples `points` to the centroid of each occupied voxel of edge `voxel` metres.
///
/// The grid has its origin at 0: a point belongs to voxel `floor(p / voxel)` (computed in f64). The output
/// is sorted by voxel index `(ix, iy, iz)` lexicographically, and each centroid sums its points in input
/// order, so the result is bit-identical whatever the thread count.
pub fn voxel_downsample(points: &[Point], voxel: f32) -> Vec<Point> {
    downsample(points, None, voxel).0
}

/// [`voxel_downsample`] with, when `tags` is given, each voxel's [`PointTag`] summary.
fn downsample(points: &[Point], tags: Option<&[PointTag]>, voxel: f32) -> (Vec<Point>, Vec<PointTag>) {
    assert!(voxel.is_finite() && voxel > 0.0, "voxel size must be positive, got {voxel}");
    if points.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let inv = 1.0 / voxel as f64;
    // Key = voxel index biased to non-negative and packed (ix, iy, iz), so keys order voxels
    // lexicographically; a cell too far from the origin to pack sends the cloud to the slower path.
    let mut keys = vec![0u64; points.len()];
    let all_pack = keys.par_chunks_mut(16_384).zip(points.par_chunks(16_384)).all(|(ks, ps)| pack_keys(ps, inv, ks));
    if !all_pack {
        return downsample_by_sort(points, tags, inv);
    }
    // Split the key range into parts of about equal point counts (quantiles of a sample of the keys); each
    // part is accumulated by one thread walking all points in input order and taking the keys in its range,
    // so every voxel's sum runs in input order whatever the split.
    let parts = rayon::current_num_threads().clamp(1, points.len().div_ceil(MIN_POINTS_PER_PART));
    let mut sample: Vec<u64> = keys.iter().step_by(64).copied().collect();
    sample.sort_unstable();
    let bounds: Vec<u64> = (0..=parts)
        .map(|i| {
            if i == parts {
                u64::MAX
            } else if i == 0 {
                0
            } else {
                sample[i * sample.len() / parts]
            }
        })
        .collect();
    let runs: Vec<(Vec<Point>, Vec<PointTag>)> = bounds.par_windows(2).map(|b| accumulate(points, tags, &keys, b[0]..b[1])).collect();
    let (points, tags): (Vec<_>, Vec<_>) = runs.into_iter().unzip();
    (points.concat(), tags.concat())
}

/// Writes the packed key of each point's voxel to `keys`; false when some cell does not pack.
fn pack_keys(points: &[Point], inv: f64, keys: &mut [u64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { pack_keys_avx2(points, inv, keys) };
    }
    pack_keys_body(points, inv, keys)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn pack_keys_avx2(points: &[Point], inv: f64, keys: &mut [u64]) -> bool {
    pack_keys_body(points, inv, keys)
}

/// Branch-free so that it vectorises: `floor` of the scaled coordinate, range-checked in f64, then turned
/// into an integer through the bits of `n + 1.5·2^52` (exact for `|n| < 2^51`).
#[inline(always)]
fn pack_keys_body(points: &[Point], inv: f64, keys: &mut [u64]) -> bool {
    const LOW: u64 = (1 << AXIS_BITS) - 1;
    let (lo, hi) = (-AXIS_BIAS as f64, AXIS_BIAS as f64);
    let mut fits = true;
    for (k, p) in keys.iter_mut().zip(points) {
        let axis = |v: f32| -> (u64, bool) {
            let v = v as f64 * inv;
            let ok = v >= lo && v < hi;
            let c = v.max(lo).min(hi).floor() + (AXIS_BIAS as f64 + F64_TO_INT_MAGIC);
            (c.to_bits() & LOW, ok)
        };
        let ((x, ox), (y, oy), (z, oz)) = (axis(p.x), axis(p.y), axis(p.z));
        fits &= ox & oy & oz;
        *k = x << (2 * AXIS_BITS) | y << AXIS_BITS | z;
    }
    fits
}

/// Centroids (and, with `tags`, tag summaries) of the voxels whose keys fall in `range`, in key order; sums
/// run in input order.
fn accumulate(points: &[Point], tags: Option<&[PointTag]>, keys: &[u64], range: std::ops::Range<u64>) -> (Vec<Point>, Vec<PointTag>) {
    let mut table = VoxelTable::with_slots((points.len() / 16).next_power_of_two().max(1024));
    // Points of a depth map come row by row, so runs of points share a voxel: look the key up once per run
    // and sum the run in registers.
    let mut i = 0;
    while i < points.len() {
        let k = keys[i];
        if !range.contains(&k) {
            i += 1;
            continue;
        }
        let e = table.entry(k);
        let Entry { mut sum, mut n, mut known, mut scene, mut view, .. } = table.entries[e];
        let run = i;
        while i < points.len() && keys[i] == k {
            let p = &points[i];
            sum[0] += p.x as f64;
            sum[1] += p.y as f64;
            sum[2] += p.z as f64;
            n += 1;
            i += 1;
        }
        if let Some(tags) = tags {
            for t in &tags[run..i] {
                known += t.known as f64;
                scene += t.scene as f64;
                view = view.min(t.view);
            }
        }
        (table.entries[e].sum, table.entries[e].n, table.entries[e].known, table.entries[e].scene, table.entries[e].view) = (sum, n, known, scene, view);
    }
    let mut entries = table.entries;
    entries.sort_unstable_by_key(|e| e.key);
    let summary = match tags {
        Some(_) => entries.iter().map(|e| PointTag { known: (e.known / e.n as f64) as f32, scene: (e.scene / e.n as f64) as f32, view: e.view }).collect(),
        None => Vec::new(),
    };
    (entries.iter().map(|e| centroid(e.sum, e.n)).collect(), summary)
}

/// One occupied voxel being summed.
#[derive(Clone, Copy)]
struct Entry {
    key: u64,
    sum: [f64; 3],
    n: u32,
    /// Sums of the points' `known` and `scene`, and the lowest `view` (tagged downsampling only).
    known: f64,
    scene: f64,
    view: u8,
}

/// Open-addressing map from voxel key to its entry, grown at half load, in front of which a small
/// direct-mapped cache of recent keys stays in L1: the next image row mostly revisits the voxels of the last.
struct VoxelTable {
    /// Entry index per slot, or `u32::MAX` when the slot is empty.
    slots: Vec<u32>,
    entries: Vec<Entry>,
    /// (key, entry index) of a recent key per cache line; key `u64::MAX` (never packed) when empty.
    recent: Vec<(u64, u32)>,
}

/// Entries of [`VoxelTable::recent`] (a power of two).
const RECENT: usize = 1024;

impl VoxelTable {
    fn with_slots(n: usize) -> VoxelTable {
        VoxelTable { slots: vec![u32::MAX; n], entries: Vec::new(), recent: vec![(u64::MAX, 0); RECENT] }
    }

    fn home(key: u64, mask: usize) -> usize {
        (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32) as usize & mask
    }

    /// The index of `key`'s entry, inserted empty when new.
    fn entry(&mut self, key: u64) -> usize {
        let line = Self::home(key, RECENT - 1);
        if self.recent[line].0 == key {
            return self.recent[line].1 as usize;
        }
        let e = self.lookup(key);
        self.recent[line] = (key, e as u32);
        e
    }

    fn lookup(&mut self, key: u64) -> usize {
        let mask = self.slots.len() - 1;
        let mut s = Self::home(key, mask);
        loop {
            match self.slots[s] {
                u32::MAX => break,
                e if self.entries[e as usize].key == key => return e as usize,
                _ => s = (s + 1) & mask,
            }
        }
        let e = self.entries.len();
        self.entries.push(Entry { key, sum: [0.0; 3], n: 0, known: 0.0, scene: 0.0, view: u8::MAX });
        self.slots[s] = e as u32;
        if 2 * self.entries.len() > self.slots.len() {
            self.grow();
        }
        e
    }

    fn grow(&mut self) {
        self.slots = vec![u32::MAX; self.slots.len() * 2];
        let mask = self.slots.len() - 1;
        for (e, entry) in self.entries.iter().enumerate() {
            let mut s = Self::home(entry.key, mask);
            while self.slots[s] != u32::MAX {
                s = (s + 1) & mask;
            }
            self.slots[s] = e as u32;
        }
    }
}

fn centroid(sum: [f64; 3], n: u32) -> Point {
    let n = n as f64;
    Point::new((sum[0] / n) as f32, (sum[1] / n) as f32, (sum[2] / n) as f32)
}

/// The same result for clouds too wide to pack: sort point indices by (voxel, index).
fn downsample_by_sort(points: &[Point], tags: Option<&[PointTag]>, inv: f64) -> (Vec<Point>, Vec<PointTag>) {
    let cells: Vec<[i64; 3]> =
        points.par_iter().map(|p| [(p.x as f64 * inv).floor() as i64, (p.y as f64 * inv).floor() as i64, (p.z as f64 * inv).floor() as i64]).collect();
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.par_sort_by_key(|&i| (cells[i as usize], i));
    let mut starts: Vec<usize> = (0..order.len()).filter(|&k| k == 0 || cells[order[k] as usize] != cells[order[k - 1] as usize]).collect();
    starts.push(order.len());
    let runs = starts.windows(2).map(|w| &order[w[0]..w[1]]);
    let summary = match tags {
        Some(tags) => runs
            .clone()
            .map(|run| {
                let known: f64 = run.iter().map(|&i| tags[i as usize].known as f64).sum();
                let scene: f64 = run.iter().map(|&i| tags[i as usize].scene as f64).sum();
                let view = run.iter().map(|&i| tags[i as usize].view).min().expect("a voxel has a point");
                PointTag { known: (known / run.len() as f64) as f32, scene: (scene / run.len() as f64) as f32, view }
            })
            .collect(),
        None => Vec::new(),
    };
    (runs.map(|run| centroid_of(points, run)).collect(), summary)
}

/// The centroid of the points `run` indexes, summed in the run's order.
fn centroid_of(points: &[Point], run: &[u32]) -> Point {
    let mut sum = [0.0f64; 3];
    for &i in run {
        let p = &points[i as usize];
        sum[0] += p.x as f64;
        sum[1] += p.y as f64;
        sum[2] += p.z as f64;
    }
    centroid(sum, run.len() as u32)
}

/// Where a point of a generated target came from. Raw: `known` 1 when re-projected from the source frame,
/// `scene` 1 when the scene (posed frames around the source) gave it, both 0 when a fill made it up; `view`
/// its target view (0 = the pair's first). After [`voxel_downsample_tagged`]: the shares of the voxel's
/// points of each kind, and the lowest view among them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointTag {
    pub known: f32,
    pub scene: f32,
    pub view: u8,
}

/// [`voxel_downsample`] of `points` (the same points, bit for bit, in the same order) with each voxel's
/// [`PointTag`] summary: the means of its points' `known` and `scene`, the minimum of their `view`.
pub fn voxel_downsample_tagged(points: &[Point], tags: &[PointTag], voxel: f32) -> (Vec<Point>, Vec<PointTag>) {
    assert_eq!(points.len(), tags.len(), "one tag per point");
    downsample(points, Some(tags), voxel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use std::collections::BTreeMap;

    /// Independent reference: a BTreeMap keyed by voxel index, points summed in input order.
    fn brute_force(points: &[Point], voxel: f32) -> Vec<Point> {
        let mut m: BTreeMap<(i64, i64, i64), (f64, f64, f64, f64)> = BTreeMap::new();
        for p in points {
            let k = (
                (p.x as f64 / voxel as f64).floor() as i64,
                (p.y as f64 / voxel as f64).floor() as i64,
                (p.z as f64 / voxel as f64).floor() as i64,
            );
            let e = m.entry(k).or_default();
            e.0 += p.x as f64;
            e.1 += p.y as f64;
            e.2 += p.z as f64;
            e.3 += 1.0;
        }
        m.values().map(|s| Point::new((s.0 / s.3) as f32, (s.1 / s.3) as f32, (s.2 / s.3) as f32)).collect()
    }

    #[test]
    fn agrees_with_brute_force_on_random_clouds() {
        let mut r = Rng::new(11);
        for &(n, voxel) in &[(1usize, 0.025f32), (1000, 0.025), (50_000, 0.025), (20_000, 0.002), (5000, 1.0)] {
            let pts: Vec<Point> = (0..n)
                .map(|_| {
                    Point::new(
                        r.uniform_range(-1.5, 1.5) as f32,
                        r.uniform_range(-1.5, 1.5) as f32,
                        r.uniform_range(0.5, 3.5) as f32,
                    )
                })
                .collect();
            assert_eq!(voxel_downsample(&pts, voxel), brute_force(&pts, voxel), "n={n} voxel={voxel}");
        }
    }

    #[test]
    fn agrees_with_brute_force_on_a_scan_ordered_cloud() {
        // Row-by-row like a back-projected depth map: long runs of points share a voxel, and 120k points
        // are split into several key ranges when threads are available.
        let pts: Vec<Point> = (0..300)
            .flat_map(|r| {
                (0..400).map(move |c| {
                    Point::new(c as f32 * 0.003 - 0.6, r as f32 * 0.003 - 0.45, 2.0 + 0.001 * (c % 7) as f32)
                })
            })
            .collect();
        let expected = brute_force(&pts, 0.025);
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            assert_eq!(pool.install(|| voxel_downsample(&pts, 0.025)), expected, "{threads} threads");
        }
    }

    #[test]
    fn wide_extent_uses_the_fallback_path_and_still_agrees() {
        // 1 mm voxels over ±5 km: cells beyond ±2^20 do not pack.
        let mut r = Rng::new(5);
        let pts: Vec<Point> = (0..3000)
            .map(|_| {
                Point::new(
                    r.uniform_range(-5000.0, 5000.0) as f32,
                    r.uniform_range(-5000.0, 5000.0) as f32,
                    r.uniform_range(-5000.0, 5000.0) as f32,
                )
            })
            .collect();
        assert_eq!(voxel_downsample(&pts, 0.001), brute_force(&pts, 0.001));
    }

    #[test]
    fn negative_coordinates_floor_towards_minus_infinity() {
        let pts = vec![Point::new(-0.01, 0.0, 0.0), Point::new(0.01, 0.0, 0.0)];
        assert_eq!(voxel_downsample(&pts, 0.025).len(), 2);
    }

    /// Tagged downsampling against an independent summary (a BTreeMap keyed by voxel index, in the same
    /// lexicographic order), with tags that mix known and filled points and several views per voxel.
    fn check_tagged(pts: &[Point], voxel: f32) {
        // Three kinds: seen by the scene (i % 7 == 0), else re-projected (i % 3 != 0), else made up.
        let tags: Vec<PointTag> = (0..pts.len())
            .map(|i| {
                let scene = i % 7 == 0;
                PointTag { known: (i % 3 != 0 && !scene) as u8 as f32, scene: scene as u8 as f32, view: (i % 5) as u8 }
            })
            .collect();
        let (out, summary) = voxel_downsample_tagged(pts, &tags, voxel);
        assert_eq!(out, voxel_downsample(pts, voxel), "the same points as the untagged downsampling");
        let mut m: BTreeMap<(i64, i64, i64), (f64, f64, f64, u8)> = BTreeMap::new();
        for (p, t) in pts.iter().zip(&tags) {
            let v = voxel as f64;
            let k = ((p.x as f64 / v).floor() as i64, (p.y as f64 / v).floor() as i64, (p.z as f64 / v).floor() as i64);
            let e = m.entry(k).or_insert((0.0, 0.0, 0.0, u8::MAX));
            e.0 += t.known as f64;
            e.1 += t.scene as f64;
            e.2 += 1.0;
            e.3 = e.3.min(t.view);
        }
        let expected: Vec<PointTag> = m.values().map(|e| PointTag { known: (e.0 / e.2) as f32, scene: (e.1 / e.2) as f32, view: e.3 }).collect();
        assert_eq!(summary, expected);
        assert!(summary.iter().any(|t| t.known > 0.0 && t.known < 1.0), "some voxels mix known and filled points");
        if pts.len() / summary.len() >= 8 {
            assert!(summary.iter().any(|t| t.scene > 0.0 && t.known > 0.0 && t.known + t.scene < 1.0), "some voxels mix all three kinds");
        }
    }

    #[test]
    fn tagged_downsampling_keeps_the_points_and_summarises_the_tags() {
        let mut r = Rng::new(17);
        let random: Vec<Point> = (0..20_000)
            .map(|_| Point::new(r.uniform_range(-1.0, 1.0) as f32, r.uniform_range(-1.0, 1.0) as f32, r.uniform_range(0.5, 2.5) as f32))
            .collect();
        check_tagged(&random, 0.1);
        // Scan order (runs of points share a voxel), split into key ranges on several threads.
        let scan: Vec<Point> =
            (0..300).flat_map(|r| (0..400).map(move |c| Point::new(c as f32 * 0.003 - 0.6, r as f32 * 0.003 - 0.45, 2.0))).collect();
        for threads in [1, 3] {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| check_tagged(&scan, 0.025));
        }
        // Too wide to pack (±2 km in 1 mm voxels): the fallback path; two points per voxel.
        let wide: Vec<Point> = (0..3000).map(|i| Point::new((i / 2) as f32 * 3.0 - 2250.0, (i % 2) as f32 * 0.0004, 1.0)).collect();
        check_tagged(&wide, 0.001);
    }
}
