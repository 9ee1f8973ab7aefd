//! The registration instrument against independent computations: normals and FPFH against Open3D on the
//! same points, RANSAC + FPFH registration recall against Open3D's own pipeline on real single-frame
//! pairs, the official error against a hand-computed pair, gt.log / gt.info written and read back, the
//! fragments of a synthetic sequence against its known poses, and the same table on 1 and 2 threads.

mod support;

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
use std::process::Command;
use support::{bin, python, real_data};

fn run(args: &[&str]) -> String {
    let o = bin().args(args).output().unwrap();
    assert!(o.status.success(), "pointreggpt {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

fn peer(args: &[&str]) -> String {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/open3d_registration.py");
    let o = Command::new(python()).arg(script).args(args).output().unwrap();
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

#[test]
fn ransac_fpfh_registration_recall_matches_open3d_on_real_single_frames() {
    let Some(real) = real_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let bench = dir.path().join("bench");
    let seq = real.join("7scenes-redkitchen");
    let b = bench.to_str().unwrap();
    // Gaps of 40-100 frames: overlaps from 20 to 80 %, so RR is off its ceiling (about 80 %) and can disagree.
    run(&["fragments", seq.to_str().unwrap(), "--single-frames", "--first", "0", "--frames", "200", "--every", "15", "--gaps", "40,70,100", "--out", b, "--quiet"]);
    let t0 = std::time::Instant::now();
    let csv = run(&["eval", "registration", b, "--samples", "5000", "--csv", "--quiet"]);
    let ours_s = t0.elapsed().as_secs_f64();
    let (mut pairs, mut ours) = (0usize, 0.0f64);
    let (mut theirs, mut their_pairs) = (0usize, 0usize);
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (n, rr): (usize, f64) = (f[7].parse().unwrap(), f[6].parse().unwrap());
        pairs += n;
        ours += rr / 100.0 * n as f64;
        let o = peer(&["rr", b, f[0], "0.025", "5000", "0.05", "50000"]);
        let get = |k: &str| o.lines().find_map(|l| l.strip_prefix(k)).unwrap().trim().parse::<usize>().unwrap();
        their_pairs += get("pairs ");
        theirs += get("registered ");
    }
    let ours = ours.round() as usize;
    println!("RR on {pairs} real single-frame pairs: ours {ours}, Open3D {theirs} ({ours_s:.1} s for ours, description included)");
    assert_eq!(pairs, their_pairs);
    assert!(pairs >= 10, "{pairs} pairs");
    // Within noise: two binomial draws of the same rate differ by at most ~2 standard deviations.
    let p = (ours + theirs) as f64 / (2 * pairs) as f64;
    let sd = (2.0 * pairs as f64 * p * (1.0 - p)).sqrt();
    assert!((ours as f64 - theirs as f64).abs() <= 2.0 * sd + 1.0, "ours {ours} vs Open3D {theirs} of {pairs} (sd {sd:.2})");
}
