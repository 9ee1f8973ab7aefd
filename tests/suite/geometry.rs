//! Geometry core against independent references: a brute-force z-buffer, analytic planes, the
//! projection / back-projection round trip over random poses, and identical results on 1 and 2 threads.

use nalgebra::{Isometry3, Vector3};
use pointreggpt::geometry::*;
use pointreggpt::rng::Rng;
use std::collections::HashMap;

fn random_pose(r: &mut Rng, max_angle: f64, max_shift: f64) -> Isometry3<f64> {
    let axis = Vector3::new(r.normal(), r.normal(), r.normal()).normalize();
    let angle = r.uniform_range(-max_angle, max_angle);
    let t = Vector3::new(r.uniform_range(-max_shift, max_shift), r.uniform_range(-max_shift, max_shift), r.uniform_range(-max_shift, max_shift));
    Isometry3::new(t, axis * angle)
}

/// A wavy surface in front of the camera with holes: a depth map with structure and occlusions.
fn structured_depth(k: &Intrinsics, r: &mut Rng) -> DepthMap {
    let mut d = vec![0.0f32; (k.width * k.height) as usize];
    let (a, b) = (r.uniform_range(0.5, 2.0), r.uniform_range(0.5, 2.0));
    for row in 0..k.height {
        for col in 0..k.width {
            let i = (row * k.width + col) as usize;
            if r.uniform() < 0.05 {
                continue;
            }
            let x = col as f64 / k.width as f64;
            let y = row as f64 / k.height as f64;
            let mut z = 2.0 + 0.5 * (a * 6.0 * x).sin() * (b * 4.0 * y).cos();
            if (0.3..0.5).contains(&x) && (0.4..0.7).contains(&y) {
                z = 1.0; // an occluder in front
            }
            d[i] = z as f32;
        }
    }
    DepthMap::new(k.width, k.height, d).unwrap()
}

/// Reference z-buffer: each point's pixel computed by the textbook formula, minimum (z, index) per pixel.
fn brute_force_zbuffer(points: &[Point], t: &Isometry3<f64>, k: &Intrinsics) -> HashMap<usize, (f32, u32)> {
    let mut best: HashMap<usize, (f32, u32)> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        let q = t * nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64);
        if (q.z as f32) <= 0.0 {
            continue;
        }
        let u = (q.x * k.fx / q.z + k.cx).round_ties_even();
        let v = (q.y * k.fy / q.z + k.cy).round_ties_even();
        if u < 0.0 || v < 0.0 || u >= k.width as f64 || v >= k.height as f64 {
            continue;
        }
        let pix = v as usize * k.width as usize + u as usize;
        let cand = (q.z as f32, i as u32);
        let e = best.entry(pix).or_insert(cand);
        if cand.0 < e.0 || (cand.0 == e.0 && cand.1 < e.1) {
            *e = cand;
        }
    }
    best
}

#[test]
fn zbuffer_equals_brute_force_over_random_poses() {
    let _timing = crate::support::timed();
    let k = Intrinsics::new(160.0, 161.0, 79.5, 59.5, 160, 120).unwrap();
    let mut r = Rng::new(77);
    for _ in 0..10 {
        let d = structured_depth(&k, &mut r);
        let pts = backproject(&d, &k, DepthRange::ANY);
        let t = random_pose(&mut r, 0.3, 0.5);
        let proj = project_zbuffer(&pts, &t, &k, true);
        let reference = brute_force_zbuffer(&pts, &t, &k);
        let src = proj.source_index.as_ref().unwrap();
        assert_eq!(proj.known.iter().filter(|b| **b).count(), reference.len());
        for (pix, &(z, idx)) in &reference {
            assert!(proj.known[*pix]);
            assert_eq!(proj.depth.data()[*pix], z);
            assert_eq!(src[*pix], idx);
        }
    }
}

