//! The labelling algorithm of the correction network's training data (paper §3.3, reference §4.2), as pure
//! functions: fuse a window of frames into the reference camera ([`fuse_window`]), then for a target pose
//! render the dense and sparse re-projections and label them ([`label_view`], [`crate::correction::keep_label`]).

use super::config::{DenseMode, LabelsConfig};
use crate::correction::keep_label;
use crate::error::{Error, Result};
use crate::geometry::{project_zbuffer, relative_pose, voxel_downsample, DepthMap, Intrinsics, Point};
use crate::sources::Frame;
use crate::tsdf::TsdfVolume;
use nalgebra::Isometry3;

/// A window fused in its reference camera's frame.
pub struct FusedWindow {
    /// Working intrinsics of the reference camera (the target views use them too).
    pub k: Intrinsics,
    /// Dense surface points `P_d` inside the crop box.
    pub dense: Vec<Point>,
    /// Their voxel-downsampled copy `P_s` (the network's input is re-projected from it).
    pub sparse: Vec<Point>,
    /// The volume, kept when `I_d` is ray cast ([`DenseMode::Raycast`]).
    pub volume: Option<TsdfVolume>,
}

/// One labelled target view.
pub struct LabelledView {
    /// `I_s`: the sparse cloud z-buffered into the target camera (the network's input).
    pub sparse: DepthMap,
    /// `I_d`: the dense reference depth.
    pub dense: DepthMap,
    /// `M_gt`, `true` = keep.
    pub keep: Vec<bool>,
}

/// Fuses `frames` (each with its camera-to-world pose) into a TSDF volume in the camera frame of
/// `reference`, and extracts the dense surface points and their sparse copy as `config` says. Frames are
/// taken one at a time, so memory holds the volume and one frame. Errors name the file of a frame without
/// pose, and the reference when the window has no surface inside the crop box.
pub fn fuse_window(reference: &Frame, frames: impl Iterator<Item = Result<Frame>>, config: &LabelsConfig) -> Result<FusedWindow> {
    let no_pose = |f: &Frame| Error::input(&f.depth_path, "frame has no camera pose (missing pose file)");
    let t_world_from_ref = reference.t_world_from_camera.ok_or_else(|| no_pose(reference))?;
    let mut volume = TsdfVolume::new(config.tsdf.clone())?;
    for f in frames {
        let f = f?;
        let pose = f.t_world_from_camera.ok_or_else(|| no_pose(&f))?;
        volume.integrate(&f.depth, &f.intrinsics, &relative_pose(&t_world_from_ref, &pose))?;
    }
    let w = &config.working;
    let dense = w.crop_box.crop(&volume.extract_points(config.clouds.weight_threshold));
    if dense.is_empty() {
        return Err(Error::input(&reference.depth_path, "the fused window has no surface inside the crop box"));
    }
    let (_, k) = w.map_intrinsics(&reference.intrinsics)?;
    let sparse = voxel_downsample(&dense, config.clouds.sparse_voxel);
    let volume = (config.clouds.dense == DenseMode::Raycast).then_some(volume);
    Ok(FusedWindow { k, dense, sparse, volume })
}

/// The labelled view of `window` from the target camera `t_target_from_reference`: `I_s` from the sparse
/// points, `I_d` ray cast from the volume (its empty pixels from the z-buffered dense points, which cover
/// thin edges the rays miss) or z-buffered from the dense points, and `M_gt = |I_s − I_d| < τ_gt`.
pub fn label_view(window: &FusedWindow, t_target_from_reference: &Isometry3<f64>, tau_gt: f32) -> Result<LabelledView> {
    let k = &window.k;
    let points = project_zbuffer(&window.dense, t_target_from_reference, k, false).depth;
    let dense = match &window.volume {
        Some(v) => fill_empty(v.raycast(k, &t_target_from_reference.inverse())?, &points),
        None => points,
    };
    let sparse = project_zbuffer(&window.sparse, t_target_from_reference, k, false).depth;
    let keep = keep_label(&sparse, &dense, tau_gt);
    Ok(LabelledView { sparse, dense, keep })
}

/// `primary` with its empty pixels taken from `fallback`.
fn fill_empty(mut primary: DepthMap, fallback: &DepthMap) -> DepthMap {
    for (r, p) in primary.data_mut().iter_mut().zip(fallback.data()) {
        if *r == 0.0 {
            *r = *p;
        }
    }
    primary
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn follows_the_reference_cases() {
        let s = DepthMap::new(5, 1, vec![0.0, 2.0, 2.0, 2.0, 0.0]).unwrap();
        let d = DepthMap::new(5, 1, vec![0.0, 0.0, 2.04, 1.5, 1.0]).unwrap();
        // both empty: keep; sparse only: drop; within 5 cm: keep; 50 cm behind: drop; dense only: 0 vs 1 m -> 0.
        assert_eq!(keep_label(&s, &d, 0.05), vec![true, false, true, false, false]);
    }

    #[test]
    fn fill_empty_keeps_primary_depths() {
        let a = DepthMap::new(3, 1, vec![1.0, 0.0, 2.0]).unwrap();
        let b = DepthMap::new(3, 1, vec![5.0, 6.0, 0.0]).unwrap();
        assert_eq!(fill_empty(a, &b).data(), &[1.0, 6.0, 2.0]);
    }
}
