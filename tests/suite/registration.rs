//! The registration instrument against independent computations: normals and FPFH against Open3D on the
//! same points; the estimator (voxel grid, FPFH, matching, RANSAC, through `evaluate`) on fragments of an
//! analytic surface at known non-identity poses, with controls that must fail there (the identity,
//! index-to-index matching, the truth off by a known vector); registration recall on real single-frame
//! pairs against Open3D's own pipeline (ours registers most of the pairs Open3D registers); the official
//! error against a hand-computed pair; the protocol's arithmetic (IR, FMR, RR, RRE / RTE, the paired
//! difference) on a hand-made benchmark; gt.log / gt.info written and read back; the fragments of a
//! synthetic sequence against its known poses; and the same table on 1 and 2 threads.

use crate::support;

use nalgebra::{Isometry3, Matrix4, Matrix6, Translation3, UnitQuaternion, Vector3};
use pointreggpt::geometry::{voxel_downsample, Point};
use pointreggpt::registration::benchmark::make::single_frame_cloud;
use pointreggpt::registration::benchmark::{find_benchmarks, read_gt_info, read_gt_log, read_gt_overlap, write_gt_info, write_gt_log, write_gt_overlap, GtPair};
use pointreggpt::registration::fpfh::fpfh;
use pointreggpt::registration::metrics::registration_error;
use pointreggpt::registration::normals::estimate_normals;
use pointreggpt::sources::{open_sequences, Layout};
use pointreggpt::stages::ingest::WorkingConfig;
use pointreggpt::stages::voxelize::VoxelizeConfig;
use std::path::Path;
use crate::support::{bin, real_data};

fn run(args: &[&str]) -> String {
    let o = bin().args(args).output().unwrap();
    assert!(o.status.success(), "pointreggpt {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

fn peer(args: &[&str]) -> String {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/open3d_registration.py");
    let o = support::python_command().arg(script).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "the Open3D peer failed (scripts/install-test-deps.sh installs open3d 0.19 and libusb-1.0-0):\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout).unwrap()
}

fn write_f32(path: &Path, v: impl IntoIterator<Item = f32>) {
    std::fs::write(path, v.into_iter().flat_map(f32::to_le_bytes).collect::<Vec<u8>>()).unwrap();
}

fn read_f32(path: &Path) -> Vec<f32> {
    std::fs::read(path).unwrap().chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}

#[test]
fn normals_and_fpfh_equal_open3d_on_a_real_frame() {
    let _timing = crate::support::timed();
    let Some(real) = real_data() else { return };
    let seq = open_sequences(&real.join("7scenes-redkitchen"), Layout::Auto).unwrap().remove(0);
    let points = single_frame_cloud(&seq, 120, &WorkingConfig::default(), &VoxelizeConfig::default()).unwrap().points;
    assert!(points.len() > 2000, "{} points", points.len());
    let normals = estimate_normals(&points, 0.05, 30);
    let dir = tempfile::tempdir().unwrap();
    write_f32(&dir.path().join("points.f32"), points.iter().flat_map(|p| [p.x, p.y, p.z]));
    write_f32(&dir.path().join("normals_ours.f32"), normals.iter().flat_map(|n| [n.x, n.y, n.z]));
    peer(&["features", dir.path().to_str().unwrap(), "0.05", "30", "0.125", "100"]);

    let theirs = read_f32(&dir.path().join("normals_o3d.f32"));
    let mut worst = 0.0f64;
    let mut over = 0;
    for (n, t) in normals.iter().zip(theirs.chunks(3)) {
        let dot = (n.x * t[0] + n.y * t[1] + n.z * t[2]).clamp(-1.0, 1.0) as f64;
        let angle = dot.acos().to_degrees();
        worst = worst.max(angle);
        over += (angle > 1.0) as usize;
    }
    println!("normals: {} points, worst angle {worst:.4} deg, {over} above 1 deg", points.len());
    assert_eq!(over, 0, "normals more than 1 degree from Open3D's (worst {worst} deg)");

    let ours = fpfh(&points, &normals, 0.125, 100);
    let theirs = read_f32(&dir.path().join("fpfh_o3d.f32"));
    assert_eq!(ours.len(), theirs.len());
    let worst = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs() / b.abs().max(1.0)).fold(0.0f32, f32::max);
    println!("fpfh: worst relative difference {worst:e}");
    assert!(worst < 1e-4, "FPFH differs from Open3D's compute_fpfh_feature by {worst}");
}

#[test]
fn official_error_of_a_hand_computed_pair() {
    let _timing = crate::support::timed();
    // Δ = inv(T_gt)·T_est: 0.1 rad about z and (0.1, 0, 0), so x = [0.1, 0, 0, 0, 0, sin 0.05].
    let mut info = Matrix6::zeros();
    for (k, v) in [100.0, 100.0, 100.0, 30.0, 35.0, 40.0].into_iter().enumerate() {
        info[(k, k)] = v;
    }
    info[(0, 5)] = 7.0;
    info[(5, 0)] = 7.0;
    let s = 0.05f64.sin();
    let want = (100.0 * 0.01 + 40.0 * s * s + 2.0 * 7.0 * 0.1 * s) / 100.0;
    let delta = Isometry3::new(Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.1));
    let gt = Isometry3::new(Vector3::new(0.5, -1.0, 2.0), Vector3::new(0.3, 0.2, -0.4));
    assert!((registration_error(&gt, &(gt * delta), &info) - want).abs() < 1e-12);
    // The same rotation stored with w < 0 gives the same error (the protocol's quaternion has w >= 0).
    let q = delta.rotation.into_inner();
    let neg = Isometry3::from_parts(Translation3::from(delta.translation.vector), UnitQuaternion::new_unchecked(-q));
    assert!((registration_error(&gt, &(gt * neg), &info) - want).abs() < 1e-12);
    // Identity estimate against identity truth: zero.
    assert_eq!(registration_error(&gt, &gt, &info).abs() < 1e-20, true);
}

