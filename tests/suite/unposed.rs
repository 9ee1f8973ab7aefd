//! Real inputs without (some) poses: a TUM sequence whose motion capture misses one sample (bridged by
//! interpolation) and a stretch longer than the bound (those frames have no pose), a TUM folder without
//! ground truth, and a plain folder of depth PNGs. Commands whose pairs take their truth from the poses
//! (`fragments`, `labels`, `eval boost`) leave the unposed frames out and count them (`--strict` stops);
//! a build needs no pose and uses every frame. The frames left out are checked in what the commands
//! write (the fragment's cloud, the labels' windows, `eval boost`'s real pairs), not only in what they print;
//! the TUM interpolation bound is pinned at 100 ms; `--intrinsics` / `--depth-scale` and a config's camera
//! replace a layout's own (the output equals the one from a folder that needs no override).

use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::Status;
use pointreggpt::sources::{depth_png, text};
use std::path::{Path, PathBuf};
use crate::support::{self, bin};
use pointreggpt::geometry::Point;

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

/// A TUM folder `to` (named like `root`'s folder, under `to`) listing only frames `frames` of `root`, with
/// the same ground truth.
fn only_frames(root: &Path, to: PathBuf, frames: std::ops::Range<usize>) -> PathBuf {
    let out = to.join(root.file_name().unwrap());
    std::fs::create_dir_all(out.join("depth")).unwrap();
    let mut list = String::from("# timestamp filename\n");
    for line in std::fs::read_to_string(root.join("depth.txt")).unwrap().lines().filter(|l| !l.starts_with('#')).skip(frames.start).take(frames.len()) {
        let file = line.split_whitespace().nth(1).unwrap();
        std::fs::copy(root.join(file), out.join(file)).unwrap();
        list += &format!("{line}\n");
    }
    std::fs::write(out.join("depth.txt"), list).unwrap();
    std::fs::copy(root.join("groundtruth.txt"), out.join("groundtruth.txt")).unwrap();
    out
}

/// The points of a PLY cloud, sorted (fusion may emit them in any order).
fn sorted_cloud(path: &Path) -> Vec<[u32; 3]> {
    let points: Vec<Point> = pointreggpt::ply::read_ply(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut v: Vec<[u32; 3]> = points.iter().map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]).collect();
    v.sort_unstable();
    v
}

