//! Smooth hand-held camera paths through a generated room: the camera circles the middle of the room
//! at head height, looking outwards and slightly down at the walls and furniture, with slow swings of
//! heading, pitch, height and radius, like a person scanning the room with a 30 Hz depth sensor.

use super::room::{camera_zone, LOW_TOP_M};
use super::scene::Scene;
use crate::rng::Rng;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use std::f64::consts::{PI, TAU};

/// Clearance (m) kept between the camera centre and every surface.
pub const CAMERA_CLEARANCE_M: f64 = 0.25;

/// Camera-to-world pose of a camera at `position` whose optical axis has heading `yaw` (radians
/// about world z, 0 = +x), elevation `pitch` (radians, negative looks down) and `roll` about the
/// optical axis (radians); `pitch` must lie strictly between −π/2 and π/2. Camera frame: x right,
/// y down, z forward.
pub fn look_pose(position: Point3<f64>, yaw: f64, pitch: f64, roll: f64) -> Isometry3<f64> {
    let f = Vector3::new(yaw.cos() * pitch.cos(), yaw.sin() * pitch.cos(), pitch.sin());
    let right = f.cross(&Vector3::z()).normalize();
    let down = f.cross(&right);
    let (s, c) = roll.sin_cos();
    let (x, y) = (right * c + down * s, down * c - right * s);
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, f]));
    Isometry3::from_parts(Translation3::from(position.coords), UnitQuaternion::from_rotation_matrix(&rot))
}

/// A slow sinusoid: amplitude, period in frames, phase.
struct Wave(f64, f64, f64);

impl Wave {
    fn random(rng: &mut Rng, amplitude: f64, periods: (f64, f64)) -> Wave {
        Wave(amplitude, rng.uniform_range(periods.0, periods.1), rng.uniform_range(0.0, TAU))
    }
    fn at(&self, i: f64) -> f64 {
        self.0 * (TAU * i / self.1 + self.2).sin()
    }
}

/// One candidate path; `None` if a pose comes closer than [`CAMERA_CLEARANCE_M`] to a surface.
fn attempt(scene: &Scene, min: Point3<f64>, max: Point3<f64>, n_frames: usize, rng: &mut Rng) -> Option<Vec<Isometry3<f64>>> {
    let size = max - min;
    let centre = nalgebra::center(&min, &max);
    // Inside the open middle of the room, clear of the furniture along the walls.
    let (zx, zy) = camera_zone(&size);
    let ax = zx * rng.uniform_range(0.7, 1.0);
    let ay = zy * rng.uniform_range(0.7, 1.0);
    // About 1.5 cm per frame along the ring (0.45 m/s), at most 0.7° of orbit per frame.
    let omega = (0.015 / ax.max(ay).max(0.05)).min(0.012) * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
    let phase = rng.uniform_range(0.0, TAU);
    let height = rng.uniform_range(1.4, 1.6).min(max.z - 0.5).max(LOW_TOP_M + 0.3);
    let pitch0 = rng.uniform_range(-0.5, -0.25);
    let radius = Wave::random(rng, 0.15, (150.0, 300.0));
    let bob = Wave::random(rng, 0.06, (90.0, 200.0));
    let swing = rng.uniform_range(0.3, 0.7);
    let yaw_swing = Wave::random(rng, swing, (150.0, 300.0));
    let nod = Wave::random(rng, 0.1, (100.0, 250.0));
    let tilt = Wave::random(rng, 0.04, (120.0, 300.0));
    let poses: Vec<Isometry3<f64>> = (0..n_frames)
        .map(|i| {
            let t = i as f64;
            let phi = phase + omega * t;
            let s = 0.85 + radius.at(t);
            let p = Point3::new(centre.x + ax * s * phi.cos(), centre.y + ay * s * phi.sin(), min.z + height + bob.at(t));
            // Outward along the ring's radius, swinging to either side.
            look_pose(p, phi + yaw_swing.at(t), pitch0 + nod.at(t), tilt.at(t))
        })
        .collect();
    let free = poses.iter().all(|q| scene.is_free(&Point3::from(q.translation.vector), CAMERA_CLEARANCE_M));
    free.then_some(poses)
}