fn pose(a: f64) -> Isometry3<f64> {
    Isometry3::new(Vector3::new(a, -0.5 * a, 0.25), Vector3::new(0.1 * a, -0.2, 0.3 * a))
}

#[test]
fn gt_files_round_trip_and_all_three_layouts_read() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let pairs = vec![GtPair { i: 0, j: 2, n: 3, t_i_from_j: pose(0.7) }, GtPair { i: 1, j: 2, n: 3, t_i_from_j: pose(-1.3) }];
    let infos: Vec<(GtPair, Matrix6<f64>)> = pairs.iter().enumerate().map(|(k, p)| (p.clone(), Matrix6::from_fn(|r, c| (r * 6 + c) as f64 * 0.37 + k as f64 / 3.0))).collect();
    let cloud = [Point::new(0.0, 0.0, 1.0)];
    let write_scene = |eval_dir: &Path, clouds: &Path| {
        write_gt_log(&eval_dir.join("gt.log"), &pairs).unwrap();
        write_gt_info(&eval_dir.join("gt.info"), &infos).unwrap();
        write_gt_overlap(&eval_dir.join("gt_overlap.log"), &[((0, 2), 0.25), ((1, 2), 0.5)]).unwrap();
        for k in 0..3 {
            pointreggpt::ply::write_points(&clouds.join(format!("cloud_bin_{k}.ply")), &cloud).unwrap();
        }
    };
    let ours = dir.path().join("ours");
    write_scene(&ours.join("metadata/benchmarks/3DLoMatch/kitchen"), &ours.join("kitchen"));
    let official = dir.path().join("official");
    write_scene(&official.join("kitchen-evaluation"), &official.join("kitchen"));
    let flat = dir.path().join("flat");
    write_scene(&flat, &flat);

    let log = ours.join("metadata/benchmarks/3DLoMatch/kitchen/gt.log");
    let back = read_gt_log(&log).unwrap();
    for (a, b) in back.iter().zip(&pairs) {
        assert_eq!((a.i, a.j, a.n), (b.i, b.j, b.n));
        assert!((a.t_i_from_j.to_homogeneous() - b.t_i_from_j.to_homogeneous()).abs().max() < 1e-15);
    }
    let info_back = read_gt_info(&log.with_file_name("gt.info")).unwrap();
    assert_eq!(info_back.iter().map(|(ij, m)| (*ij, *m)).collect::<Vec<_>>(), infos.iter().map(|(p, m)| ((p.i, p.j), *m)).collect::<Vec<_>>());
    assert_eq!(read_gt_overlap(&log.with_file_name("gt_overlap.log")).unwrap(), vec![((0, 2), 0.25), ((1, 2), 0.5)]);

    for (root, name) in [(&ours, "3DLoMatch"), (&official, "3DMatch"), (&flat, "3DMatch")] {
        let benches = find_benchmarks(root).unwrap();
        assert_eq!(benches.len(), 1, "{}", root.display());
        assert_eq!(benches[0].name, name);
        let p = &benches[0].pairs[1];
        assert_eq!((p.i, p.j), (1, 2));
        assert_eq!(p.info, infos[1].1);
        assert!(p.source_path.ends_with("cloud_bin_2.ply") && p.target_path.ends_with("cloud_bin_1.ply"));
    }

    // Bad input names the file and the line.
    std::fs::write(&log, "0 2 3\n1 0 0 0\n0 1 0 0\n0 0 x 0\n0 0 0 1\n").unwrap();
    let e = read_gt_log(&log).unwrap_err().to_string();
    assert!(e.contains("gt.log") && e.contains("line 4"), "{e}");
    std::fs::remove_file(ours.join("kitchen/cloud_bin_0.ply")).unwrap();
    write_gt_log(&log, &pairs).unwrap();
    let e = find_benchmarks(&ours).unwrap_err().to_string();
    assert!(e.contains("cloud_bin_0.ply") && e.contains("does not exist"), "{e}");
}

/// How many of `queries` have a point of `set` closer than `r`: an exhaustive check over the points whose
/// x lies within r (a sweep over `set` sorted by x).
fn count_within(queries: &[Point], set: &[Point], r: f32) -> usize {
    let mut sorted = set.to_vec();
    sorted.sort_by(|a, b| a.x.partial_cmp(&b.x).unwrap());
    queries
        .iter()
        .filter(|q| {
            let start = sorted.partition_point(|p| p.x < q.x - r);
            sorted[start..].iter().take_while(|p| p.x <= q.x + r).any(|p| (*q - p).norm_squared() < r * r)
        })
        .count()
}

fn read_pose(path: &Path) -> Matrix4<f64> {
    let v: Vec<f64> = std::fs::read_to_string(path).unwrap().split_whitespace().map(|x| x.parse().unwrap()).collect();
    Matrix4::from_row_slice(&v[..16])
}

