//! The pinhole camera of the TSDF inner loops, in f32: world → camera rotation and translation and the
//! intrinsics.

use crate::geometry::Intrinsics;
use nalgebra::{Isometry3, Matrix3, Vector3};

/// A pinhole camera in f32 for the inner loops: world → camera rotation and translation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Camera {
    /// `R_camera_from_world`, row-major.
    pub(crate) r: [[f32; 3]; 3],
    /// `t_camera_from_world`, metres.
    pub(crate) t: [f32; 3],
    pub(crate) fx: f32,
    pub(crate) fy: f32,
    pub(crate) cx: f32,
    pub(crate) cy: f32,
    pub(crate) width: usize,
    pub(crate) height: usize,
}

impl Camera {
    pub(crate) fn new(k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Camera {
        let inv = t_world_from_camera.inverse();
        let m: Matrix3<f64> = inv.rotation.to_rotation_matrix().into_inner();
        let t: Vector3<f64> = inv.translation.vector;
        Camera {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)] as f32)),
            t: [t.x as f32, t.y as f32, t.z as f32],
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            width: k.width as usize,
            height: k.height as usize,
        }
    }

    /// `R·p + t`: a world point in camera coordinates.
    #[inline]
    pub(crate) fn camera_point(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.r;
        [0, 1, 2].map(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + self.t[i])
    }
}