/// `n_frames` camera-to-world poses of a smooth hand-held path inside `scene`'s room (consecutive
/// poses at most 1.5 cm and about 0.1–2° apart, camera 1.34–1.66 m above the floor, looking 9–34°
/// down, at least [`CAMERA_CLEARANCE_M`] from every surface). The same seed gives the same path.
/// Panics when the scene has no room shell.
pub fn trajectory(scene: &Scene, n_frames: usize, seed: u64) -> Vec<Isometry3<f64>> {
    let (min, max) = scene.room().expect("trajectory needs a scene with a room shell");
    let base = Rng::new(seed).fork(0x7EA7);
    for k in 0..32 {
        if let Some(p) = attempt(scene, min, max, n_frames, &mut base.fork(k)) {
            return p;
        }
    }
    // Not reached for generated rooms (their middle is free above LOW_TOP_M); for hand-made ones,
    // turn slowly on the spot at the room centre.
    let c = nalgebra::center(&min, &max);
    let p = Point3::new(c.x, c.y, min.z + (LOW_TOP_M + 0.4).min(max.z - 0.5));
    let yaw0 = base.fork(99).uniform_range(-PI, PI);
    (0..n_frames).map(|i| look_pose(p, yaw0 + 0.01 * i as f64, -0.3, 0.0)).collect()
}

#[cfg(test)]
mod tests {
    use super::super::SceneConfig;
    use super::*;
    use crate::geometry::Intrinsics;

    #[test]
    fn look_pose_axes_follow_the_camera_convention() {
        let p = look_pose(Point3::new(1.0, 2.0, 1.5), 0.0, 0.0, 0.0);
        let r = p.rotation.to_rotation_matrix();
        // Optical axis (camera z) along world +x, image down (camera y) along world −z, right along −y.
        assert!((r * Vector3::z() - Vector3::x()).norm() < 1e-12);
        assert!((r * Vector3::y() + Vector3::z()).norm() < 1e-12);
        assert!((r * Vector3::x() + Vector3::y()).norm() < 1e-12);
        assert_eq!(p.translation.vector, Vector3::new(1.0, 2.0, 1.5));
    }

    #[test]
    fn paths_are_smooth_free_level_and_see_the_room_at_indoor_distances() {
        let k = Intrinsics::new(146.25, 146.25, 80.0, 60.0, 160, 120).unwrap();
        for seed in 0..12u64 {
            let scene = Scene::generate(&SceneConfig::default(), seed);
            let (min, max) = scene.room().unwrap();
            let poses = trajectory(&scene, 240, seed);
            assert_eq!(poses.len(), 240);
            assert_eq!(poses, trajectory(&scene, 240, seed), "deterministic");
            for (i, p) in poses.iter().enumerate() {
                let c = Point3::from(p.translation.vector);
                assert!(p.to_homogeneous().iter().all(|v| v.is_finite()));
                assert!((0..3).all(|a| c[a] > min[a] + 0.3 && c[a] < max[a] - 0.3), "seed {seed} frame {i}: {c}");
                assert!(scene.is_free(&c, CAMERA_CLEARANCE_M), "seed {seed} frame {i}: camera touches an object");
                // Roughly level: the image's x axis stays within 5° of horizontal.
                assert!((p.rotation * Vector3::x()).z.abs() < 5f64.to_radians().sin());
            }
            for w in poses.windows(2) {
                let d = w[0].inverse() * w[1];
                assert!(d.translation.vector.norm() < 0.05, "seed {seed}: step {}", d.translation.vector.norm());
                assert!(d.rotation.angle() < 3f64.to_radians(), "seed {seed}: turn {}", d.rotation.angle().to_degrees());
            }
            for p in poses.iter().step_by(60) {
                let depth = scene.render_depth(&k, p);
                let mut z: Vec<f32> = depth.data().to_vec();
                z.sort_by(f32::total_cmp);
                let median = z[z.len() / 2];
                let in_range = z.iter().filter(|v| (0.4..8.0).contains(*v)).count();
                assert!((0.5..4.0).contains(&median), "seed {seed}: median depth {median}");
                assert!(in_range > z.len() * 9 / 10, "seed {seed}: {in_range} pixels in the sensor range");
            }
        }
    }
}