#[test]
fn fragments_of_a_synthetic_sequence_and_a_deterministic_table() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let seqs = dir.path().join("seqs");
    let bench = dir.path().join("bench");
    run(&["synth", "--out", seqs.to_str().unwrap(), "--frames", "100", "--seed", "4"]);
    let seq = seqs.join("synthetic-4");
    let out = run(&["fragments", seq.to_str().unwrap(), "--frames-per-fragment", "25", "--out", bench.to_str().unwrap(), "--quiet"]);
    println!("{out}");
    let mut pairs = 0;
    for name in ["3DMatch", "3DLoMatch"] {
        let d = bench.join("metadata/benchmarks").join(name).join("synthetic-4");
        let overlaps = read_gt_overlap(&d.join("gt_overlap.log")).unwrap();
        let infos = read_gt_info(&d.join("gt.info")).unwrap();
        for (k, p) in read_gt_log(&d.join("gt.log")).unwrap().into_iter().enumerate() {
            pairs += 1;
            assert_eq!(p.n, 4);
            // The truth from the pose files: T_i_from_j = inv(P_25i)·P_25j.
            let pi = read_pose(&seq.join(format!("frame-{:06}.pose.txt", 25 * p.i)));
            let pj = read_pose(&seq.join(format!("frame-{:06}.pose.txt", 25 * p.j)));
            let want = pi.try_inverse().unwrap() * pj;
            assert!((p.t_i_from_j.to_homogeneous() - want).abs().max() < 1e-9, "pair {} {}", p.i, p.j);
            // Overlap and Info₀₀ by brute force on the written clouds.
            let cloud = |k: usize| voxel_downsample(&pointreggpt::ply::read_ply(&bench.join(format!("synthetic-4/cloud_bin_{k}.ply"))).unwrap(), 0.025);
            let (ti, sj) = (cloud(p.i), cloud(p.j));
            let t = p.t_i_from_j.cast::<f32>();
            let moved: Vec<Point> = sj.iter().map(|q| t * q).collect();
            let n_src = count_within(&moved, &ti, 0.0375);
            let n_tgt = count_within(&ti, &moved, 0.0375);
            let ov = (n_src as f64 / sj.len() as f64).max(n_tgt as f64 / ti.len() as f64);
            assert_eq!(overlaps[k].0, (p.i, p.j));
            assert!((overlaps[k].1 - ov).abs() < 2e-3, "overlap {} vs brute force {ov}", overlaps[k].1);
            assert!((infos[k].1[(0, 0)] - n_src as f64).abs() <= 2.0, "Info00 {} vs {n_src} overlapping points", infos[k].1[(0, 0)]);
            let expect_lo = ov <= 0.3;
            assert_eq!(name == "3DLoMatch", expect_lo, "pair {} {} with overlap {ov} in {name}", p.i, p.j);
        }
    }
    assert!(pairs >= 3, "{pairs} pairs");
    let b = bench.to_str().unwrap();
    let eval = |threads: &str| run(&["--threads", threads, "eval", "registration", b, "--samples", "1000,250", "--ransac-iterations", "4000", "--compare", "fpfh:0.075", "--quiet"]);
    let (one, two) = (eval("1"), eval("2"));
    println!("{one}");
    assert_eq!(one, two, "the table differs between 1 and 2 threads");
    assert!(one.contains("paired IR difference fpfh:0.125 - fpfh:0.075"), "{one}");
}

/// Voxel edge of the hand-made benchmark's clouds and of the evaluation, metres.
const VOXEL: f64 = 0.025;

/// The voxel indices of a bumpy surface about 2 m in front of the camera: one point at the centre of
/// each voxel of an `n`×`n` patch of columns, each column's voxel row drawn at random in a 3-row band
/// above a gentle slope, so no two neighbourhoods look alike.
fn bumpy_surface(n: i64, seed: u64) -> Vec<[i64; 3]> {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 33) % 3
    };
    let mut out = Vec::new();
    for ix in -n / 2..n - n / 2 {
        for iy in -n / 2..n - n / 2 {
            out.push([ix, iy, 80 + ix / 6 - iy / 9 + next() as i64]);
        }
    }
    out
}

/// Voxel indices to points at the voxel centres (which voxel-downsampling keeps exactly).
fn voxel_centres(idx: &[[i64; 3]]) -> Vec<Point> {
    let c = |k: i64| ((k as f64 + 0.5) * VOXEL) as f32;
    idx.iter().map(|v| Point::new(c(v[0]), c(v[1]), c(v[2]))).collect()
}

/// What the protocol must report for one pair, computed here from the construction.
struct Expected {
    ir: f64,
    ir_all_to_first: f64,
    registered: bool,
    counts: bool,
    rre: f64,
    rte: f64,
}

/// The 4×4 rows of a pose as gt.log writes them.
fn rows4(t: &Isometry3<f64>) -> String {
    let m = t.to_homogeneous();
    (0..4).map(|r| format!("{:.17e} {:.17e} {:.17e} {:.17e}\n", m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)])).collect()
}

fn csv_rows(text: &str, header: &str) -> Vec<Vec<String>> {
    let mut lines = text.lines().skip_while(|l| *l != header).skip(1);
    let mut out = Vec::new();
    for l in lines.by_ref() {
        if l.is_empty() || l.starts_with("benchmark,") {
            break;
        }
        out.push(l.split(',').map(str::to_string).collect());
    }
    out
}