#[test]
fn round_trip_recovers_points_within_pixel_rounding() {
    let _timing = crate::support::timed();
    // Project into a target camera, back-project the z-buffer, move back: every winning point is
    // recovered to within the half-pixel rounding of its ray (z·0.5·√2/f) and its exact depth.
    let k = Intrinsics::new(300.0, 300.0, 127.5, 127.5, 256, 256).unwrap();
    let mut r = Rng::new(5);
    for _ in 0..10 {
        let d = structured_depth(&k, &mut r);
        let pts = backproject(&d, &k, DepthRange::ANY);
        let t = random_pose(&mut r, 0.2, 0.3);
        let proj = project_zbuffer(&pts, &t, &k, true);
        let (back, pixels) = backproject_with_pixels(&proj.depth, &k, DepthRange::ANY);
        let back_in_source = transform_points(&back, &t.inverse());
        let src = proj.source_index.unwrap();
        assert!(back.len() > 10_000);
        for (q, pix) in back_in_source.iter().zip(&pixels) {
            let p = pts[src[*pix as usize] as usize];
            let z_target = (t * nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64)).z;
            let tol = (z_target * 0.5 * 2f64.sqrt() / k.fx + 1e-5) as f32;
            assert!((q - p).norm() <= tol, "recovered point off by {} > {}", (q - p).norm(), tol);
        }
    }
}

#[test]
fn camera_facing_a_plane_sees_the_analytic_depth() {
    let _timing = crate::support::timed();
    // Points on the plane z = 3 (source frame); the target camera is 1 m closer and rotated about z,
    // which keeps the plane fronto-parallel: every hit pixel must read exactly 2 m.
    let k = Intrinsics::new(200.0, 200.0, 63.5, 63.5, 128, 128).unwrap();
    let mut pts = Vec::new();
    for i in 0..600 {
        for j in 0..600 {
            pts.push(Point::new(-1.2 + i as f32 * 0.004, -1.2 + j as f32 * 0.004, 3.0));
        }
    }
    let t = Isometry3::new(Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.0, 0.0, 0.4));
    let proj = project_zbuffer(&pts, &t, &k, false);
    let known = proj.known.iter().filter(|b| **b).count();
    assert_eq!(known, 128 * 128, "a dense plane covers the whole image");
    assert!(proj.depth.data().iter().all(|z| (*z - 2.0).abs() < 1e-6));
}

#[test]
fn results_are_identical_on_one_and_two_threads() {
    let _timing = crate::support::timed();
    let k = Intrinsics::new(585.0, 585.0, 320.0, 240.0, 640, 480).unwrap();
    let mut r = Rng::new(123);
    let d = structured_depth(&k, &mut r);
    let t = random_pose(&mut r, 0.2, 0.3);
    let run = || {
        let pts = backproject(&d, &k, DepthRange::OFFICIAL);
        let proj = project_zbuffer(&pts, &t, &k, true);
        let vox = voxel_downsample(&pts, 0.025);
        let moved = transform_points(&vox, &t);
        let vox2 = voxel_downsample(&moved, 0.025);
        let ov = overlap(&vox, &vox2, &t, 0.0375);
        (pts, proj, vox, ov)
    };
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(run);
    let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(run);
    assert_eq!(one.0, two.0);
    assert_eq!(one.1, two.1);
    assert_eq!(one.2, two.2);
    assert_eq!(one.3, two.3);
    assert!(one.3.source > 0.5, "a cloud overlaps its own moved copy: {:?}", one.3);
}

#[test]
fn official_pipeline_crop_and_voxel_on_a_frame() {
    let _timing = crate::support::timed();
    // Resize-crop a 640x480 map, back-project with the official clip and box: every point lies in the box,
    // and voxel centroids lie in the box too (the box is convex).
    let k = Intrinsics::new(585.0, 585.0, 320.0, 240.0, 640, 480).unwrap();
    let mut r = Rng::new(8);
    let d = structured_depth(&k, &mut r);
    let rc = ResizeCrop::official(640, 480, 256).unwrap();
    let d256 = d.resize_crop(&rc).unwrap();
    let k256 = rc.official_intrinsics(&k).unwrap();
    let pts = AxisBox::OFFICIAL.crop(&backproject(&d256, &k256, DepthRange::OFFICIAL));
    assert!(!pts.is_empty());
    let vox = voxel_downsample(&pts, 0.025);
    assert!(vox.len() < pts.len());
    assert!(vox.iter().all(|p| AxisBox::OFFICIAL.contains(p)));
}
