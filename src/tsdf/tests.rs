//! Tests of integration, extraction and ray casting against analytic planes, and of determinism.

use super::*;
use crate::geometry::Point;
use crate::sources::synthetic::{SensorConfig, SyntheticConfig, SyntheticSequence};
use nalgebra::{Translation3, UnitQuaternion, Vector3};

fn small_k() -> Intrinsics {
    Intrinsics::new(150.0, 150.0, 80.0, 60.0, 160, 120).unwrap()
}

fn plane(d: f32) -> DepthMap {
    DepthMap::new(160, 120, vec![d; 160 * 120]).unwrap()
}

fn median(mut v: Vec<f32>) -> f32 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

#[test]
fn fronto_parallel_plane_matches_the_analytic_tsdf() {
    let (d, cfg) = (1.0037f32, TsdfConfig::coarse());
    let mut v = TsdfVolume::new(cfg.clone()).unwrap();
    v.integrate(&plane(d), &small_k(), &Isometry3::identity()).unwrap();
    assert_eq!(v.frame_count(), 1);
    let side = cfg.block_side as i32;
    let (mut observed, mut checked_band) = (0, 0);
    for (b, blk) in v.coords.iter().zip(v.voxels.chunks(v.side.pow(3))) {
        for (i, vox) in blk.iter().enumerate() {
            let g = [
                b[0] * side + i as i32 % side,
                b[1] * side + i as i32 / side % side,
                b[2] * side + i as i32 / side / side,
            ];
            let c = v.voxel_center(g);
            let (u, r) = (150.0 * c.x / c.z + 80.0, 150.0 * c.y / c.z + 60.0);
            let inside = c.z > 0.0 && (-0.5..159.5).contains(&u) && (-0.5..119.5).contains(&r);
            let expect = ((d - c.z) / cfg.truncation_m).min(1.0);
            if vox.weight > 0.0 {
                observed += 1;
                assert_eq!(vox.weight, 1.0);
                assert!(inside && d - c.z >= -cfg.truncation_m, "voxel {g:?} at {c:?} should not be observed");
                assert!((vox.tsdf - expect).abs() < 1e-5, "voxel {g:?}: tsdf {} vs analytic {expect}", vox.tsdf);
            } else if inside && (u - 80.0).abs() < 70.0 && (r - 60.0).abs() < 50.0 {
                assert!(d - c.z < -cfg.truncation_m, "voxel {g:?} at {c:?} in the band was not updated");
            }
            if inside && (d - c.z).abs() < cfg.truncation_m {
                checked_band += 1;
            }
        }
    }
    assert!(observed > 10_000 && checked_band > 5_000, "{observed} {checked_band}");
    // Every voxel of the band on the optical axis is allocated and observed.
    for zi in 97..=103 {
        let vox = v.voxel([0, 0, zi]).expect("band voxel allocated");
        assert_eq!(vox.weight, 1.0, "z index {zi}");
    }

    let pts = v.extract_points(0.0);
    // The image covers about 1.07 m × 0.80 m at 1 m: ~107 × 80 voxel columns, one crossing each.
    assert!(pts.len() > 8_000, "{}", pts.len());
    let worst = pts.iter().map(|p| (p.z - d).abs()).fold(0.0, f32::max);
    assert!(worst < 1e-3, "extracted point {worst} m off the plane");

    let ray = v.raycast(&small_k(), &Isometry3::identity()).unwrap();
    let hits: Vec<f32> = ray.data().iter().copied().filter(|z| *z > 0.0).collect();
    assert!(hits.len() as f64 > 0.9 * 160.0 * 120.0, "{} hits", hits.len());
    assert!(hits.iter().all(|z| (z - d).abs() < 1e-3), "raycast off the plane");
    assert!((ray.at(80, 60) - d).abs() < 2e-4, "{}", ray.at(80, 60));
}

#[test]
fn repeated_observations_average_and_cap_the_weight() {
    let cfg = TsdfConfig { max_weight: 3.0, ..TsdfConfig::coarse() };
    let mut v = TsdfVolume::new(cfg).unwrap();
    let k = small_k();
    // Plane at 1.000 m twice, then at 1.020 m twice: running average, then the cap at 3.
    for d in [1.0, 1.0, 1.02, 1.02] {
        v.integrate(&plane(d), &k, &Isometry3::identity()).unwrap();
    }
    let c = v.voxel_center([0, 0, 98]); // centre z = 0.985
    let t = |d: f32| (d - c.z) / 0.04;
    let after3 = (2.0 * t(1.0) + t(1.02)) / 3.0;
    let expect = (after3 * 3.0 + t(1.02)) / 4.0;
    let vox = v.voxel([0, 0, 98]).unwrap();
    assert_eq!(vox.weight, 3.0);
    assert!((vox.tsdf - expect).abs() < 1e-5, "{} vs {expect}", vox.tsdf);
}