/// `eval registration` on a benchmark written by hand: every fragment of a scene is the same bumpy
/// surface (the true pose between fragments is the identity), so FPFH matches every point to itself and
/// RANSAC finds the identity. The gt.log does not state the identity: it states a designed error D (a
/// shift, a tilt, a spin about a corner), so the inlier ratio, the registration error against gt.info,
/// RRE and RTE of every pair follow from D and are computed here; then FMR, the mean IR, RR (consecutive 3DMatch fragments left out, not in
/// 3DLoMatch), RRE / RTE over the registered pairs that count, and the paired IR difference against a
/// descriptor that matches everything to the first target point (FPFH with a radius below the voxel:
/// every histogram empty). The true poses here are the identity, so this checks the protocol's
/// arithmetic, not the estimator:
/// `ransac_fpfh_registers_fragments_at_known_non_identity_poses_and_rejects_the_controls` does that.
#[test]
fn eval_registration_on_a_hand_made_benchmark_equals_an_independent_computation() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let scenes = [("a", bumpy_surface(48, 1)), ("b", bumpy_surface(28, 2))];
    // (A quarter turn of the odd fragments about the camera axis, exact on the voxel grid, was tried:
    // FPFH then matched 2-3 % of the points of the larger surface elsewhere, float noise in the
    // normals, which this test is not about.)
    let fragment = |surface: &[[i64; 3]], _k: usize| surface.to_vec();
    for (scene, surface) in &scenes {
        std::fs::create_dir_all(root.join(scene)).unwrap();
        for k in 0..5 {
            pointreggpt::ply::write_points(&root.join(format!("{scene}/cloud_bin_{k}.ply")), &voxel_centres(&fragment(surface, k))).unwrap();
        }
    }
    // The designed errors, in the source fragment's frame.
    let about = |c: Vector3<f64>, axis: Vector3<f64>, angle: f64| {
        let r = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
        Isometry3::from_parts(Translation3::from(c - r * c), r)
    };
    let design = |name: &str, source: &[Point]| -> Isometry3<f64> {
        let (x0, y0) = source.iter().fold((f64::MAX, f64::MAX), |(x, y), p| (x.min(p.x as f64), y.min(p.y as f64)));
        match name {
            "shift" => Isometry3::translation(0.05, -0.03, 0.02),
            "far" => Isometry3::translation(0.31, 0.013, -0.007),
            "tilt" => about(Vector3::new(0.0, 0.0, 2.0), Vector3::y(), 0.2),
            "tilt2" => about(Vector3::new(0.1, 0.0, 2.1), Vector3::new(1.0, 1.0, 0.0), 0.12),
            "corner" => about(Vector3::new(x0, y0, 0.0), Vector3::z(), 0.5),
            _ => unreachable!(),
        }
    };
    // (benchmark, scene, i, j, design)
    let pairs: [(&str, usize, usize, usize, &str); 13] = [
        ("3DMatch", 0, 0, 1, "shift"),
        ("3DMatch", 0, 0, 2, "tilt"),
        ("3DMatch", 0, 1, 3, "far"),
        ("3DMatch", 0, 2, 4, "corner"),
        ("3DMatch", 0, 3, 4, "far"),
        ("3DMatch", 1, 0, 2, "shift"),
        ("3DMatch", 1, 1, 2, "tilt"),
        ("3DMatch", 1, 0, 3, "corner"),
        ("3DMatch", 1, 1, 4, "tilt2"),
        ("3DMatch", 1, 2, 3, "tilt2"),
        ("3DLoMatch", 0, 2, 3, "tilt2"),
        ("3DLoMatch", 0, 0, 4, "far"),
        ("3DLoMatch", 1, 3, 4, "shift"),
    ];
    let mut expected: Vec<(&str, Expected)> = Vec::new();
    let mut logs: std::collections::BTreeMap<(String, String), (String, String)> = Default::default();
    for (bench, s, i, j, name) in pairs {
        let (scene, surface) = &scenes[s];
        let source = voxel_centres(&fragment(surface, j));
        let target_idx = fragment(surface, i);
        // The truth maps fragment j into fragment i; gt.log states it composed with the designed error.
        let truth = Isometry3::<f64>::identity();
        let stated = truth * design(name, &source);
        // Information matrix of the source points, Σ Gᵀ·G with G = [I | −2·[p]×] (Choi et al.).
        let mut info = Matrix6::zeros();
        for p in &source {
            let p = p.cast::<f64>();
            let mut g = nalgebra::Matrix3x6::zeros();
            g.fixed_view_mut::<3, 3>(0, 0).copy_from(&nalgebra::Matrix3::identity());
            g.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-2.0 * p.coords.cross_matrix()));
            info += g.transpose() * g;
        }
        let n = source.len() as f64;
        // IR: the share of sources within 10 cm of their match (their true image) under the stated pose.
        let dist = |p: &Point, q: Vector3<f64>| (stated * p.cast::<f64>() - nalgebra::Point3::from(q)).norm();
        let moved: Vec<f64> = source.iter().map(|p| dist(p, (truth * p.cast::<f64>()).coords)).collect();
        assert!(moved.iter().all(|d| (d - 0.1).abs() > 1e-5), "{bench} {scene} {i} {j}: a point sits on the 10 cm border");
        let ir = moved.iter().filter(|d| **d < 0.1).count() as f64 / n;
        // Every source matched to the first target point (the lowest voxel, lexicographically).
        let first = *target_idx.iter().min().unwrap();
        let first = voxel_centres(&[first])[0].cast::<f64>().coords;
        let to_first: Vec<f64> = source.iter().map(|p| dist(p, first)).collect();
        assert!(to_first.iter().all(|d| (d - 0.1).abs() > 1e-5), "{bench} {scene} {i} {j}: a point sits on the 10 cm border of the first target point: {:?}", to_first.iter().find(|d| (*d - 0.1).abs() <= 1e-5));
        let ir_all_to_first = to_first.iter().filter(|d| **d < 0.1).count() as f64 / n;
        // The official error of the true pose (what RANSAC finds) against the stated one.
        let delta = stated.inverse() * truth;
        let q = delta.rotation.quaternion();
        let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
        let x = nalgebra::Vector6::new(delta.translation.x, delta.translation.y, delta.translation.z, sign * q.i, sign * q.j, sign * q.k);
        let error = (x.transpose() * info * x)[(0, 0)] / info[(0, 0)];
        assert!((error - 0.04).abs() > 2e-3, "{bench} {scene} {i} {j}: error {error} too near the 0.2² threshold");
        let rre = (stated.rotation.inverse() * truth.rotation).angle().to_degrees();
        let rte = (stated.translation.vector - truth.translation.vector).norm();
        let counts = !(bench == "3DMatch" && j == i + 1);
        expected.push((bench, Expected { ir, ir_all_to_first, registered: error <= 0.04, counts, rre, rte }));
        let (log, inf) = logs.entry((bench.to_string(), scene.to_string())).or_default();
        log.push_str(&format!("{i} {j} 5\n{}", rows4(&stated)));
        inf.push_str(&format!("{i} {j} 5\n"));
        for r in 0..6 {
            inf.push_str(&(0..6).map(|c| format!("{:.17e}", info[(r, c)])).collect::<Vec<_>>().join(" "));
            inf.push('\n');
        }
    }
    for ((bench, scene), (log, inf)) in &logs {
        let d = root.join("metadata/benchmarks").join(bench).join(scene);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("gt.log"), log).unwrap();
        std::fs::write(d.join("gt.info"), inf).unwrap();
    }
    // The construction covers every rule: pairs on both sides of the FMR bar and of RR, registered and
    // unregistered consecutive 3DMatch pairs, a consecutive 3DLoMatch pair that counts, two cloud sizes.
    let all = |b: &'static str| expected.iter().filter(move |(x, _)| *x == b).map(move |(_, e)| e);
    assert!(all("3DMatch").any(|e| e.ir > 0.0 && e.ir <= 0.05) && all("3DMatch").any(|e| e.ir > 0.05 && e.ir < 1.0));
    assert!(all("3DMatch").any(|e| !e.counts && e.registered) && all("3DMatch").any(|e| !e.counts && !e.registered));
    assert!(all("3DMatch").any(|e| e.counts && e.registered) && all("3DMatch").any(|e| e.counts && !e.registered));
    assert!(all("3DLoMatch").any(|e| e.registered) && all("3DLoMatch").any(|e| !e.registered));

    let b = root.to_str().unwrap();
    let out = run(&["eval", "registration", b, "--samples", "5000", "--compare", "fpfh:0.01", "--ransac-iterations", "2000", "--csv", "--quiet"]);
    println!("{out}");
    let table = csv_rows(&out, "benchmark,descriptor,samples,pairs,fmr_pct,ir_pct,rr_pct,rr_pairs,rre_deg,rte_m");
    let paired = csv_rows(&out, "benchmark,samples,pairs,ir_diff_pp,ci95_lo,ci95_hi");
    let num = |v: &str| v.parse::<f64>().unwrap();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    for bench in ["3DMatch", "3DLoMatch"] {
        let es: Vec<&Expected> = all(bench).collect();
        let row = table.iter().find(|r| r[0] == bench && r[1] == "fpfh:0.125").unwrap_or_else(|| panic!("no {bench} row:\n{out}"));
        let counted: Vec<&&Expected> = es.iter().filter(|e| e.counts).collect();
        let registered: Vec<&&&Expected> = counted.iter().filter(|e| e.registered).collect();
        let want = [
            es.len() as f64,
            100.0 * es.iter().filter(|e| e.ir > 0.05).count() as f64 / es.len() as f64,
            100.0 * mean(&es.iter().map(|e| e.ir).collect::<Vec<_>>()),
            100.0 * registered.len() as f64 / counted.len() as f64,
            counted.len() as f64,
            mean(&registered.iter().map(|e| e.rre).collect::<Vec<_>>()),
            mean(&registered.iter().map(|e| e.rte).collect::<Vec<_>>()),
        ];
        let got = [num(&row[3]), num(&row[4]), num(&row[5]), num(&row[6]), num(&row[7]), num(&row[8]), num(&row[9])];
        let names = ["pairs", "FMR %", "IR %", "RR %", "RR pairs", "RRE deg", "RTE m"];
        let tolerance = [0.0, 1e-3, 1e-3, 1e-3, 0.0, 2e-3, 2e-4];
        for k in 0..7 {
            assert!((got[k] - want[k]).abs() <= tolerance[k], "{bench} {}: eval says {}, the construction {}\n{out}", names[k], got[k], want[k]);
        }
        // The paired difference fpfh − (every match to the first point): per pair IR − IR', its mean and
        // the 95 % interval with Student's t over the pairs.
        let d: Vec<f64> = es.iter().map(|e| 100.0 * (e.ir - e.ir_all_to_first)).collect();
        let m = mean(&d);
        let sd = (d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt();
        let t = [12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228][d.len() - 2];
        let half = t * sd / (d.len() as f64).sqrt();
        let row = paired.iter().find(|r| r[0] == bench).unwrap_or_else(|| panic!("no paired {bench} row:\n{out}"));
        let got = [num(&row[3]), num(&row[4]), num(&row[5])];
        assert!(m.abs() > 1.0 && half > 0.1, "the constructed difference is not informative: {m} ± {half}");
        for (g, w) in got.iter().zip([m, m - half, m + half]) {
            assert!((g - w).abs() < 1e-3, "{bench}: paired IR difference {got:?}, constructed {:?}\n{out}", [m, m - half, m + half]);
        }
    }
    // A descriptor compared with itself: difference 0 on every pair, an interval of width 0.
    let same = run(&["eval", "registration", b, "--samples", "5000", "--compare", "fpfh", "--csv", "--quiet"]);
    let paired = csv_rows(&same, "benchmark,samples,pairs,ir_diff_pp,ci95_lo,ci95_hi");
    assert_eq!(paired.len(), 2, "{same}");
    for row in &paired {
        assert!(row[3..6].iter().all(|v| num(v) == 0.0), "fpfh against itself: {row:?}");
    }
}