/// The label rows of a labels dataset, by window and sample.
fn read_labels(out: &Path) -> Vec<pointreggpt::shards::labels::LabelRow> {
    let ds = Dataset::open(out).unwrap();
    let mut rows = Vec::new();
    for e in ds.committed(pointreggpt::shards::labels::LABELS_TABLE).unwrap().values() {
        for b in ds.read_shard_batches(e).unwrap() {
            rows.extend(pointreggpt::shards::labels::batch_to_labels(&b).unwrap());
        }
    }
    rows.sort_by_key(|r| (r.unit_index, r.sample_index));
    rows
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
    // What was fused, not only what was printed: fragment 2 is the fragment of frames 25-29 alone (a TUM
    // folder listing only those frames, fused as one fragment of 5 frames), point for point.
    let alone = only_frames(&root, dir.path().join("alone"), 25..30);
    let bench_alone = dir.path().join("bench-alone");
    run_ok(&["fragments", alone.to_str().unwrap(), "--intrinsics", &camera, "--frames-per-fragment", "5", "--out", bench_alone.to_str().unwrap(), "--quiet"]);
    let (gap_fragment, reference) = (sorted_cloud(&bench.join("rgbd_dataset_synthetic/cloud_bin_2.ply")), sorted_cloud(&bench_alone.join("rgbd_dataset_synthetic/cloud_bin_0.ply")));
    assert!(reference.len() > 1000, "{} points", reference.len());
    assert!(gap_fragment == reference, "fragment 2 ({} points) is not the fragment of frames 25-29 ({} points)", gap_fragment.len(), reference.len());
    // The negative control: fragment 3 (frames 30-39, all posed) is not that fragment.
    assert!(sorted_cloud(&bench.join("rgbd_dataset_synthetic/cloud_bin_3.ply")) != reference);
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
    // In the rows: window 2 fused its 5 posed frames 25-29, in the camera of frame 25 (the posed frame
    // nearest its first); the other windows their 10 frames, each in the camera of its first.
    let key = |i: usize| format!("rgbd_dataset_synthetic/{:.6}", 1000.0 + i as f64 / 30.0);
    let rows = read_labels(&labels);
    assert_eq!(rows.iter().map(|r| r.unit_index).collect::<std::collections::BTreeSet<_>>().len(), 4);
    for r in &rows {
        let w = r.unit_index as usize;
        let (first, last, frames) = if w == 2 { (25, 29, 5) } else { (10 * w, 10 * w + 9, 10) };
        assert_eq!((r.first_frame.as_str(), r.last_frame.as_str(), r.frames), (key(first).as_str(), key(last).as_str(), frames), "window {w}");
        assert_eq!(r.reference_frame, key(first), "window {w}: reference frame");
    }
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
    // In the pairs: `frag` trained on the real fragment pairs of windows of 10 frames every 5, the same
    // pairs with the same overlaps as the `fragments` command makes of them (whose fragments leave the
    // unposed frames out: checked above).
    let strided = dir.path().join("bench-strided");
    run_ok(&["fragments", seq, "--intrinsics", &camera, "--frames-per-fragment", "10", "--stride", "5", "--out", strided.to_str().unwrap(), "--quiet"]);
    let mut want: Vec<(usize, usize, f64)> = Vec::new();
    for b in ["3DMatch", "3DLoMatch"] {
        let Ok(text) = std::fs::read_to_string(strided.join("metadata/benchmarks").join(b).join("rgbd_dataset_synthetic/gt_overlap.log")) else { continue };
        for line in text.lines() {
            let f: Vec<&str> = line.split_whitespace().collect();
            want.push((f[0].parse().unwrap(), f[1].parse().unwrap(), f[2].parse().unwrap()));
        }
    }
    want.sort_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)));
    let mut got: Vec<(usize, usize, f64)> = std::fs::read_to_string(boost.join("frag/seed-0/training-pairs.tsv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            let k: Vec<&str> = f[0].split('/').collect();
            (k[1].parse().unwrap(), k[2].parse().unwrap(), f[1].parse().unwrap())
        })
        .collect();
    got.sort_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)));
    assert!(want.len() >= 3, "{want:?}");
    assert_eq!(got.iter().map(|g| (g.0, g.1)).collect::<Vec<_>>(), want.iter().map(|w| (w.0, w.1)).collect::<Vec<_>>(), "eval boost's real fragment pairs");
    for (g, w) in got.iter().zip(&want) {
        assert!((g.2 - w.2).abs() < 1e-3, "pair {}-{}: overlap {} in eval boost, {} from fragments", g.0, g.1, g.2, w.2);
    }
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

/// The TUM interpolation bound is the 100 ms docs/building.md promises: a frame whose two surrounding
/// ground-truth samples are 99.8 ms apart gets the pose between them (linear in position), one whose
/// samples are 100.2 ms apart gets none; `inspect` counts them so.
#[test]
fn tum_poses_are_interpolated_across_gaps_of_at_most_100_ms() {
    let _timing = crate::support::timed();
    use pointreggpt::sources::{open_sequences, Layout, OpenOptions, PoseSource};
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("rgbd_dataset_bound");
    std::fs::create_dir_all(root.join("depth")).unwrap();
    let (mut list, mut gt) = (String::from("# timestamp filename\n"), String::from("# timestamp tx ty tz qx qy qz qw\n"));
    // Frame 0 at 10.0 s between samples at 9.9501 and 10.0499 s (99.8 ms); frame 1 at 20.0 s between
    // samples at 19.9499 and 20.0501 s (100.2 ms). The camera moves 1 m along x between the samples.
    for (t, half) in [(10.0f64, 0.0499f64), (20.0, 0.0501)] {
        let name = format!("depth/{t:.6}.png");
        depth_png::write_depth_png(&root.join(&name), 8, 6, &[5000u16; 48]).unwrap();
        list += &format!("{t:.6} {name}\n");
        gt += &format!("{:.4} 0 0 0 0 0 0 1\n{:.4} 1 0 0 0 0 0 1\n", t - half, t + half);
    }
    std::fs::write(root.join("depth.txt"), list).unwrap();
    std::fs::write(root.join("groundtruth.txt"), gt).unwrap();
    let seqs = open_sequences(&root, OpenOptions { layout: Layout::Tum, ..Default::default() }).unwrap();
    let frames = &seqs[0].frames;
    assert_eq!(frames.len(), 2);
    match &frames[0].pose {
        PoseSource::Known(p) => {
            let v = p.translation.vector;
            assert!((v.x - 0.5).abs() < 1e-6 && v.y.abs() < 1e-9 && v.z.abs() < 1e-9, "interpolated at {v:?}, not halfway");
        }
        other => panic!("a frame between samples 99.8 ms apart has no interpolated pose: {other:?}"),
    }
    assert_eq!(frames[1].pose, PoseSource::None, "a frame between samples 100.2 ms apart got a pose");
    let out = run_ok(&["inspect", root.to_str().unwrap()]);
    assert!(out.contains("0 poses exact, 1 interpolated, 1 frame(s) without a pose"), "{out}");
}