#[test]
fn invalid_and_out_of_range_depths_are_ignored() {
    let cfg = TsdfConfig { min_depth_m: 0.5, max_depth_m: 3.0, ..TsdfConfig::coarse() };
    let mut data = vec![0.0f32; 160 * 120];
    data[60 * 160 + 80] = 0.3; // too near
    data[60 * 160 + 81] = 3.5; // too far
    let mut v = TsdfVolume::new(cfg).unwrap();
    v.integrate(&DepthMap::new(160, 120, data).unwrap(), &small_k(), &Isometry3::identity()).unwrap();
    assert_eq!(v.block_count(), 0);
    assert!(v.extract_points(0.0).is_empty());
    assert!(v.raycast(&small_k(), &Isometry3::identity()).unwrap().data().iter().all(|z| *z == 0.0));
}

#[test]
fn bad_inputs_are_errors() {
    let mut v = TsdfVolume::new(TsdfConfig::coarse()).unwrap();
    let e = v.integrate(&DepthMap::zeros(10, 10), &small_k(), &Isometry3::identity()).unwrap_err().to_string();
    assert!(e.contains("10x10") && e.contains("160x120"), "{e}");
    let far = Isometry3::translation(1e6, 0.0, 0.0);
    assert!(v.integrate(&plane(1.0), &small_k(), &far).unwrap_err().to_string().contains("too far"));
    let nan = Isometry3::translation(f64::NAN, 0.0, 0.0);
    assert!(v.integrate(&plane(1.0), &small_k(), &nan).is_err());
    assert!(v.raycast(&small_k(), &nan).is_err());
    let e = TsdfVolume::new(TsdfConfig { voxel_size_m: -1.0, ..TsdfConfig::default() }).unwrap_err().to_string();
    assert!(e.contains("voxel_size_m"), "{e}");
}

#[test]
fn fragments_live_in_the_base_camera_frame() {
    // A camera 2 m up and turned: in its own frame the plane is at z = 1.2 m whatever the world pose.
    let base =
        Isometry3::from_parts(Translation3::new(0.3, -1.0, 2.0), UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0));
    let moved = base * Isometry3::translation(0.0, 0.0, 0.05);
    let frames = vec![(plane(1.2), small_k(), base), (plane(1.15), small_k(), moved)];
    let frag = fuse_fragment(&frames, 0, &TsdfConfig::coarse()).unwrap();
    let pts = frag.extract_points(1.0);
    assert!(pts.len() > 5_000);
    assert!(pts.iter().all(|p| (p.z - 1.2).abs() < 1e-3));
    let world = fuse_frames(&frames, &TsdfConfig::coarse()).unwrap();
    let d_frag = frag.raycast(&small_k(), &Isometry3::identity()).unwrap();
    let d_world = world.raycast(&small_k(), &base).unwrap();
    let dz: Vec<f32> = d_frag
        .data()
        .iter()
        .zip(d_world.data())
        .filter(|(a, b)| **a > 0.0 && **b > 0.0)
        .map(|(a, b)| (a - b).abs())
        .collect();
    assert!(dz.len() > 10_000 && median(dz) < 5e-4);
    assert!(fuse_fragment(&frames, 2, &TsdfConfig::coarse()).is_err());
}

#[test]
fn results_are_bit_identical_for_one_and_two_threads() {
    let cfg = SyntheticConfig {
        frames: 6,
        intrinsics: small_k(),
        sensor: SensorConfig::default(),
        ..SyntheticConfig::default()
    };
    let seq = SyntheticSequence::generate(&cfg, 3).unwrap();
    let frames: Vec<(DepthMap, Intrinsics, Isometry3<f64>)> =
        (0..seq.len()).map(|i| (seq.noisy_depth(i), seq.intrinsics, seq.poses[i])).collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let v = fuse_frames(&frames, &TsdfConfig::coarse()).unwrap();
            (v.extract_points(1.0), v.extract_mesh(1.0), v.raycast(&seq.intrinsics, &seq.poses[2]).unwrap())
        })
    };
    let (p1, m1, r1) = run(1);
    let (p2, m2, r2) = run(2);
    assert!(p1.len() > 1_000 && m1.triangles.len() > 1_000, "{} {}", p1.len(), m1.triangles.len());
    let bits = |p: &[Point]| p.iter().flat_map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]).collect::<Vec<u32>>();
    assert_eq!(bits(&p1), bits(&p2));
    assert_eq!(m1, m2);
    assert_eq!(r1, r2);
    // And the surface is where the scene is: within a few mm of the oracle on average.
    let dist: Vec<f32> = p1
        .iter()
        .map(|p| {
            let q = p.cast::<f64>();
            seq.scene.shapes().iter().map(|s| s.signed_distance(&q).abs()).fold(f64::INFINITY, f64::min) as f32
        })
        .collect();
    let mean = dist.iter().sum::<f32>() / dist.len() as f32;
    assert!(mean < 0.005, "mean distance to the true surface {mean} m");
    let _ = Vector3::<f32>::zeros();
}
