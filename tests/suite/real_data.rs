//! Ingest on the real RGB-D samples in `../shared/realdata` (7-Scenes redkitchen, SUN3D studyroom,
//! a RealSense capture): listing, decoding, invalid-depth handling and pose consistency.
//!
//! The folder is given by `POINTREGGPT_REAL_DATA`; without it the tests fail (see `support::real_data`).

use nalgebra::Isometry3;
use pointreggpt::geometry::{backproject, project_zbuffer, relative_pose, DepthMap, DepthRange, Intrinsics};
use pointreggpt::sources::{depth_png, open_sequences, threedmatch, Frame, Layout};
use rayon::prelude::*;

use crate::support::real_data;

fn load_all(dir: &std::path::Path) -> Vec<Frame> {
    let seqs = threedmatch::open(dir).unwrap();
    assert_eq!(seqs.len(), 1);
    seqs[0].frames.par_iter().map(|f| f.load().unwrap_or_else(|e| panic!("{e}"))).collect()
}

/// Median |Δz| (metres) between `source` re-projected into the target camera and `target`, over
/// the pixels where both have depth; also the number of such pixels.
fn reprojection_median(source: &DepthMap, target: &DepthMap, t_target_from_source: &Isometry3<f64>, k: &Intrinsics) -> (f32, usize) {
    let points = backproject(source, k, DepthRange::ANY);
    let proj = project_zbuffer(&points, t_target_from_source, k, false);
    let mut dz: Vec<f32> = proj
        .depth
        .data()
        .iter()
        .zip(target.data())
        .filter(|(p, t)| **p > 0.0 && **t > 0.0)
        .map(|(p, t)| (p - t).abs())
        .collect();
    assert!(!dz.is_empty(), "no common pixels");
    let mid = dz.len() / 2;
    let n = dz.len();
    (*dz.select_nth_unstable_by(mid, f32::total_cmp).1, n)
}

#[test]
fn redkitchen_400_frames_list_and_load_with_invalid_codes_zeroed() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let dir = root.join("7scenes-redkitchen");
    let seqs = threedmatch::open(&dir).unwrap();
    let frames = &seqs[0].frames;
    assert_eq!(frames.len(), 400);
    assert_eq!(frames[42].key, "7scenes-redkitchen/frame-000042");
    let k = frames[0].intrinsics;
    assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (585.0, 585.0, 320.0, 240.0, 640, 480));

    let loaded = load_all(&dir);
    for f in &loaded {
        assert_eq!((f.depth.width(), f.depth.height()), (640, 480), "{}", f.key);
        assert!(f.t_world_from_camera.is_some(), "{} has no pose", f.key);
        assert!(f.depth.data().iter().all(|z| *z < 65.0), "{} keeps a 65535 value", f.key);
        assert!(f.depth.valid_count() > 100_000, "{} is nearly empty", f.key);
    }

    // SOURCE.txt: 108 raw 65535 pixels in frames 33, 163, 233 and 234, none elsewhere.
    let raw33 = depth_png::read_depth_png(&frames[33].depth_path).unwrap();
    assert!(raw33.data.contains(&65535));
    let per_frame: Vec<(usize, usize)> = frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| (i, depth_png::read_depth_png(&f.depth_path).unwrap().data.iter().filter(|v| **v == 65535).count()))
        .filter(|(_, n)| *n > 0)
        .collect();
    assert_eq!(per_frame.iter().map(|(i, _)| *i).collect::<Vec<_>>(), [33, 163, 233, 234]);
    assert_eq!(per_frame.iter().map(|(_, n)| n).sum::<usize>(), 108);
}

