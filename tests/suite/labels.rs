//! The correction-label pipeline against the synthetic oracle: the dense re-projection I_d matches the
//! scene's true depth at the sampled pose, and M_gt agrees with the exact penetration mask.

use crate::support;

use pointreggpt::geometry::{pose_from_rows, DepthMap, Intrinsics};
use pointreggpt::labels::{run_labels, LabelsConfig};
use pointreggpt::pipeline::BuildOptions;
use pointreggpt::runtime::CancelToken;
use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::labels::{batch_to_labels, LabelRow, LABELS_TABLE};
use pointreggpt::shards::row::Status;
use pointreggpt::sources::depth_png::decode_depth_png;
use pointreggpt::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use std::path::Path;

const CONFIG: &str = r#"
seed = 5
samples_per_window = 3
shard_size = 2
tau_gt = 0.05
[source]
kind = "synthetic"
scenes = 1
first_seed = 40
[source.synthetic]
frames = 100
[window]
frames = 50
stride = 50
[tsdf]
voxel_size_m = 0.006
truncation_m = 0.03
"#;

fn depth(png: &[u8]) -> DepthMap {
    let raw = decode_depth_png(png, Path::new("row.png")).unwrap();
    DepthMap::from_raw(raw.width, raw.height, &raw.data, 1000.0, &[0]).unwrap()
}

fn mask(png: &[u8]) -> Vec<bool> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
    let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf[..info.buffer_size()].iter().map(|v| *v > 127).collect()
}

/// Whether the true surface point seen at `pixel` of the target camera was observed by a frame of the
/// window: it projects into that frame where the frame's true depth equals its depth within 1 cm.
fn observed(seq: &SyntheticSequence, truths: &[DepthMap], window: &[usize], t_world_from_target: &nalgebra::Isometry3<f64>, k: &Intrinsics, pixel: usize, z: f32) -> bool {
    if z <= 0.0 {
        return false;
    }
    let (c, r) = ((pixel % k.width as usize) as f64, (pixel / k.width as usize) as f64);
    let z = z as f64;
    let p_world = t_world_from_target * nalgebra::Point3::new((c - k.cx) * z / k.fx, (r - k.cy) * z / k.fy, z);
    let kf = &seq.intrinsics;
    window.iter().any(|&i| {
        let q = seq.poses[i].inverse() * p_world;
        if q.z <= 0.0 {
            return false;
        }
        let (u, v) = ((q.x * kf.fx / q.z + kf.cx).round(), (q.y * kf.fy / q.z + kf.cy).round());
        u >= 0.0 && v >= 0.0 && u < kf.width as f64 && v < kf.height as f64 && (truths[i].at(u as u32, v as u32) as f64 - q.z).abs() < 0.01
    })
}

fn read_labels(out: &Path) -> Vec<LabelRow> {
    let ds = Dataset::open(out).unwrap();
    let mut rows = Vec::new();
    for e in ds.committed(LABELS_TABLE).unwrap().values() {
        for b in ds.read_shard_batches(e).unwrap() {
            rows.extend(batch_to_labels(&b).unwrap());
        }
    }
    rows.sort_by_key(|r| (r.unit_index, r.sample_index));
    rows
}

