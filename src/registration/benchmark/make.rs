//! Makes a benchmark from a posed RGB-D sequence: TSDF fragments in the 3DMatch convention (fragment k =
//! frames `per·k … per·k + per − 1`, points in the camera of its first frame; with a stride below `per`,
//! overlapping windows `stride·k … stride·k + per − 1`) and single-frame clouds
//! made exactly as a build makes them; the pairs between them with their ground truth, information
//! matrix and overlap, split by overlap into benchmarks.

use super::gtlog::{write_gt_info, write_gt_log, write_gt_overlap, GtPair};
use crate::error::{Error, Result};
use crate::geometry::{backproject, overlap, relative_pose, transform_points, voxel_downsample, Point, RadiusIndex};
use crate::registration::metrics::information_matrix;
use crate::sources::Sequence;
use crate::stages::ingest::WorkingConfig;
use crate::stages::voxelize::VoxelizeConfig;
use crate::tsdf::{TsdfConfig, TsdfVolume};
use nalgebra::Isometry3;
use rayon::prelude::*;
use std::path::Path;

/// Overlap and the information matrix are computed on clouds downsampled to this, metres.
pub const PAIR_VOXEL: f32 = 0.025;
/// A point overlaps the other cloud when it has a neighbour within this under the ground truth, metres
/// (the 3DMatch / PREDATOR overlap radius).
pub const OVERLAP_RADIUS: f32 = 0.0375;
/// Overlap bounds: 3DMatch above `LO_MATCH_MAX`, 3DLoMatch from `MIN_OVERLAP` to it.
pub const MIN_OVERLAP: f64 = 0.1;
pub const LO_MATCH_MAX: f64 = 0.3;
/// Single-frame pairs above this overlap are dropped (nearly identical views).
pub const SINGLE_FRAME_MAX_OVERLAP: f64 = 0.9;

/// A cloud of the benchmark: its index (fragment k, or frame index), points in its own camera frame
/// (metres), and the camera-to-world pose of that frame.
pub struct Cloud {
    pub index: usize,
    pub points: Vec<Point>,
    pub t_world_from_camera: Isometry3<f64>,
}

fn pose_of(seq: &Sequence, f: usize) -> Result<(crate::sources::Frame, Isometry3<f64>)> {
    let frame = seq.frames[f].load()?;
    let pose = frame.t_world_from_camera.ok_or_else(|| Error::input(&frame.depth_path, "frame has no camera pose"))?;
    Ok((frame, pose))
}

/// Fuses fragment `k` (frames `stride·k … stride·k + per − 1` of `seq`; the official fragments have
/// `stride = per`) with `tsdf` and returns its surface points (weight above `weight_threshold`) in the
/// camera of frame `stride·k`. Frames without a pose are left out (the fragment is then in the camera
/// of its first posed frame); `None` when no frame of the window has one.
pub fn fuse_fragment(seq: &Sequence, k: usize, per: usize, stride: usize, tsdf: &TsdfConfig, weight_threshold: f32) -> Result<Option<Cloud>> {
    let mut volume = TsdfVolume::new(tsdf.clone())?;
    let mut base = None;
    for f in (stride * k..stride * k + per).filter(|&f| seq.frames[f].has_pose()) {
        let (frame, pose) = pose_of(seq, f)?;
        let t_world_from_base = *base.get_or_insert(pose);
        volume.integrate(&frame.depth, &frame.intrinsics, &relative_pose(&t_world_from_base, &pose))?;
    }
    Ok(base.map(|t_world_from_camera| Cloud { index: k, points: volume.extract_points(weight_threshold), t_world_from_camera }))
}

/// The fragments `k` whose frames `stride·k … stride·k + per − 1` all lie in `first .. end`.
pub fn fragments_within(first: usize, end: usize, per: usize, stride: usize) -> std::ops::Range<usize> {
    let lo = first.div_ceil(stride);
    let hi = if end >= per { (end - per) / stride + 1 } else { 0 };
    lo..hi.max(lo)
}

/// Frame `f`'s cloud as a build makes it: the working resolution and intrinsics, back-projection within
/// the depth range, the crop box, the voxel grid (`working`, `voxelize`). The frame must have a pose
/// (callers leave unposed frames out: [`Sequence::unposed`]).
pub fn single_frame_cloud(
    seq: &Sequence,
    f: usize,
    working: &WorkingConfig,
    voxelize: &VoxelizeConfig,
) -> Result<Cloud> {
    let (frame, pose) = pose_of(seq, f)?;
    let (depth, k) = working.map_frame(&frame)?;
    let points =
        voxel_downsample(&working.crop_box.crop(&backproject(&depth, &k, working.depth_range())), voxelize.voxel);
    Ok(Cloud { index: f, points, t_world_from_camera: pose })
}