#[test]
fn redkitchen_poses_reproject_consecutive_frames_within_a_centimetre() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let frames = load_all(&root.join("7scenes-redkitchen"));
    let k = frames[0].intrinsics;
    let pose = |i: usize| frames[i].t_world_from_camera.unwrap();
    let results: Vec<(usize, f32, usize, f32)> = (0..400)
        .step_by(20)
        .collect::<Vec<usize>>()
        .par_iter()
        .map(|&j| {
            let (good, n) = reprojection_median(&frames[j].depth, &frames[j + 1].depth, &relative_pose(&pose(j + 1), &pose(j)), &k);
            assert!(n > 50_000, "frame {j}: only {n} common pixels");
            // A deliberately wrong pose: the camera of a frame 40 away instead of j+1's.
            let far = if j + 40 < 400 { j + 40 } else { j - 40 };
            let (wrong, _) = reprojection_median(&frames[j].depth, &frames[j + 1].depth, &relative_pose(&pose(far), &pose(j)), &k);
            (j, good, far, wrong)
        })
        .collect();
    for (j, good, far, wrong) in &results {
        eprintln!("j={j:3}  median |dz| = {:.2} mm  (with frame {far}'s pose: {:.1} mm)", good * 1000.0, wrong * 1000.0);
    }
    for (j, good, far, wrong) in results {
        assert!(good < 0.01, "frame {j} -> {}: median |dz| {good} m", j + 1);
        assert!(wrong > 0.02, "frame {j} with frame {far}'s pose: median |dz| only {wrong} m");
    }
}

#[test]
fn sun3d_seq_folder_and_realsense_intrinsics_name() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let sun3d = threedmatch::open(&root.join("sun3d-studyroom-5frames")).unwrap();
    assert_eq!(sun3d.len(), 1);
    let keys: Vec<&str> = sun3d[0].frames.iter().map(|f| f.key.as_str()).collect();
    assert_eq!(
        keys,
        [
            "sun3d-studyroom-5frames/seq-01/frame-000000",
            "sun3d-studyroom-5frames/seq-01/frame-000001",
            "sun3d-studyroom-5frames/seq-01/frame-000002",
            "sun3d-studyroom-5frames/seq-01/frame-000116",
            "sun3d-studyroom-5frames/seq-01/frame-000422",
        ]
    );
    assert!((sun3d[0].frames[0].intrinsics.fx - 570.342205).abs() < 1e-6);
    let f = sun3d[0].frames[3].load().unwrap();
    assert!(f.t_world_from_camera.is_some() && f.depth.valid_count() > 10_000);

    let rs = threedmatch::open(&root.join("apcbox-realsense")).unwrap();
    let frames = &rs[0].frames;
    assert_eq!(frames.len(), 50);
    assert_eq!(frames[0].key, "apcbox-realsense/frame-000015");
    assert_eq!(frames[49].key, "apcbox-realsense/frame-000113");
    let k = frames[0].intrinsics;
    assert!((k.fx - 615.195).abs() < 0.01 && (k.fy - 615.195).abs() < 0.01, "{k:?}");
    assert!((k.cx - 298.44).abs() < 0.01 && (k.cy - 247.52).abs() < 0.01, "{k:?}");
    assert_eq!((k.width, k.height), (640, 480));
    // frame-000015 is the reference of the trajectory: its pose is the identity.
    let first = frames[0].load().unwrap().t_world_from_camera.unwrap();
    assert!((first.to_homogeneous() - nalgebra::Matrix4::identity()).abs().max() < 1e-6);
}

#[test]
fn auto_layout_on_7scenes_gives_one_sequence() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let seqs = open_sequences(&root.join("7scenes-redkitchen"), Layout::Auto).unwrap();
    assert_eq!(seqs.len(), 1);
    assert_eq!(seqs[0].name, "7scenes-redkitchen");
    assert_eq!(seqs[0].frames.len(), 400);
}

