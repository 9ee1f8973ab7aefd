//! Real inputs without (some) poses: a TUM sequence whose motion capture misses one sample (bridged by
//! interpolation) and a stretch longer than the bound (those frames have no pose), a TUM folder without
//! ground truth, and a plain folder of depth PNGs. Commands whose pairs take their truth from the poses
//! (`fragments`, `labels`, `eval boost`) leave the unposed frames out and count them (`--strict` stops);
//! a build needs no pose and uses every frame.

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::Status;
use pointreggpt::sources::{depth_png, text};
use std::path::{Path, PathBuf};
use crate::support::bin;

fn run(args: &[&str]) -> (bool, String, String) {
    let o = bin().args(args).output().unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn run_ok(args: &[&str]) -> String {
    let (ok, out, err) = run(args);
    assert!(ok, "{args:?}: {err}");
    out
}

const FRAMES: usize = 40;
/// Frames whose ground-truth sample is removed: 5 alone (a 67 ms gap: interpolated), 20-24 (a 200 ms
/// gap, longer than the 100 ms bound: no pose).
const ONE_MISSING: usize = 5;
const GAP: std::ops::Range<usize> = 20..25;

/// A synthetic scene written as a TUM sequence (depth at 5000 units per metre, `depth.txt`, and a
/// `groundtruth.txt` with one sample at each frame's time except the removed ones), and the camera
/// `fx,fy,cx,cy` of its images (given to the commands, since TUM's default is 525).
fn tum_sequence(dir: &Path, groundtruth: bool) -> (PathBuf, String) {
    let synth = dir.join("synth");
    run_ok(&["synth", "--out", synth.to_str().unwrap(), "--frames", &FRAMES.to_string(), "--seed", "700"]);
    let src = synth.join("synthetic-700");
    let root = dir.join("rgbd_dataset_synthetic");
    std::fs::create_dir_all(root.join("depth")).unwrap();
    let (mut depth_txt, mut gt) = (String::from("# timestamp filename\n"), String::from("# timestamp tx ty tz qx qy qz qw\n"));
    for i in 0..FRAMES {
        let t = 1000.0 + i as f64 / 30.0;
        let png = depth_png::read_depth_png(&src.join(format!("frame-{i:06}.depth.png"))).unwrap();
        let raw: Vec<u16> = png.data.iter().map(|&mm| mm.saturating_mul(5)).collect();
        depth_png::write_depth_png(&root.join(format!("depth/{t:.6}.png")), png.width, png.height, &raw).unwrap();
        depth_txt.push_str(&format!("{t:.6} depth/{t:.6}.png\n"));
        if i != ONE_MISSING && !GAP.contains(&i) {
            let p = text::read_pose_file(&src.join(format!("frame-{i:06}.pose.txt"))).unwrap();
            let (v, q) = (p.translation.vector, p.rotation.into_inner());
            gt.push_str(&format!("{t:.6} {} {} {} {} {} {} {}\n", v.x, v.y, v.z, q.i, q.j, q.k, q.w));
        }
    }
    std::fs::write(root.join("depth.txt"), depth_txt).unwrap();
    if groundtruth {
        std::fs::write(root.join("groundtruth.txt"), gt).unwrap();
    }
    let k = text::read_numbers(&src.join("camera-intrinsics.txt")).unwrap();
    (root, format!("{},{},{},{}", k[0], k[4], k[2], k[5]))
}

fn source_toml(root: &Path, camera: &str, layout: &str, extra: &str) -> String {
    let c: Vec<&str> = camera.split(',').collect();
    format!(
        "[source]\nkind = \"directory\"\npath = \"{}\"\nlayout = \"{layout}\"\nintrinsics = {{ fx = {}, fy = {}, cx = {}, cy = {} }}\n{extra}",
        root.display(),
        c[0],
        c[1],
        c[2],
        c[3]
    )
}

#[test]
fn tum_gaps_are_counted_in_inspect_fragments_labels_and_eval_boost_and_strict_stops() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (root, camera) = tum_sequence(dir.path(), true);
    let seq = root.to_str().unwrap();

    let out = run_ok(&["inspect", seq, "--intrinsics", &camera]);
    assert!(out.contains(&format!("{FRAMES} frames ({} with a pose)", FRAMES - GAP.len())), "{out}");
    assert!(out.contains(&format!("{} poses exact, 1 interpolated, {} frame(s) without a pose", FRAMES - GAP.len() - 1, GAP.len())), "{out}");

    // Fragments of 10 frames: fragment 2 (frames 20-29) loses the 5 frames of the gap and is fused from
    // the other 5, in the camera of frame 25.
    let bench = dir.path().join("bench");
    let out = run_ok(&["fragments", seq, "--intrinsics", &camera, "--frames-per-fragment", "10", "--out", bench.to_str().unwrap(), "--quiet"]);
    assert!(out.contains("4 clouds"), "{out}");
    assert!(out.contains(&format!("{} of the frames used left out for want of a pose", GAP.len())), "{out}");
    let singles = dir.path().join("singles");
    let out = run_ok(&["fragments", seq, "--intrinsics", &camera, "--single-frames", "--every", "5", "--gaps", "5,10", "--out", singles.to_str().unwrap(), "--quiet"]);
    // Frames 0, 5, ..., 35 are used (sources and their partners 5 and 10 frames later); of the gap's
    // frames 20-24 only 20 is among them. Frame 5 (its sample missing) is interpolated, so it stays.
    assert!(out.contains("1 of the frames used left out"), "{out}");
    let written: Vec<String> = std::fs::read_dir(singles.join("rgbd_dataset_synthetic-frames")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert!(!written.contains(&"cloud_bin_20.ply".to_string()) && written.contains(&"cloud_bin_25.ply".to_string()), "{written:?}");

    let (ok, _, err) = run(&["fragments", seq, "--intrinsics", &camera, "--frames-per-fragment", "10", "--strict", "--out", dir.path().join("strict").to_str().unwrap()]);
    assert!(!ok && err.contains("depth/1000.666667.png") && err.contains("no camera pose"), "{err}");

    // Labels: windows of 10 frames; window 2 fuses its 5 posed frames, its reference the posed frame
    // nearest its first; nothing is dropped.
    let labels_cfg = dir.path().join("labels.toml");
    std::fs::write(
        &labels_cfg,
        format!(
            "seed = 1\nsamples_per_window = 1\nshard_size = 2\n{}\n[window]\nframes = 10\nstride = 10\nreference = \"first\"\n\
             [tsdf]\nvoxel_size_m = 0.02\ntruncation_m = 0.06\nmax_depth_m = 6.0\n[working]\nsize = 64\n",
            source_toml(&root, &camera, "tum", "")
        ),
    )
    .unwrap();
    let labels = dir.path().join("labels");
    let out = run_ok(&["labels", labels_cfg.to_str().unwrap(), "--out", labels.to_str().unwrap(), "--no-progress"]);
    assert!(out.contains(&format!("{} frame(s) without a camera pose left out of their windows; 0 window(s)", GAP.len())), "{out}");
    assert!(out.contains("4 windows"), "{out}");
    let (ok, _, err) = run(&["labels", labels_cfg.to_str().unwrap(), "--out", dir.path().join("labels-strict").to_str().unwrap(), "--no-progress", "--strict"]);
    assert!(!ok && err.contains("no camera pose"), "{err}");

    // eval boost: the real fragment pairs leave the gap's frames out and say so.
    let root_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let boost = dir.path().join("boost");
    let (classical, with_frames) = (root_dir.join("pipelines/paper-3dmatch-classical.toml"), format!("{seq}@0-39"));
    let args = [
        "eval", "boost", bench.to_str().unwrap(), "--sequence", &with_frames, "--intrinsics", &camera, "--conditions", "fpfh,frag",
        "--fragment-frames", "10", "--fragment-stride", "5", "--seeds", "1", "--pairs", "50", "--steps", "2", "--samples", "100",
        "--classical-config", classical.to_str().unwrap(), "--out", boost.to_str().unwrap(), "--quiet",
    ];
    let out = run_ok(&args);
    assert!(out.contains(&format!("{} of frames 0..40 have no camera pose: left out of the real pairs", GAP.len())), "{out}");
    let notes = std::fs::read_to_string(boost.join("data-notes.txt")).unwrap();
    assert!(notes.contains("left out of the real pairs"), "{notes}");
    let mut strict = args.to_vec();
    let other = dir.path().join("boost-strict");
    *strict.iter_mut().find(|a| **a == boost.to_str().unwrap()).unwrap() = other.to_str().unwrap();
    strict.push("--strict");
    let (ok, _, err) = run(&strict);
    assert!(!ok && err.contains("no camera pose"), "{err}");
}

/// A build needs only depth and intrinsics: every frame of a TUM folder with gaps in its ground truth,
/// and of one without any ground truth, makes a pair.
#[test]
fn builds_use_every_frame_with_or_without_a_pose() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    for with_gt in [true, false] {
        let sub = dir.path().join(format!("gt-{with_gt}"));
        let (root, camera) = tum_sequence(&sub, with_gt);
        let cfg = sub.join("build.toml");
        std::fs::write(&cfg, format!("shard_size = 8\n{}\n[select]\nevery = 4\n", source_toml(&root, &camera, "tum", ""))).unwrap();
        let out = sub.join("ds");
        run_ok(&["build", cfg.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-progress"]);
        let rows = Dataset::open(&out).unwrap().read_pairs().unwrap();
        assert_eq!(rows.len(), FRAMES / 4);
        assert!(rows.iter().all(|r| r.status != Status::InputError), "{:?}", rows.iter().map(|r| &r.message).collect::<Vec<_>>());
        let ok = rows.iter().filter(|r| r.status == Status::Ok).count();
        assert!(ok >= rows.len() - 2, "{ok} of {} ok", rows.len());
        // Frame 20 (no pose in either folder) made a pair.
        assert!(rows.iter().any(|r| r.frame_key.ends_with("1000.666667") && r.status == Status::Ok), "with ground truth: {with_gt}");
    }
}

/// A plain folder of depth PNGs (a phone's export: millimetres, names `depth_<n>.png`), with the camera
/// and the scale in the config, builds pairs; without them the config is refused naming the key.
#[test]
fn a_plain_depth_folder_builds_pairs() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let synth = dir.path().join("synth");
    run_ok(&["synth", "--out", synth.to_str().unwrap(), "--frames", "12", "--seed", "701"]);
    let src = synth.join("synthetic-701");
    let plain = dir.path().join("phone");
    std::fs::create_dir(&plain).unwrap();
    for i in 0..12 {
        std::fs::copy(src.join(format!("frame-{i:06}.depth.png")), plain.join(format!("depth_{i}.png"))).unwrap();
    }
    let k = text::read_numbers(&src.join("camera-intrinsics.txt")).unwrap();
    let camera = format!("{},{},{},{}", k[0], k[4], k[2], k[5]);
    // The shipped example config, with this folder and this camera.
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/depth-folder.toml");
    let c: Vec<&str> = camera.split(',').collect();
    let out = dir.path().join("ds");
    run_ok(&[
        "build", example.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-progress", "--set", &format!("source.path={}", plain.display()),
        "--set", &format!("source.intrinsics={{ fx = {}, fy = {}, cx = {}, cy = {} }}", c[0], c[1], c[2], c[3]), "--set", "shard_size=6",
    ]);
    let rows = Dataset::open(&out).unwrap().read_pairs().unwrap();
    assert_eq!(rows.len(), 12);
    assert_eq!(rows[0].frame_key, "phone/depth_0");
    assert_eq!(rows[11].frame_key, "phone/depth_11", "natural order");
    assert!(rows.iter().filter(|r| r.status == Status::Ok).count() >= 10);
    // The camera of the config reaches the rows (working intrinsics are derived from it).
    assert!(rows.iter().all(|r| r.source_path.contains("phone/depth_")));

    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, source_toml(&plain, &camera, "folder", "")).unwrap();
    let (ok, _, err) = run(&["build", bad.to_str().unwrap(), "--out", dir.path().join("x").to_str().unwrap()]);
    assert!(!ok && err.contains("source.layout") && err.contains("depth_scale"), "{err}");
    assert!(!dir.path().join("x").exists(), "a refused config writes nothing");
}
