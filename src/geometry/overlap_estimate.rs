//! The overlap a target pose will give, estimated before the target view is filled: a target depth map
//! (the re-projection, corrected) made into a cloud the way the build makes the target's, and its overlap
//! with the source measured the way the validate stage measures it.

use super::{backproject, overlap, voxel_downsample, AxisBox, DepthMap, DepthRange, Intrinsics, Point};
use nalgebra::Isometry3;

/// The `overlap_source` the validate stage stores for a pair whose target view is `view` (depth seen by
/// camera `k` at `t_target_from_source`): the view back-projected within `range`, cut to `crop_box` and
/// voxelized at `voxel` in the target frame, and [`overlap`] at `radius` against `source_voxels` (the
/// source cloud as stored). With the view a corrected re-projection, the fill only adds target points, so
/// the stored value is this or a little more.
#[allow(clippy::too_many_arguments)]
pub fn view_overlap(
    source_voxels: &[Point],
    view: &DepthMap,
    t_target_from_source: &Isometry3<f64>,
    k: &Intrinsics,
    range: DepthRange,
    crop_box: &AxisBox,
    voxel: f32,
    radius: f32,
) -> f64 {
    let target = voxel_downsample(&crop_box.crop(&backproject(view, k, range)), voxel);
    overlap(source_voxels, &target, t_target_from_source, radius).source
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::project_zbuffer;

    /// A 2 m × 2 m wall at depth `z` (x, y in [−1, 1]), sampled every `step` metres.
    fn wall(z: f32, step: f32) -> Vec<Point> {
        let n = (2.0 / step).round() as i32;
        (0..=n).flat_map(|i| (0..=n).map(move |j| Point::new(-1.0 + i as f32 * step, -1.0 + j as f32 * step, z))).collect()
    }

    /// The overlap of `memory` with its own re-projection into `t`.
    fn estimate(memory: &[Point], t: &Isometry3<f64>, k: &Intrinsics) -> f64 {
        let voxels = voxel_downsample(memory, 0.025);
        let view = project_zbuffer(memory, t, k, false).depth;
        view_overlap(&voxels, &view, t, k, DepthRange::OFFICIAL, &AxisBox::OFFICIAL, 0.025, 0.0375)
    }

    #[test]
    fn a_wall_seen_head_on_overlaps_fully_and_a_hidden_one_not_at_all() {
        // 256² at fx 200: the camera sees ±0.64·z, so at 1.5 m ±0.96 m: nearly all of the wall.
        let k = Intrinsics::new(200.0, 200.0, 127.5, 127.5, 256, 256).unwrap();
        let front = wall(1.5, 0.005);
        let id = Isometry3::identity();
        let all = estimate(&front, &id, &k);
        assert!(all > 0.97, "{all}");
        // A second wall 1 m behind the first: its voxels have no target neighbour, the front's all do.
        let both: Vec<Point> = front.iter().chain(&wall(2.5, 0.005)).copied().collect();
        let voxels = voxel_downsample(&both, 0.025);
        let front_share = voxels.iter().filter(|p| p.z < 2.0).count() as f64 / voxels.len() as f64;
        let view = project_zbuffer(&both, &id, &k, false).depth;
        let ov = view_overlap(&voxels, &view, &id, &k, DepthRange::OFFICIAL, &AxisBox::OFFICIAL, 0.025, 0.0375);
        assert!((ov - all * front_share).abs() < 0.01, "{ov} vs {}", all * front_share);
    }

    #[test]
    fn a_sideways_move_keeps_the_part_left_in_the_box() {
        // Moving the camera 1 m to the right (points move 1 m left): the wall spans x in [−2, 0] in the
        // target frame, all in view at fx 50, and the crop box keeps x ≥ −1.5: source x in [−0.5, 1].
        let k = Intrinsics::new(50.0, 50.0, 127.5, 127.5, 256, 256).unwrap();
        let w = wall(2.0, 0.005);
        let share = estimate(&w, &Isometry3::translation(-1.0, 0.0, 0.0), &k);
        assert!((share - 0.75).abs() < 0.02, "{share}");
        assert_eq!(estimate(&w, &Isometry3::translation(-5.0, 0.0, 0.0), &k), 0.0, "moved out of the box");
    }
}