#[test]
fn labels_agree_with_the_exact_penetration_mask() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config: LabelsConfig = toml::from_str(CONFIG).unwrap();
    let opts = BuildOptions::into_folder(dir.path().join("labels"));
    let report = run_labels(&config, &opts, &CancelToken::new()).unwrap();
    assert_eq!(report.rows_by_status.get("ok"), Some(&6), "2 windows x 3 samples");

    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 100, ..Default::default() }, 40).unwrap();
    let rows = read_labels(&opts.out);
    let (mut inter, mut union) = (0usize, 0usize);
    let mut all = (0usize, 0usize);
    let mut behind = (0usize, 0usize);
    let truths: Vec<DepthMap> = (0..seq.len()).map(|i| seq.true_depth(i)).collect();
    for r in &rows {
        assert_eq!(r.status, Status::Ok);
        let reference: usize = r.reference_frame.rsplit("frame-").next().unwrap().parse().unwrap();
        let t = pose_from_rows(&r.t_target_from_reference).unwrap();
        let k = Intrinsics::new(r.intrinsics[0], r.intrinsics[1], r.intrinsics[2], r.intrinsics[3], r.width, r.height).unwrap();
        let t_world_from_target = seq.poses[reference] * t.inverse();
        let truth = seq.scene.render_depth(&k, &t_world_from_target);
        let window: Vec<usize> = (reference..reference + 50).collect();
        let (sparse, dense, keep) = (depth(&r.sparse_depth_png), depth(&r.dense_depth_png), mask(&r.label_png));

        // I_d is the fused surface seen from the sampled pose: within a few mm of the truth.
        let mut err: Vec<f32> = dense.data().iter().zip(truth.data()).filter(|(d, t)| **d > 0.0 && **t > 0.0).map(|(d, t)| (d - t).abs()).collect();
        assert!(err.len() > 20_000, "I_d covers {} pixels", err.len());
        err.sort_by(f32::total_cmp);
        let median = err[err.len() / 2];
        assert!(median < 0.006, "{}: median |I_d - truth| = {median}", r.label_key);

        for (pixel, ((s, t), kept)) in sparse.data().iter().zip(truth.data()).zip(&keep).enumerate() {
            if *s <= 0.0 {
                continue;
            }
            // The exact label: the same formula on the true depth (a sparse point more than τ behind the
            // true surface, i.e. penetrating, or floating more than τ in front of it).
            let exact = !(*t > 0.0 && (s - t).abs() < r.tau_gt);
            behind.0 += (*t > 0.0 && s - t > r.tau_gt && !kept) as usize;
            behind.1 += (*t > 0.0 && s - t > r.tau_gt) as usize;
            let labelled = !kept;
            all.0 += (exact && labelled) as usize;
            all.1 += (exact || labelled) as usize;
            if observed(&seq, &truths, &window, &t_world_from_target, &k, pixel, *t) {
                inter += (exact && labelled) as usize;
                union += (exact || labelled) as usize;
            }
        }
        eprintln!("{}: median |I_d - truth| {:.4} m, sparse pixels {}, dropped {}", r.label_key, median, r.sparse_pixels, r.dropped_pixels);
    }
    let iou = inter as f64 / union.max(1) as f64;
    eprintln!(
        "penetrated-class IoU of M_gt against the exact mask: {iou:.3} ({inter} / {union}) where the window observed the true surface; \
         {:.3} ({} / {}) over every sparse pixel (occluders no fused frame saw cannot be labelled)",
        all.0 as f64 / all.1.max(1) as f64,
        all.0,
        all.1
    );
    eprintln!("of the sparse pixels truly behind the surface by more than tau_gt (penetrating), M_gt drops {} of {}", behind.0, behind.1);
    assert!(union > 500, "the sampled views must show penetration ({union} pixels)");
    assert!(iou >= 0.9, "IoU {iou:.3}");
}

#[test]
fn fuse_command_writes_a_cloud_on_the_true_surface_and_a_mesh() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 10, ..Default::default() }, 8).unwrap();
    seq.write_3dmatch(&dir.path().join("seq")).unwrap();
    let o = support::bin()
        .args(["fuse"])
        .arg(dir.path().join("seq"))
        .args(["--frames", "10", "--voxel", "0.01", "--truncation", "0.04", "--out"])
        .arg(dir.path().join("fused"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let points = pointreggpt::ply::read_ply(&dir.path().join("fused/fused.cloud.ply")).unwrap();
    assert!(points.len() > 10_000);
    assert!(String::from_utf8_lossy(&o.stdout).contains(&format!("{} surface points", points.len())));
    // The cloud is in frame 0's camera coordinates: move it to the world and measure the distance to the scene.
    let world = pointreggpt::geometry::transform_points(&points, &seq.poses[0]);
    let mut d: Vec<f64> = world
        .iter()
        .step_by(50)
        .map(|p| {
            let q = nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64);
            seq.scene.shapes().iter().map(|s| s.signed_distance(&q).abs()).fold(f64::INFINITY, f64::min)
        })
        .collect();
    d.sort_by(f64::total_cmp);
    assert!(d[d.len() / 2] < 0.005, "median distance to the true surface {}", d[d.len() / 2]);
    let mesh = std::fs::read(dir.path().join("fused/fused.mesh.ply")).unwrap();
    let header = String::from_utf8_lossy(&mesh[..300.min(mesh.len())]).to_string();
    assert!(header.contains("element face") && header.contains("element vertex"), "{header}");
}
