//! Integration tests of the synthetic scenes through the public API: exact rendering checked against
//! an independent distance computation, trajectories, sensor determinism across thread counts, and
//! the 3DMatch export read back from disk.

use nalgebra::{Isometry3, Point3, Vector3};
use pointreggpt::geometry::{backproject, DepthRange, Intrinsics};
use pointreggpt::sources::depth_png::read_depth_png;
use pointreggpt::sources::synthetic::{
    Scene, Shape, SyntheticConfig, SyntheticSequence, DEFAULT_INTRINSICS,
};
use pointreggpt::sources::text::{read_intrinsics_file, read_pose_file};

/// Distance (m) from `p` to the surface of `s`, written out independently of the library.
fn surface_distance(s: &Shape, p: &Point3<f64>) -> f64 {
    match s {
        Shape::Plane { point, normal } => (p - point).dot(normal).abs(),
        Shape::Room { min, max } => {
            let faces = [p.x - min.x, max.x - p.x, p.y - min.y, max.y - p.y, p.z - min.z, max.z - p.z];
            faces.iter().map(|d| d.abs()).fold(f64::INFINITY, f64::min)
        }
        Shape::Cuboid { center, half, yaw } => {
            let d = p - center;
            let local = [d.x * yaw.cos() + d.y * yaw.sin(), -d.x * yaw.sin() + d.y * yaw.cos(), d.z];
            let out: Vec<f64> = (0..3).map(|i| (local[i].abs() - half[i]).max(0.0)).collect();
            let outside = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt();
            let inside = (0..3).map(|i| half[i] - local[i].abs()).fold(f64::INFINITY, f64::min);
            if outside > 0.0 { outside } else { inside }
        }
        Shape::Sphere { center, radius } => ((p - center).norm() - radius).abs(),
        Shape::Cylinder { axis_x, axis_y, radius, z_min, z_max } => {
            let rho = ((p.x - axis_x).powi(2) + (p.y - axis_y).powi(2)).sqrt();
            let dr = (rho - radius).max(0.0);
            let dz = (z_min - p.z).max(p.z - z_max).max(0.0);
            if dr > 0.0 || dz > 0.0 {
                (dr * dr + dz * dz).sqrt()
            } else {
                (radius - rho).min(p.z - z_min).min(z_max - p.z)
            }
        }
    }
}

fn small_config(frames: usize) -> SyntheticConfig {
    SyntheticConfig {
        intrinsics: Intrinsics::new(146.25, 146.25, 80.0, 60.0, 160, 120).unwrap(),
        frames,
        ..SyntheticConfig::default()
    }
}

#[test]
fn rendered_depth_backprojects_onto_scene_surfaces() {
    let _timing = crate::support::timed();
    for seed in [21u64, 22, 23, 24] {
        let seq = SyntheticSequence::generate(&small_config(30), seed).unwrap();
        for i in [0, 15, 29] {
            let depth = seq.true_depth(i);
            let pts = backproject(&depth, &seq.intrinsics, DepthRange::ANY);
            assert_eq!(pts.len(), 160 * 120, "seed {seed}: every ray of a closed room hits");
            let mut off = 0;
            for p in &pts {
                let w = seq.poses[i] * Point3::new(p.x as f64, p.y as f64, p.z as f64);
                let d = seq.scene.shapes().iter().map(|s| surface_distance(s, &w)).fold(f64::INFINITY, f64::min);
                off += usize::from(d > 1e-4);
            }
            assert_eq!(off, 0, "seed {seed} frame {i}: {off} points farther than 0.1 mm from every surface");
        }
    }
}

#[test]
fn oracle_renders_an_analytic_wall_exactly() {
    let _timing = crate::support::timed();
    let d = 2.345;
    let seq = SyntheticSequence {
        scene: Scene::from_shapes(vec![Shape::Plane { point: Point3::new(0.0, 0.0, d), normal: Vector3::z() }]),
        intrinsics: DEFAULT_INTRINSICS,
        poses: vec![Isometry3::identity()],
        sensor: Default::default(),
        seed: 0,
    };
    let depth = seq.true_depth(0);
    assert!(depth.data().iter().all(|&z| z == d as f32));
    // Moving the camera 0.5 m towards the wall and turning it about its axis changes z to d − 0.5.
    let pose = Isometry3::new(Vector3::new(0.3, -0.2, 0.5), Vector3::new(0.0, 0.0, 0.4));
    assert!(seq.true_depth_at(&pose).data().iter().all(|&z| (z as f64 - (d - 0.5)).abs() < 1e-6));
}

