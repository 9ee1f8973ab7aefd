//! Pure geometry: intrinsics, depth maps, SE(3) poses, z-buffer projection, crops, voxels, overlap,
//! fixed-radius neighbour search.
//!
//! Units: metres (`f32` for points and depth, `f64` for poses and intrinsics). Pixel convention (the
//! official code's): pixel (column c, row r) has the integer coordinate (c, r), so a point projects to
//! `c = round_half_even(x·fx/z + cx)`. Poses are named `t_<to>_from_<from>`: `p_to = R·p_from + t`.

pub mod crop;
pub mod depth;
pub mod depth_filters;
pub mod intrinsics;
pub mod overlap;
pub mod overlap_estimate;
pub mod pose;
pub mod pose_sampling;
pub mod projection;
pub mod radius_index;
pub mod voxel;

pub use crop::AxisBox;
pub use depth::{backproject, backproject_with_pixels, DepthMap, DepthRange};
pub use depth_filters::valid_min3x3;
pub use intrinsics::{Intrinsics, ResizeCrop};
pub use overlap::{overlap, Overlap};
pub use radius_index::RadiusIndex;
pub use overlap_estimate::view_overlap;
pub use pose::{pose_from_rows, pose_to_rows, relative_pose, transform_points};
pub use pose_sampling::PivotPoseSampler;
pub use projection::{project_zbuffer, Projection};
pub use voxel::{voxel_downsample, voxel_downsample_tagged, PointTag};

/// A 3D point in metres.
pub type Point = nalgebra::Point3<f32>;

/// 1.5·2^52: adding it to an integer-valued f64 `n` with `|n| < 2^51` puts `n` in the low bits of the sum's
/// mantissa, a float-to-integer conversion that vectorises (z-buffer pixel indices, voxel keys).
pub(crate) const F64_TO_INT_MAGIC: f64 = 6_755_399_441_055_744.0;