/// A small linear congruential generator for the test's own draws (independent of `pointreggpt::rng`).
struct Lcg(u64);

impl Lcg {
    /// Uniform in [0, 1).
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The official error written out here from its definition: `x = [t, q_xyz]` of `Δ = inv(gt)·est` with
/// the quaternion's w ≥ 0, `xᵀ·Info·x / Info₀₀`.
fn official_error(gt: &Isometry3<f64>, est: &Isometry3<f64>, info: &Matrix6<f64>) -> f64 {
    let d = gt.inverse() * est;
    let q = d.rotation.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    let x = nalgebra::Vector6::new(d.translation.x, d.translation.y, d.translation.z, s * q.i, s * q.j, s * q.k);
    (x.transpose() * info * x)[(0, 0)] / info[(0, 0)]
}

/// `Σ Gᵀ·G` with `G = [I | −2·[p]×]` over `points` (Choi et al.).
fn information_of(points: &[Point]) -> Matrix6<f64> {
    let mut info = Matrix6::zeros();
    for p in points {
        let p = p.cast::<f64>();
        let mut g = nalgebra::Matrix3x6::zeros();
        g.fixed_view_mut::<3, 3>(0, 0).copy_from(&nalgebra::Matrix3::identity());
        g.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-2.0 * p.coords.cross_matrix()));
        info += g.transpose() * g;
    }
    info
}