#[test]
fn trajectories_see_the_room_like_a_handheld_kinect() {
    let _timing = crate::support::timed();
    for seed in [1u64, 2, 3] {
        let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 120, ..Default::default() }, seed).unwrap();
        let (min, max) = seq.scene.room().unwrap();
        for (i, p) in seq.poses.iter().enumerate() {
            let c = Point3::from(p.translation.vector);
            assert!(p.to_homogeneous().iter().all(|v| v.is_finite()));
            assert!((0..3).all(|a| c[a] > min[a] && c[a] < max[a]), "frame {i} outside the room");
            let inside_object = seq.scene.shapes().iter().any(|s| s.is_solid() && s.signed_distance(&c) <= 0.0);
            assert!(!inside_object, "frame {i}: camera inside an object");
        }
        for w in seq.poses.windows(2) {
            let d = w[0].inverse() * w[1];
            assert!(d.translation.vector.norm() < 0.10 && d.rotation.angle() < 5f64.to_radians());
        }
        for i in [0, 60, 119] {
            let truth = seq.true_depth(i);
            let mut z = truth.data().to_vec();
            z.sort_by(f32::total_cmp);
            assert!((0.5..4.0).contains(&z[z.len() / 2]), "seed {seed} frame {i}: median {}", z[z.len() / 2]);
            let frame = seq.frame(i);
            let valid = frame.depth.valid_count() as f64 / (640.0 * 480.0);
            assert!(valid > 0.8, "seed {seed} frame {i}: {valid} of the pixels valid");
            // Kept readings are the truth plus noise of a few σ.
            let sigma_ok = frame.depth.data().iter().zip(truth.data()).filter(|(n, _)| **n > 0.0).all(|(n, t)| {
                (n - t).abs() as f64 <= 6.0 * seq.sensor.sigma(*t as f64) + 0.0006
            });
            assert!(sigma_ok, "seed {seed} frame {i}: a reading far from the truth");
        }
    }
}

#[test]
fn frames_are_identical_for_one_and_two_threads_and_depend_on_the_seed() {
    let _timing = crate::support::timed();
    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 5, ..Default::default() }, 77).unwrap();
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let one = pool(1).install(|| seq.frame(3));
    let two = pool(2).install(|| seq.frame(3));
    let bits = |f: &pointreggpt::sources::Frame| f.depth.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one), bits(&two));
    assert_eq!(one, two);
    assert_eq!(one.key, "synthetic-77/frame-000003");
    assert_eq!(one.depth_path.to_string_lossy(), "synthetic://77/frame-000003");
    assert_eq!(one.t_world_from_camera, Some(seq.poses[3]));
    let raw: Vec<u8> = one.depth.to_raw(1000.0).iter().flat_map(|v| v.to_le_bytes()).collect();
    assert_eq!(one.content_hash, blake3::hash(&raw).to_hex().to_string());
    assert_ne!(bits(&seq.frame(2)), bits(&one), "frames differ");
    let mut other = seq.clone();
    other.seed = 78;
    assert_ne!(bits(&other.frame(3)), bits(&one), "another seed, other noise");
    let again = SyntheticSequence::generate(&SyntheticConfig { frames: 5, ..Default::default() }, 77).unwrap();
    assert_eq!(again, seq);
    assert_eq!(again.frame(3), one);
}

#[test]
fn write_3dmatch_reads_back_as_the_served_frames() {
    let _timing = crate::support::timed();
    let seq = SyntheticSequence::generate(&small_config(4), 5).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("synthetic-5");
    seq.write_3dmatch(&root).unwrap();
    assert_eq!(read_intrinsics_file(&root.join("camera-intrinsics.txt"), 160, 120).unwrap(), seq.intrinsics);
    for i in 0..4 {
        let frame = seq.frame(i);
        let png = read_depth_png(&root.join(format!("frame-{i:06}.depth.png"))).unwrap();
        assert_eq!((png.width, png.height), (160, 120));
        assert_eq!(png.data, frame.depth.to_raw(1000.0));
        let back = pointreggpt::geometry::DepthMap::from_raw(160, 120, &png.data, 1000.0, &[0, 65535]).unwrap();
        assert_eq!(back, frame.depth, "metres decoded from the PNG equal the served ones bit for bit");
        let pose = read_pose_file(&root.join(format!("frame-{i:06}.pose.txt"))).unwrap();
        assert!((pose.to_homogeneous() - seq.poses[i].to_homogeneous()).abs().max() < 1e-12);
    }
    // Through the 3DMatch reader: one flat sequence whose frames load as the served ones.
    let sequences = pointreggpt::sources::threedmatch::open(&root).unwrap();
    assert_eq!(sequences.len(), 1);
    assert_eq!(sequences[0].frames.len(), 4);
    for (i, fr) in sequences[0].frames.iter().enumerate() {
        let loaded = fr.load().unwrap();
        let served = seq.frame(i);
        assert_eq!(loaded.key, served.key, "the folder name makes the keys agree");
        assert_eq!(loaded.intrinsics, seq.intrinsics);
        assert_eq!(loaded.depth, served.depth);
        let pose = loaded.t_world_from_camera.unwrap();
        assert!((pose.to_homogeneous() - seq.poses[i].to_homogeneous()).abs().max() < 1e-12);
    }
}