/// `--intrinsics` and `--depth-scale` replace the layout's own camera and depth scale: a copy of a 3DMatch
/// folder whose camera file is wrong and whose depth is stored at 2000 units per metre, opened with the
/// true camera and scale, gives `fragments --single-frames` the original's clouds and pairs; without
/// either option it does not. `inspect` shows the camera given.
#[test]
fn intrinsics_and_depth_scale_options_replace_the_layouts_own() {
    let _timing = crate::support::timed();
    use pointreggpt::sources::{open_sequences, CameraConfig, OpenOptions};
    let dir = tempfile::tempdir().unwrap();
    let src = support::synthetic_sequence(16, 703);
    let copy = dir.path().join("copy").join("synthetic-703");
    std::fs::create_dir_all(&copy).unwrap();
    let k = text::read_numbers(&src.join("camera-intrinsics.txt")).unwrap();
    let camera = format!("{},{},{},{}", k[0], k[4], k[2], k[5]);
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_string();
        if name.ends_with(".depth.png") {
            let png = depth_png::read_depth_png(&path).unwrap();
            assert!(png.data.iter().all(|&mm| mm < 30_000), "{name}: a depth too far to double");
            let raw: Vec<u16> = png.data.iter().map(|&mm| mm * 2).collect();
            depth_png::write_depth_png(&copy.join(&name), png.width, png.height, &raw).unwrap();
        } else if name == "camera-intrinsics.txt" {
            let wrong = format!("{} 0 {}\n0 {} {}\n0 0 1\n", k[0] * 1.25, k[2] + 7.0, k[4] * 1.25, k[5] - 5.0);
            std::fs::write(copy.join(&name), wrong).unwrap();
        } else {
            std::fs::copy(&path, copy.join(&name)).unwrap();
        }
    }
    // The library: the options reach every frame.
    let given = OpenOptions { intrinsics: Some(CameraConfig::parse(&camera).unwrap()), depth_scale: Some(2000.0), ..Default::default() };
    let frames = &open_sequences(&copy, given).unwrap()[0].frames;
    let f = &frames[3];
    assert_eq!((f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy, f.depth_scale), (k[0], k[4], k[2], k[5], 2000.0));
    // The command line: the same clouds and pairs as from the original folder.
    let fragments = |seq: &Path, name: &str, extra: &[&str]| -> std::collections::BTreeMap<String, Vec<u8>> {
        let out = dir.path().join(name);
        run_ok(&[&["fragments", seq.to_str().unwrap(), "--single-frames", "--every", "3", "--gaps", "3,6", "--out", out.to_str().unwrap(), "--quiet"][..], extra].concat());
        files(&out)
    };
    let reference = fragments(&src, "reference", &[]);
    assert!(reference.keys().filter(|k| k.ends_with(".ply")).count() >= 4 && reference.keys().any(|k| k.ends_with("gt.log")), "{:?}", reference.keys());
    let both = fragments(&copy, "both", &["--intrinsics", &camera, "--depth-scale", "2000"]);
    assert!(both == reference, "--intrinsics and --depth-scale: other files than the original folder's: {:?} vs {:?}", both.keys(), reference.keys());
    assert!(fragments(&copy, "camera-only", &["--intrinsics", &camera]) != reference, "the depth scale made no difference");
    assert!(fragments(&copy, "scale-only", &["--depth-scale", "2000"]) != reference, "the camera made no difference");
    let shown = run_ok(&["inspect", copy.to_str().unwrap(), "--intrinsics", &camera]);
    assert!(shown.contains(&format!("fx={:.3} fy={:.3} cx={:.3} cy={:.3}", k[0], k[4], k[2], k[5])), "{shown}");
    let own = run_ok(&["inspect", copy.to_str().unwrap()]);
    assert!(own.contains(&format!("fx={:.3}", k[0] * 1.25)), "{own}");
}

/// Every file under `dir` by relative path.
fn files(dir: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(base: &Path, dir: &Path, out: &mut std::collections::BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                out.insert(p.strip_prefix(base).unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}
