//! TSDF fusion by voxel hashing: integrate depth maps, extract surface points and meshes, ray cast.
//!
//! The interface follows Open3D's: [`TsdfVolume::new`] with a [`TsdfConfig`] (checked),
//! [`TsdfVolume::reset`], [`TsdfVolume::integrate`]`(depth, intrinsics, t_world_from_camera)`,
//! [`TsdfVolume::extract_points`], [`TsdfVolume::extract_mesh`], and [`TsdfVolume::raycast`].
//! Units: metres for depth, distances and coordinates; pixels for intrinsics; poses camera-to-world.
//! The sign convention is KinectFusion's and Open3D's: positive in front of the surface (free
//! space), negative behind it. Voxel `i` spans `[i·s, (i+1)·s)` (origin at 0) with its centre at
//! `(i + ½)·s`. Every result is the same bit for bit whatever the rayon thread count.
//!
//! Files: [`config`] (parameters), [`volume`] (hashed blocks), `integrate` (block allocation and
//! the parallel update) with its per-block kernel in `update` (scalar and AVX2, bit-identical) and the
//! f32 camera both use in `camera`,
//! `extract` (points), `marching_cubes` with its lookup tables in [`tables`], `raycast` with its
//! lookups in `sample`, [`mesh`] (the mesh type; [`crate::ply`] writes it), and the fusion helpers below.

mod camera;
pub mod config;
mod extract;
mod integrate;
mod marching_cubes;
pub mod mesh;
mod raycast;
mod sample;
pub mod tables;
mod update;
pub mod volume;

pub use config::TsdfConfig;
pub use extract::MAX_CROSSING_TSDF;
pub use mesh::Mesh;
pub use volume::{TsdfVolume, Voxel};

use crate::error::{Error, Result};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::Isometry3;

/// Fuses `frames` — depth (metres, 0 = invalid), intrinsics (pixels) and camera-to-world pose — in
/// order into a new volume whose coordinates are the poses' world frame.
pub fn fuse_frames(frames: &[(DepthMap, Intrinsics, Isometry3<f64>)], config: &TsdfConfig) -> Result<TsdfVolume> {
    let mut volume = TsdfVolume::new(config.clone())?;
    for (depth, k, pose) in frames {
        volume.integrate(depth, k, pose)?;
    }
    Ok(volume)
}

/// Fuses `frames` as a 3DMatch fragment: in the camera frame of `frames[base]`, each frame entering
/// with `t_base_from_camera = inv(t_world_from_base) · t_world_from_camera`. The volume's
/// coordinates are metres in the base camera (x right, y down, z forward).
pub fn fuse_fragment(
    frames: &[(DepthMap, Intrinsics, Isometry3<f64>)],
    base: usize,
    config: &TsdfConfig,
) -> Result<TsdfVolume> {
    let t_base_from_world = frames
        .get(base)
        .ok_or_else(|| Error::InvalidArgument(format!("base frame {base} of a {}-frame fragment", frames.len())))?
        .2
        .inverse();
    let mut volume = TsdfVolume::new(config.clone())?;
    for (depth, k, t_world_from_camera) in frames {
        volume.integrate(depth, k, &(t_base_from_world * t_world_from_camera))?;
    }
    Ok(volume)
}

#[cfg(test)]
mod tests;