/// The analytic scene of the posed benchmark: a height field `z = 2 + h(x, y)` in the world frame, a
/// gentle slope plus 40 Gaussian bumps and dents (4-12 cm wide, 3-10 cm high) at drawn places, so
/// neighbourhoods 12.5 cm across differ.
fn bumpy_height(seed: u64) -> impl Fn(f64, f64) -> f64 {
    let mut rng = Lcg(seed);
    let bumps: Vec<[f64; 4]> = (0..40)
        .map(|_| {
            let (cx, cy) = (rng.next() * 1.8 - 0.9, rng.next() * 1.4 - 0.7);
            let w = 0.04 + 0.08 * rng.next();
            let a = (0.03 + 0.07 * rng.next()) * if rng.next() < 0.5 { -1.0 } else { 1.0 };
            [cx, cy, w, a]
        })
        .collect();
    move |x, y| {
        let bump = |[cx, cy, w, a]: &[f64; 4]| a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (w * w)).exp();
        0.08 * x - 0.05 * y + bumps.iter().map(bump).sum::<f64>()
    }
}

/// A registration benchmark at known non-identity poses that the estimator must solve, and controls
/// that must fail on it. Four fragments of the analytic height field (`bumpy_height`), each the part of
/// the field under its own window, sampled on a 1 cm grid, expressed in its own camera frame `P_k` and
/// written with its points shuffled (the six pairs: turns of 47° to 145°, shifts of 0.33 to 0.71 m,
/// overlaps of 38 to 80 %); gt.log states `inv(P_i)·P_j` and gt.info the information matrix of the
/// source points whose world position lies under the target's window (both from the construction).
///
/// The real pipeline (`evaluate`: voxel grid, normals, FPFH, matching, RANSAC, the official error, the
/// same code as `eval registration`) must register all six pairs with an error below a tenth of the
/// bar and RRE below 5° (measured: errors at most 1.2e-4 against the bar 0.04, RRE at most 2.2°).
/// Controls built here, scored with the protocol's error and with the one written out in the test,
/// must be rejected on every pair: the identity (a RANSAC that returns it), RANSAC and Kabsch on
/// index-to-index correspondences (a matcher that pairs by index, in the written and in the
/// voxel-downsampled order), and the truth with its translation off by a known vector δ (whose error
/// is exactly |δ|², just over the bar; half of δ passes).
#[test]
fn ransac_fpfh_registers_fragments_at_known_non_identity_poses_and_rejects_the_controls() {
    let _timing = crate::support::timed();
    use pointreggpt::registration::metrics::RR_ERROR;
    use pointreggpt::registration::ransac::{kabsch, ransac, RansacConfig};
    use pointreggpt::registration::{evaluate, Descriptor, EvalConfig};
    let t0 = std::time::Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let h = bumpy_height(7);
    // Per fragment: the world window (x0, x1, y0, y1) and the camera pose P_k (camera to world).
    let fragments: [([f64; 4], Isometry3<f64>); 4] = [
        ([-0.85, 0.25, -0.65, 0.35], Isometry3::new(Vector3::new(0.1, -0.05, 0.0), Vector3::new(0.05, -0.1, 0.3))),
        ([-0.45, 0.55, -0.40, 0.60], Isometry3::new(Vector3::new(-0.2, 0.1, 0.15), Vector3::new(-0.15, 0.1, -0.5))),
        ([-0.15, 0.85, -0.60, 0.40], Isometry3::new(Vector3::new(0.3, 0.2, -0.1), Vector3::new(0.1, 0.2, 1.2))),
        ([-0.60, 0.40, -0.25, 0.65], Isometry3::new(Vector3::new(-0.1, -0.3, 0.2), Vector3::new(-0.2, -0.1, -1.3))),
    ];
    let inside = |w: &[f64; 4], x: f64, y: f64| x >= w[0] && x < w[1] && y >= w[2] && y < w[3];
    // World points of each fragment (1 cm grid), and the same in the fragment's frame, shuffled.
    let mut world: Vec<Vec<Point>> = Vec::new();
    let mut local: Vec<Vec<Point>> = Vec::new();
    let mut rng = Lcg(99);
    for (w, pose) in &fragments {
        let mut pts = Vec::new();
        for ix in (w[0] * 100.0).round() as i64..(w[1] * 100.0).round() as i64 {
            for iy in (w[2] * 100.0).round() as i64..(w[3] * 100.0).round() as i64 {
                let (x, y) = (ix as f64 / 100.0 + 0.005, iy as f64 / 100.0 + 0.005);
                pts.push(Point::new(x as f32, y as f32, (2.0 + h(x, y)) as f32));
            }
        }
        for a in (1..pts.len()).rev() {
            pts.swap(a, (rng.next() * (a + 1) as f64) as usize);
        }
        let inv = pose.inverse();
        local.push(pts.iter().map(|p| (inv * p.cast::<f64>()).cast::<f32>()).collect());
        world.push(pts);
    }
    std::fs::create_dir_all(root.join("posed")).unwrap();
    for (k, pts) in local.iter().enumerate() {
        pointreggpt::ply::write_points(&root.join(format!("posed/cloud_bin_{k}.ply")), pts).unwrap();
    }
    let mut truths = std::collections::BTreeMap::new();
    let (mut log, mut inf) = (String::new(), String::new());
    for i in 0..4 {
        for j in i + 1..4 {
            let truth = fragments[i].1.inverse() * fragments[j].1;
            let under_i = |p: &&Point| inside(&fragments[i].0, p.x as f64, p.y as f64);
            let overlap: Vec<Point> = world[j].iter().zip(&local[j]).filter(|(p, _)| under_i(p)).map(|(_, q)| *q).collect();
            let share = overlap.len() as f64 / local[j].len() as f64;
            assert!((0.25..0.9).contains(&share), "pair {i} {j}: overlap {share}");
            let (turn, shift) = (truth.rotation.angle().to_degrees(), truth.translation.vector.norm());
            println!("pair {i} {j}: truth turns {turn:.1} deg and shifts {shift:.3} m, overlap {share:.2}");
            let info = information_of(&overlap);
            log.push_str(&format!("{i} {j} 4\n{}", rows4(&truth)));
            inf.push_str(&format!("{i} {j} 4\n"));
            for r in 0..6 {
                inf.push_str(&(0..6).map(|c| format!("{:.17e}", info[(r, c)])).collect::<Vec<_>>().join(" "));
                inf.push('\n');
            }
            truths.insert((i, j), (truth, info));
        }
    }
    let d = root.join("metadata/benchmarks/posed/posed");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("gt.log"), log).unwrap();
    std::fs::write(d.join("gt.info"), inf).unwrap();

    // The controls, scored with the protocol's error and with the one written out here.
    let rejected = |what: &str, i: usize, j: usize, est: &Isometry3<f64>| {
        let (truth, info) = &truths[&(i, j)];
        let (ours, theirs) = (official_error(truth, est, info), registration_error(truth, est, info));
        assert!((ours - theirs).abs() <= 1e-9 * ours.max(1.0), "pair {i} {j}, {what}: error {theirs} vs {ours} written out");
        assert!(
            ours > RR_ERROR,
            "pair {i} {j}: the control `{what}` has error {ours} <= {RR_ERROR}, so the benchmark cannot tell it from a registration"
        );
        ours
    };
    let delta = Vector3::new(0.15, -0.12, 0.1);
    let vectors = |pts: &[Point]| pts.iter().map(|p| p.coords.cast::<f64>()).collect::<Vec<_>>();
    let index_ransac = |s: &[Point], t: &[Point]| {
        let corr: Vec<(u32, u32)> = (0..s.len().min(t.len()) as u32).map(|k| (k, k)).collect();
        ransac(s, t, &corr, &RansacConfig::default()).map(|r| r.t_target_from_source)
    };
    let mut worst_control = f64::MAX;
    for (&(i, j), (truth, info)) in &truths {
        let mut errors = vec![rejected("identity", i, j, &Isometry3::identity())];
        let (ds, dt) = (voxel_downsample(&local[j], VOXEL as f32), voxel_downsample(&local[i], VOXEL as f32));
        for (name, s, t) in [("written order", &local[j], &local[i]), ("voxel order", &ds, &dt)] {
            let n = s.len().min(t.len());
            let k = kabsch(&vectors(&s[..n]), &vectors(&t[..n])).unwrap();
            errors.push(rejected(&format!("Kabsch on same-index points, {name}"), i, j, &k));
            if let Some(r) = index_ransac(s, t) {
                errors.push(rejected(&format!("RANSAC on same-index matches, {name}"), i, j, &r));
            }
        }
        // The truth off by δ in the target frame: Δ = inv(T)·(δ + T) is the pure shift Rᵀ·δ, so the error
        // is |δ|² (Info's top-left block is n·I); half of δ is within the bar.
        let off = Translation3::from(delta) * truth;
        let e = rejected("the truth shifted by δ", i, j, &off);
        assert!((e - delta.norm_squared()).abs() < 1e-9, "pair {i} {j}: shift error {e}, |δ|² = {}", delta.norm_squared());
        let half = Translation3::from(delta / 2.0) * truth;
        assert!(official_error(truth, &half, info) <= RR_ERROR, "pair {i} {j}: half of δ is rejected too");
        worst_control = worst_control.min(errors.iter().copied().fold(f64::MAX, f64::min));
        println!("pair {i} {j}: control errors {errors:.3?}, shift by δ {e:.4}");
    }
    let t_build = t0.elapsed().as_secs_f64();

    // The real estimator through the protocol.
    let t1 = std::time::Instant::now();
    let config = EvalConfig { samples: vec![5000], ..Default::default() };
    let benches = find_benchmarks(root).unwrap();
    assert_eq!(benches.len(), 1);
    let fpfh = [Descriptor::parse("fpfh", "--descriptor").unwrap()];
    let scores = evaluate(&benches[0], &fpfh, &config, &mut || {}).unwrap().remove(0);
    assert_eq!(scores.len(), 6);
    for s in &scores {
        println!("pair {} {}: IR {:.3}, error {:.2e}, RRE {:.3} deg, RTE {:.4} m", s.i, s.j, s.inlier_ratio, s.error, s.rre_deg, s.rte_m);
    }
    let t_pipeline = t1.elapsed().as_secs_f64();
    println!("{t_build:.1} s to build the benchmark and its controls, {t_pipeline:.1} s for the pipeline; smallest control error {worst_control:.4}");
    for s in &scores {
        let (truth, _) = &truths[&(s.i, s.j)];
        let turn = truth.rotation.angle().to_degrees();
        let shift = truth.translation.vector.norm();
        assert!(turn > 40.0 && shift > 0.3, "pair {} {}: the truth is too near the identity ({turn} deg, {shift} m)", s.i, s.j);
        assert!(
            s.registered && s.error < RR_ERROR / 10.0 && s.rre_deg < 5.0,
            "pair {} {} (truth: {turn:.0} deg, {shift:.2} m) not registered within a tenth of the bar and 5°: error {} \
             (bar {RR_ERROR}), RRE {} deg, RTE {} m, IR {}",
            s.i,
            s.j,
            s.error,
            s.rre_deg,
            s.rte_m,
            s.inlier_ratio
        );
    }
}