/// A pair's ground truth: target i, source j, `t_i_from_j`, overlap (the larger of the two directions'
/// fractions of points with a neighbour within [`OVERLAP_RADIUS`]) and the information matrix of the
/// source's overlapping points (in the source frame), all on clouds downsampled to [`PAIR_VOXEL`].
pub struct PairTruth {
    pub gt: GtPair,
    pub overlap: f64,
    /// The source side alone: the fraction of cloud j's points with a neighbour in cloud i.
    pub source_overlap: f64,
    pub info: nalgebra::Matrix6<f64>,
}

/// Ground truth of every pair of clouds `(i, j)`, `i < j` by position in `clouds`, that `keep(index i,
/// index j)` accepts and whose overlap is in `[MIN_OVERLAP, max_overlap]`; `n` is the count written in
/// gt.log headers.
pub fn pair_truths(
    clouds: &[Cloud],
    n: usize,
    max_overlap: f64,
    keep: &dyn Fn(usize, usize) -> bool,
) -> Vec<PairTruth> {
    let down: Vec<Vec<Point>> = clouds.par_iter().map(|c| voxel_downsample(&c.points, PAIR_VOXEL)).collect();
    let mut todo = Vec::new();
    for a in 0..clouds.len() {
        for b in a + 1..clouds.len() {
            if keep(clouds[a].index, clouds[b].index) {
                todo.push((a, b));
            }
        }
    }
    todo.into_par_iter()
        .filter_map(|(a, b)| {
            let t = relative_pose(&clouds[a].t_world_from_camera, &clouds[b].t_world_from_camera);
            let ov = overlap(&down[b], &down[a], &t, OVERLAP_RADIUS);
            let o = ov.source.max(ov.target);
            if !(MIN_OVERLAP..=max_overlap).contains(&o) {
                return None;
            }
            let index = RadiusIndex::new(&down[a], OVERLAP_RADIUS);
            let moved = transform_points(&down[b], &t);
            let overlapping: Vec<Point> =
                down[b].iter().zip(&moved).filter(|(_, m)| index.has_neighbor(m)).map(|(p, _)| *p).collect();
            Some(PairTruth {
                gt: GtPair { i: clouds[a].index, j: clouds[b].index, n, t_i_from_j: t },
                overlap: o,
                source_overlap: ov.source,
                info: information_matrix(&overlapping),
            })
        })
        .collect()
}

/// Writes `pairs` of `scene` into `<root>/metadata/benchmarks/<name>/<scene>/` (gt.log, gt.info, gt_overlap.log).
pub fn write_benchmark(root: &Path, name: &str, scene: &str, pairs: &[&PairTruth]) -> Result<()> {
    let dir = root.join("metadata/benchmarks").join(name).join(scene);
    write_gt_log(&dir.join("gt.log"), &pairs.iter().map(|p| p.gt.clone()).collect::<Vec<_>>())?;
    write_gt_info(&dir.join("gt.info"), &pairs.iter().map(|p| (p.gt.clone(), p.info)).collect::<Vec<_>>())?;
    write_gt_overlap(
        &dir.join("gt_overlap.log"),
        &pairs.iter().map(|p| ((p.gt.i, p.gt.j), p.overlap)).collect::<Vec<_>>(),
    )
}

#[cfg(test)]
mod tests {
    use super::fragments_within;

    #[test]
    fn fragments_within_a_frame_range() {
        // Official: 50-frame fragments of frames 0..200 are 0..4; of 100..400, 2..8.
        assert_eq!(fragments_within(0, 200, 50, 50), 0..4);
        assert_eq!(fragments_within(100, 400, 50, 50), 2..8);
        assert_eq!(fragments_within(0, 199, 50, 50), 0..3);
        // Stride 10: fragment k starts at 10k and needs frames up to 10k + 49 < end.
        assert_eq!(fragments_within(0, 200, 50, 10), 0..16);
        assert_eq!(fragments_within(300, 400, 50, 10), 30..36);
        assert_eq!(fragments_within(0, 40, 50, 10), 0..0);
    }
}