/// The two real folders the README's results rest on besides redkitchen, opened as the commands open them:
/// the TUM fr3 cabinet key frames (TUM layout: 58 frames at 5000 units per metre, TUM's default camera,
/// every frame an exact ground-truth sample) and the ICL-NUIM living room (ScanNet layout: 801 frames in
/// millimetres, the camera of its `intrinsic_depth.txt`, every frame posed). Their poses agree with their
/// depth: a frame re-projected into a neighbour with the ground truth lands on the neighbour's depth, far
/// better than with the pose of a frame further away.
#[test]
fn tum_cabinet_and_icl_nuim_open_with_their_cameras_and_poses_that_fit_the_depth() {
    let _timing = crate::support::timed();
    let Some(root) = real_data() else { return };
    let tum = open_sequences(&root.join("tum-fr3-cabinet-keyframes"), Layout::Auto).unwrap();
    assert_eq!(tum.len(), 1);
    let frames = &tum[0].frames;
    assert_eq!(frames.len(), 58);
    assert_eq!((tum[0].poses.exact, tum[0].poses.interpolated, tum[0].poses.without), (58, 0, 0), "{:?}", tum[0].poses);
    let k = frames[0].intrinsics;
    assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (525.0, 525.0, 319.5, 239.5, 640, 480));
    assert!(frames.iter().all(|f| f.depth_scale == 5000.0 && f.intrinsics == k));
    let loaded: std::collections::BTreeMap<usize, Frame> = frames.par_iter().enumerate().map(|(i, f)| (i, f.load().unwrap_or_else(|e| panic!("{e}")))).collect();
    assert!(loaded.values().all(|f| f.depth.valid_count() > 100_000 && f.depth.data().iter().all(|z| *z < 13.2)));
    check_neighbours("TUM cabinet", &loaded, &(0..57).step_by(4).map(|i| (i, i + 1, if i >= 5 { i - 5 } else { i + 5 })).collect::<Vec<_>>(), 0.05);

    let icl = open_sequences(&root.join("icl-nuim-livingroom"), Layout::Auto).unwrap();
    assert_eq!(icl.len(), 1);
    let frames = &icl[0].frames;
    assert_eq!(frames.len(), 801);
    let k = frames[0].intrinsics;
    assert_eq!((k.fx, k.fy, k.cx, k.cy, k.width, k.height), (481.2, 489.0, 319.5, 239.5, 640, 480));
    assert!(frames.iter().all(|f| f.depth_scale == 1000.0 && f.has_pose()));
    let picks: Vec<(usize, usize, usize)> = (0..780).step_by(60).map(|i| (i, i + 10, i + 60)).collect();
    let mut wanted: Vec<usize> = picks.iter().flat_map(|&(a, b, c)| [a, b, c]).collect();
    wanted.sort_unstable();
    wanted.dedup();
    let loaded: std::collections::BTreeMap<usize, Frame> = wanted.par_iter().map(|&i| (i, frames[i].load().unwrap_or_else(|e| panic!("{e}")))).collect();
    check_neighbours("ICL-NUIM", &loaded, &picks, 0.03);
}

/// For each (source, target, far): the median |dz| of source re-projected into target with the ground
/// truth is below `bound` metres, and with far's pose in place of target's more than twice that.
fn check_neighbours(name: &str, frames: &std::collections::BTreeMap<usize, Frame>, picks: &[(usize, usize, usize)], bound: f32) {
    let pose = |i: usize| frames[&i].t_world_from_camera.unwrap();
    let k = frames[&picks[0].0].intrinsics;
    let results: Vec<(usize, usize, f32, f32, usize)> = picks
        .par_iter()
        .map(|&(s, t, far)| {
            let (good, n) = reprojection_median(&frames[&s].depth, &frames[&t].depth, &relative_pose(&pose(t), &pose(s)), &k);
            let (wrong, _) = reprojection_median(&frames[&s].depth, &frames[&t].depth, &relative_pose(&pose(far), &pose(s)), &k);
            (s, t, good, wrong, n)
        })
        .collect();
    for (s, t, good, wrong, n) in &results {
        eprintln!("{name}: {s} -> {t}: median |dz| {:.1} mm over {n} pixels, with a far frame's pose {:.1} mm", good * 1000.0, wrong * 1000.0);
    }
    for (s, t, good, wrong, n) in results {
        assert!(n > 20_000, "{name} {s} -> {t}: only {n} common pixels");
        assert!(good < bound, "{name} {s} -> {t}: median |dz| {good} m with the ground truth");
        assert!(wrong > 2.0 * good, "{name} {s} -> {t}: median |dz| {wrong} m with a far frame's pose, {good} m with the ground truth");
    }
}