/// The least share of the pairs Open3D registers that ours must register too. Measured (27 pairs, 5000
/// samples, three runs): ours 21; Open3D 20 or 21 (its RANSAC varies from run to run), of which ours
/// registers 20 (95-100 %). 80 % leaves room for Open3D's streams; a pipeline that registers nothing or
/// only a few fails (RANSAC returning the identity registers 1).
const SHARE_OF_OPEN3D: f64 = 0.8;
/// The least number of pairs Open3D must register for the share to mean something (measured: 20-21 of 27).
const MIN_OPEN3D_REGISTERED: usize = 12;

/// Registration recall of our RANSAC + FPFH against Open3D's own pipeline on real single-frame pairs of
/// 7-Scenes: ours must register at least [`SHARE_OF_OPEN3D`] of the very pairs Open3D registers, and
/// Open3D at least [`MIN_OPEN3D_REGISTERED`], so a pipeline that registers nothing fails.
#[test]
fn ransac_fpfh_registers_most_of_the_real_pairs_open3d_registers() {
    let _timing = crate::support::timed();
    use pointreggpt::registration::{evaluate, Descriptor, EvalConfig};
    let Some(real) = real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let bench = dir.path().join("bench");
    let seq = real.join("7scenes-redkitchen");
    let b = bench.to_str().unwrap();
    // Gaps of 40-100 frames: overlaps from 20 to 80 %, so not every pair is easy (Open3D registers about 3 in 4).
    run(&["fragments", seq.to_str().unwrap(), "--single-frames", "--first", "0", "--frames", "200", "--every", "15", "--gaps", "40,70,100", "--out", b, "--quiet"]);
    // Ours, pair by pair, with the settings of `eval registration --samples 5000` (the same code).
    let t0 = std::time::Instant::now();
    let config = EvalConfig { samples: vec![5000], ..Default::default() };
    let mut ours = std::collections::BTreeMap::new();
    let benches = find_benchmarks(&bench).unwrap();
    for bm in &benches {
        for s in evaluate(bm, &[Descriptor::parse("fpfh", "--descriptor").unwrap()], &config, &mut || {}).unwrap().remove(0) {
            ours.insert((bm.name.clone(), s.scene.clone(), s.i, s.j), s.registered);
        }
    }
    let ours_s = t0.elapsed().as_secs_f64();
    // Open3D's own pipeline on the same pairs (its own sampling and RANSAC streams).
    let mut theirs = std::collections::BTreeMap::new();
    for bm in &benches {
        let o = peer(&["rr", b, &bm.name, "0.025", "5000", "0.05", "50000"]);
        for l in o.lines().filter_map(|l| l.strip_prefix("pair ")) {
            let f: Vec<&str> = l.split_whitespace().collect();
            theirs.insert((bm.name.clone(), f[0].to_string(), f[1].parse::<usize>().unwrap(), f[2].parse::<usize>().unwrap()), f[3] == "1");
        }
    }
    assert_eq!(ours.keys().collect::<Vec<_>>(), theirs.keys().collect::<Vec<_>>(), "not the same pairs");
    let pairs = ours.len();
    let (n_ours, n_theirs) = (ours.values().filter(|r| **r).count(), theirs.values().filter(|r| **r).count());
    let both = ours.iter().filter(|(k, r)| **r && theirs[*k]).count();
    let only_ours = ours.iter().filter(|(k, r)| **r && !theirs[*k]).count();
    println!(
        "RR on {pairs} real single-frame pairs: ours {n_ours}, Open3D {n_theirs}; registered by both {both}, by ours only \
         {only_ours}, by Open3D only {} ({ours_s:.1} s for ours, description included)",
        n_theirs - both
    );
    assert!(pairs >= 20, "{pairs} pairs");
    assert!(
        n_theirs >= MIN_OPEN3D_REGISTERED,
        "Open3D registers {n_theirs} of {pairs} pairs, fewer than {MIN_OPEN3D_REGISTERED}: the comparison says nothing"
    );
    assert!(
        both as f64 >= SHARE_OF_OPEN3D * n_theirs as f64,
        "ours registers {both} of the {n_theirs} pairs Open3D registers (below {:.0} %; ours {n_ours} of {pairs} in all)",
        100.0 * SHARE_OF_OPEN3D
    );
}
