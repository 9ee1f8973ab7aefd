//! TSDF fusion through the public API, checked against independent truths: the synthetic scenes'
//! exact geometry (distance of fused surface points to the true surfaces, ray-cast depth against
//! the analytic render), and on real 7-Scenes data the depth a held-out frame actually captured.
//!
//! The real-data test needs `POINTREGGPT_REAL_DATA` (see `support::real_data`).

use nalgebra::{Isometry3, Point3};
use pointreggpt::geometry::{DepthMap, Intrinsics, Point};
use pointreggpt::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use pointreggpt::sources::threedmatch;
use pointreggpt::tsdf::{fuse_frames, TsdfConfig};
use rayon::prelude::*;
use std::time::Instant;

use pointreggpt::ply::read_ply;
use crate::support::real_data;

/// `q`-quantile (0..1) of `v`.
fn quantile(v: &[f32], q: f64) -> f32 {
    let mut v = v.to_vec();
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    *v.select_nth_unstable_by(i, f32::total_cmp).1
}

/// |Δz| (m) over the pixels where both maps have depth, and how many pixels that is.
fn depth_differences(a: &DepthMap, b: &DepthMap) -> Vec<f32> {
    a.data().iter().zip(b.data()).filter(|(x, y)| **x > 0.0 && **y > 0.0).map(|(x, y)| (x - y).abs()).collect()
}

#[test]
fn fused_synthetic_frames_lie_on_the_true_surfaces() {
    let _timing = crate::support::timed();
    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 30, ..SyntheticConfig::default() }, 41).unwrap();
    let frames: Vec<(DepthMap, Intrinsics, Isometry3<f64>)> =
        (0..seq.len()).into_par_iter().map(|i| (seq.noisy_depth(i), seq.intrinsics, seq.poses[i])).collect();
    let config = TsdfConfig::default();
    let start = Instant::now();
    let volume = fuse_frames(&frames, &config).unwrap();
    let fuse_s = start.elapsed().as_secs_f64();
    assert_eq!(volume.frame_count(), 30);

    // Surface points against the exact scene: min over shapes of |signed distance|.
    let points = volume.extract_points(3.0);
    let distance = |p: &Point| {
        let q: Point3<f64> = p.cast();
        seq.scene.shapes().iter().map(|s| s.signed_distance(&q).abs()).fold(f64::INFINITY, f64::min) as f32
    };
    let d: Vec<f32> = points.par_iter().map(distance).collect();
    let mean = d.iter().map(|v| *v as f64).sum::<f64>() / d.len() as f64;
    let p95 = quantile(&d, 0.95);
    println!(
        "synthetic seed 41, 30 noisy frames 640x480, voxel {} m / truncation {} m: fused in {fuse_s:.2} s, \
         {} blocks, {} points; distance to the true surface: mean {:.2} mm, median {:.2} mm, p95 {:.2} mm",
        config.voxel_size_m,
        config.truncation_m,
        volume.block_count(),
        points.len(),
        mean * 1e3,
        quantile(&d, 0.5) * 1e3,
        p95 * 1e3
    );
    assert!(points.len() > 100_000, "{} points", points.len());
    assert!(mean < 0.002, "mean distance {mean} m");
    assert!(p95 < 0.006, "95th percentile {p95} m");

    // The mesh's vertices too, and its PLY on disk.
    let mesh = volume.extract_mesh(3.0);
    let dm: Vec<f32> = mesh.vertices.par_iter().map(distance).collect();
    let mesh_mean = dm.iter().map(|v| *v as f64).sum::<f64>() / dm.len() as f64;
    println!(
        "mesh: {} vertices, {} triangles, mean vertex distance {:.2} mm",
        mesh.vertices.len(),
        mesh.triangles.len(),
        mesh_mean * 1e3
    );
    assert!(mesh.triangles.len() > 150_000 && mesh_mean < 0.002, "{} triangles, {mesh_mean} m", mesh.triangles.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fragment.ply");
    pointreggpt::ply::write_mesh(&path, &mesh.vertices, &mesh.triangles).unwrap();
    assert_eq!(read_ply(&path).unwrap(), mesh.vertices);

    // Ray cast from a trajectory pose between two integrated frames against the exact render.
    let pose = seq.poses[14].lerp_slerp(&seq.poses[15], 0.5);
    let cast = volume.raycast(&seq.intrinsics, &pose).unwrap();
    let truth = seq.true_depth_at(&pose);
    let dz = depth_differences(&cast, &truth);
    let coverage = dz.len() as f64 / truth.valid_count() as f64;
    let median = quantile(&dz, 0.5);
    println!(
        "ray cast between frames 14 and 15: {:.1}% of the true pixels, |Δz| median {:.2} mm, p90 {:.2} mm",
        coverage * 100.0,
        median * 1e3,
        quantile(&dz, 0.9) * 1e3
    );
    assert!(coverage > 0.8, "coverage {coverage}");
    assert!(median < 0.001, "median |Δz| {median} m");
}

#[test]
fn fused_7scenes_frames_predict_a_held_out_frame() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let seqs = threedmatch::open(&root.join("7scenes-redkitchen")).unwrap();
    let held_out = 25;
    let loaded: Vec<_> = seqs[0].frames[..50].par_iter().map(|f| f.load().unwrap_or_else(|e| panic!("{e}"))).collect();
    let frames: Vec<(DepthMap, Intrinsics, Isometry3<f64>)> = loaded
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != held_out)
        .map(|(_, f)| (f.depth.clone(), f.intrinsics, f.t_world_from_camera.expect("7-Scenes frames have poses")))
        .collect();
    let config = TsdfConfig::default();
    let start = Instant::now();
    let volume = fuse_frames(&frames, &config).unwrap();
    let fuse_s = start.elapsed().as_secs_f64();

    let target = &loaded[held_out];
    let cast = volume.raycast(&target.intrinsics, &target.t_world_from_camera.unwrap()).unwrap();
    let dz = depth_differences(&cast, &target.depth);
    let coverage = dz.len() as f64 / target.depth.valid_count() as f64;
    let median = quantile(&dz, 0.5);
    println!(
        "7-Scenes redkitchen frames 0..50 without {held_out}, voxel {} m / truncation {} m: fused in {fuse_s:.2} s \
         ({:.1} ms/frame), {} blocks; ray cast into frame {held_out}: {:.1}% of its pixels, |Δz| median {:.2} mm, p90 {:.2} mm",
        config.voxel_size_m,
        config.truncation_m,
        fuse_s * 1e3 / frames.len() as f64,
        volume.block_count(),
        coverage * 100.0,
        median * 1e3,
        quantile(&dz, 0.9) * 1e3
    );
    assert!(coverage > 0.8, "coverage {coverage}");
    assert!(median < 0.01, "median |Δz| {median} m");
}
