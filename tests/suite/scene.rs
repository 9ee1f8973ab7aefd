//! Scene-made targets (issue 49): for posed sequences the frames around a source frame are fused and
//! ray-cast at the target pose; the scene corrects and fills the target. Checked against the synthetic
//! scenes' exact depth (the oracle), independent counts of the provenance and of the scene's frames, the
//! held-out rule of `eval inpaint`, and a killed build's resume.

use crate::support;

use pointreggpt::geometry::{pose_from_rows, DepthMap, Intrinsics};
use pointreggpt::pipeline::{run_build, BuildConfig, BuildOptions};
use pointreggpt::runtime::CancelToken;
use pointreggpt::scene::SceneConfig;
use pointreggpt::shards::dataset::Dataset;
use pointreggpt::shards::row::{PairRow, Status};
use pointreggpt::sources::depth_png::decode_depth_png;
use pointreggpt::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;
use crate::support::{bin, synthetic_config};

/// The TSDF voxel of the scenes below, metres.
const VOXEL: f32 = 0.01;

/// One synthetic scene of 90 frames at 320×240 seen by an ideal sensor (1 mm quantisation only), every
/// 15th frame a source with two samples; the scene of each source fuses every 3rd frame of its block of
/// 30 and 30 frames on each side; `correct` and `inpaint` as given (TOML tables).
fn config_text(correct: &str, inpaint: &str) -> String {
    format!(
        "{}[source.synthetic.sensor]\nnoise_base_m = 0.0\nnoise_quadratic_per_m = 0.0\ngrazing_start_deg = 90.0\ngrazing_full_deg = 90.0\n\
         edge_drop_probability = 0.0\nspeckle_drop_probability = 0.0\nmin_depth_m = 0.0\nmax_depth_m = 65.0\n\
         [scene]\nblock = 30\nreach = 30\nevery = 3\n[scene.tsdf]\nvoxel_size_m = {VOXEL}\ntruncation_m = 0.04\n\
         [correct]\ncondition = {correct}\noutput = {correct}\n[inpaint]\n{inpaint}\n",
        synthetic_config(1, 90, 15, 2, 320, 240, 4)
    )
}

const SCENE_CORRECT: &str = r#"{ method = "scene", margin = 0.05, fallback = { method = "min_pool", threshold = 0.0375 } }"#;
const SCENE_FILL: &str = "method = \"scene\"\nfallback = { method = \"none\" }";

fn build(text: &str, out: &Path) -> Vec<PairRow> {
    let config = BuildConfig::from_toml(text, "scene test").unwrap();
    run_build(&config, &BuildOptions::into_folder(out), &CancelToken::new()).unwrap();
    let mut rows = Dataset::open(out).unwrap().read_pairs().unwrap();
    rows.sort_by_key(|r| r.unit_index);
    rows
}

/// The scene build and the same build with the background fill (same poses, same corrections), built once.
struct Builds {
    _dir: tempfile::TempDir,
    scene: Vec<PairRow>,
    background: Vec<PairRow>,
}

fn builds() -> &'static Builds {
    static B: OnceLock<Builds> = OnceLock::new();
    B.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let scene = build(&config_text(SCENE_CORRECT, SCENE_FILL), &dir.path().join("scene"));
        let background = build(&config_text(SCENE_CORRECT, "method = \"background\""), &dir.path().join("background"));
        Builds { _dir: dir, scene, background }
    })
}

fn depth_of(png: &[u8], w: u32, h: u32) -> Vec<f32> {
    let raw = decode_depth_png(png, Path::new("target_depth_png")).unwrap();
    assert_eq!((raw.width, raw.height), (w, h));
    raw.data.iter().map(|&v| v as f32 / 1000.0).collect()
}

fn mask_of(png: &[u8]) -> Vec<bool> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
    let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf[..info.buffer_size()].iter().map(|&v| v > 0).collect()
}

/// The exact depth the target camera of `row` sees: the synthetic scene rendered at the source frame's
/// pose composed with the row's `T_target_from_source`, at the row's working intrinsics.
fn true_target_depth(seq: &SyntheticSequence, row: &PairRow) -> Vec<f32> {
    let frame: usize = row.frame_key.rsplit("frame-").next().unwrap().parse().unwrap();
    let t = pose_from_rows(&row.t_target_from_source).unwrap();
    let [fx, fy, cx, cy] = row.target_intrinsics;
    let k = Intrinsics::new(fx, fy, cx, cy, row.width, row.height).unwrap();
    seq.scene.render_depth(&k, &(seq.poses[frame] * t.inverse())).into_data()
}

fn sequence() -> SyntheticSequence {
    let config = BuildConfig::from_toml(&config_text(SCENE_CORRECT, SCENE_FILL), "t").unwrap();
    match config.source {
        pointreggpt::sources::SourceConfig::Synthetic { synthetic, first_seed, .. } => SyntheticSequence::generate(&synthetic, first_seed).unwrap(),
        _ => unreachable!(),
    }
}

#[test]
fn the_scene_fill_reproduces_the_true_hidden_depth_and_the_background_fill_does_not() {
    let _timing = crate::support::timed();
    let b = builds();
    let seq = sequence();
    let (mut scene_close, mut background_close, mut pixels, mut unknown) = (0usize, 0usize, 0usize, 0usize);
    let mut errors = Vec::new();
    let mut paired = 0;
    for (s, g) in b.scene.iter().zip(&b.background) {
        assert_eq!((s.unit_index, s.t_target_from_source), (g.unit_index, g.t_target_from_source), "the two builds draw the same poses");
        if s.status != Status::Ok || g.status != Status::Ok {
            continue;
        }
        paired += 1;
        assert!(s.scene_frames > 0, "{}: a posed frame takes the scene path", s.pair_key);
        assert_eq!(s.known_mask_png, g.known_mask_png, "the same correction: the same known pixels");
        let known = mask_of(&s.known_mask_png);
        let truth = true_target_depth(&seq, s);
        let (scene, background) = (depth_of(&s.target_depth_png, s.width, s.height), depth_of(&g.target_depth_png, g.width, g.height));
        for i in 0..known.len() {
            if known[i] || truth[i] <= 0.0 {
                continue;
            }
            unknown += 1;
            // With `fallback = none`, every unknown pixel with depth came from the scene.
            if scene[i] > 0.0 {
                pixels += 1;
                scene_close += ((scene[i] - truth[i]).abs() <= VOXEL) as usize;
                errors.push((scene[i] - truth[i]).abs());
                background_close += (background[i] > 0.0 && (background[i] - truth[i]).abs() <= VOXEL) as usize;
            }
        }
    }
    assert!(paired >= 6, "only {paired} pairs both ok");
    errors.sort_by(f32::total_cmp);
    let q = |f: f64| errors[((errors.len() - 1) as f64 * f) as usize];
    println!("scene-pixel |error| quantiles 0.5 {:.4} 0.8 {:.4} 0.9 {:.4} 0.95 {:.4} 0.99 {:.4} m", q(0.5), q(0.8), q(0.9), q(0.95), q(0.99));
    let share = |n: usize| n as f64 / pixels.max(1) as f64;
    println!(
        "{pixels} scene pixels ({:.1} % of the unknown ones): within {VOXEL} m of the truth {:.3} (scene) vs {:.3} (background fill)",
        100.0 * pixels as f64 / unknown as f64,
        share(scene_close),
        share(background_close)
    );
    assert!(pixels as f64 >= 0.25 * unknown as f64, "the scene covers a good part of the unknown pixels: {pixels} of {unknown}");
    assert!(q(0.5) <= 0.002, "the scene fill's median error is {} m", q(0.5));
    assert!(share(scene_close) >= 0.85, "scene fill within a voxel of the truth on {:.3} of its pixels", share(scene_close));
    assert!(share(background_close) <= 0.5, "the background fill must not reproduce the hidden depth ({:.3})", share(background_close));
}

#[test]
fn provenance_shares_agree_with_an_independent_count_of_the_pixels() {
    let _timing = crate::support::timed();
    // Per pair: the voxels (2.5 cm, origin 0) of the target's pixels back-projected from the stored PNGs,
    // each classified re-projected (known mask), scene (unknown with depth: the fallback is `none`) — then
    // the share of voxels that are mostly scene, against the stored per-point shares.
    let b = builds();
    let mut checked = 0;
    for r in b.scene.iter().filter(|r| r.status == Status::Ok) {
        assert_eq!(r.target_known_share.len(), r.target_points.len());
        assert_eq!(r.target_scene_share.len(), r.target_points.len());
        for (k, s) in r.target_known_share.iter().zip(&r.target_scene_share) {
            assert!((k + s - 1.0).abs() < 1e-5, "{}: with no fallback fill every point is re-projected or scene ({k} + {s})", r.pair_key);
        }
        let known = mask_of(&r.known_mask_png);
        let depth = depth_of(&r.target_depth_png, r.width, r.height);
        let [fx, fy, cx, cy] = r.target_intrinsics;
        let mut voxels: BTreeMap<[i64; 3], (u32, u32)> = BTreeMap::new();
        for (i, &z) in depth.iter().enumerate() {
            if !(z > 0.5 && z < 10.0) {
                continue;
            }
            let (c, row) = ((i % r.width as usize) as f64, (i / r.width as usize) as f64);
            let p = [(c - cx) / fx * z as f64, (row - cy) / fy * z as f64, z as f64];
            if p[0].abs() > 1.5 || p[1].abs() > 1.5 || p[2] < 0.5 || p[2] > 3.5 {
                continue;
            }
            let e = voxels.entry(p.map(|v| (v / 0.025).floor() as i64)).or_default();
            e.0 += 1;
            e.1 += !known[i] as u32;
        }
        let mostly_scene = |n: usize, m: usize| m as f64 / n as f64;
        let expected = mostly_scene(voxels.len(), voxels.values().filter(|(n, s)| 2 * s > *n).count());
        let stored = mostly_scene(r.target_scene_share.len(), r.target_scene_share.iter().filter(|s| **s > 0.5).count());
        assert!((expected - stored).abs() < 0.03, "{}: mostly-scene voxels {stored:.3} stored vs {expected:.3} counted", r.pair_key);
        assert!((voxels.len() as f64 / r.target_points.len() as f64 - 1.0).abs() < 0.03, "{}: {} voxels counted, {} points", r.pair_key, voxels.len(), r.target_points.len());
        checked += 1;
    }
    assert!(checked >= 6);
    assert!(b.scene.iter().any(|r| r.target_scene_share.iter().any(|s| *s > 0.5)), "some points came from the scene");
}

#[test]
fn each_scene_fuses_the_posed_frames_of_its_window_once_and_unposed_frames_take_the_single_map_path() {
    let _timing = crate::support::timed();
    // A 3DMatch-layout copy of a synthetic sequence with the poses of frames 6, 7 and 45 removed: frame 45
    // (a source) has no pose, so its units take the single-map path; frame 6 is in the scene of block 0
    // (every 3rd frame), frame 7 is not.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("seq");
    let synthetic = SyntheticConfig { frames: 60, intrinsics: Intrinsics::new(292.5, 292.5, 160.0, 120.0, 320, 240).unwrap(), ..Default::default() };
    SyntheticSequence::generate(&synthetic, 3).unwrap().write_3dmatch(&data).unwrap();
    for f in [6, 7, 45] {
        std::fs::remove_file(data.join(format!("frame-{f:06}.pose.txt"))).unwrap();
    }
    let text = format!(
        "seed = 5\nsamples_per_frame = 2\nshard_size = 4\n[source]\nkind = \"directory\"\npath = \"{}\"\n[select]\nevery = 15\n\
         [scene]\nblock = 30\nreach = 15\nevery = 3\n[correct]\ncondition = {SCENE_CORRECT}\noutput = {SCENE_CORRECT}\n[inpaint]\n{SCENE_FILL}\n",
        data.display()
    );
    let out = dir.path().join("ds");
    let config = BuildConfig::from_toml(&text, "t").unwrap();
    let report = run_build(&config, &BuildOptions::into_folder(&out), &CancelToken::new()).unwrap();
    // Sources 0, 15 (block 0) and 30, 45 (block 1); block 1's source 45 has no pose, but 30 has: two fusions.
    assert_eq!(report.scenes_fused, 2, "one fusion per block, shared by its units");
    // The frames each block fuses, counted here: multiples of 3 within the block ± 15, inside the
    // selection's span (0..=45), with a pose.
    let posed = |p: usize| ![6, 7, 45].contains(&p);
    let fused = |block: usize| (0..=45usize).filter(|p| p % 3 == 0 && *p + 15 >= block * 30 && *p < (block + 1) * 30 + 15 && posed(*p)).count() as u32;
    let rows = Dataset::open(&out).unwrap().read_pairs().unwrap();
    assert_eq!(rows.len(), 8);
    for r in &rows {
        let frame: usize = r.frame_key.rsplit("frame-").next().unwrap().parse().unwrap();
        assert_ne!(r.status, Status::InputError, "{}: {}", r.pair_key, r.message);
        let want = if posed(frame) { fused(frame / 30) } else { 0 };
        assert_eq!(r.scene_frames, want, "{}", r.pair_key);
        if r.scene_frames == 0 {
            assert!(r.target_scene_share.iter().all(|s| *s == 0.0), "no scene, no scene points");
        }
    }
    // `stats` counts the rows by path as the rows say.
    let stats_dir = dir.path().join("stats");
    let o = bin().args(["stats"]).arg(&out).arg("--out").arg(&stats_dir).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    for (path, scene) in [("scene", true), ("single-map", false)] {
        let mut want = [0u64; 4];
        for r in rows.iter().filter(|r| (r.scene_frames > 0) == scene) {
            want[[Status::Ok, Status::LowOverlap, Status::TooFewPoints, Status::InputError].iter().position(|s| *s == r.status).unwrap()] += 1;
        }
        let line = text.lines().find(|l| l.starts_with(&format!("{path} "))).unwrap_or_else(|| panic!("no {path} line in\n{text}"));
        let got: Vec<u64> = line.split_whitespace().skip(1).map(|v| v.parse().unwrap()).collect();
        assert_eq!(got, want, "{path}: {line}");
    }
}

#[test]
fn a_held_out_view_never_sees_its_own_frame_or_its_neighbours() {
    let _timing = crate::support::timed();
    use pointreggpt::training::eval_inpaint::scene_of_view;
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("seq");
    let synthetic = SyntheticConfig { frames: 80, intrinsics: Intrinsics::new(146.25, 146.25, 80.0, 60.0, 160, 120).unwrap(), ..Default::default() };
    SyntheticSequence::generate(&synthetic, 9).unwrap().write_3dmatch(&data).unwrap();
    let seq = pointreggpt::sources::open_sequences(&data, pointreggpt::sources::Layout::Auto).unwrap().remove(0);
    let config = SceneConfig { block: 20, reach: 40, every: 1, ..SceneConfig::default() };
    let k = Intrinsics::new(100.0, 100.0, 64.0, 64.0, 128, 128).unwrap();
    for (source, target, exclude) in [(10, 20, 15), (30, 40, 5), (40, 40, 0), (60, 79, 3)] {
        let (depth, fused) = scene_of_view(&seq, source, target, exclude, &config, &k).unwrap();
        assert!(!fused.is_empty());
        assert!(fused.iter().all(|p| p.abs_diff(target) > exclude), "view {source} -> {target}: fused {fused:?}");
        // Everything else of the window is there: the rule takes out the held-out frames only.
        let block = source / 20;
        let window = (block * 20).saturating_sub(40)..((block + 1) * 20 + 40).min(80);
        assert_eq!(fused.len(), window.filter(|p| p.abs_diff(target) > exclude).count());
        assert_eq!((depth.width(), depth.height()), (128, 128));
    }
}

#[test]
fn a_killed_scene_build_resumes_to_the_same_rows() {
    let _timing = crate::support::timed();
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("scene.toml");
    std::fs::write(&config, config_text(SCENE_CORRECT, "method = \"scene\"\nfallback = { method = \"background\" }")).unwrap();
    // The reference: one uninterrupted build, in-process on this test's threads.
    let reference = support::digests({
        let out = dir.path().join("reference");
        build(&std::fs::read_to_string(&config).unwrap(), &out);
        out
    });
    // Killed once its first shard is committed (the scene of block 0 fused, block 1's maybe half), then resumed
    // on one thread with no scene cache (each unit fuses its scene anew).
    let out = dir.path().join("killed");
    let mut child = bin().args(["--threads", "2", "build"]).arg(&config).arg("--out").arg(&out).arg("--no-progress").spawn().unwrap();
    let t0 = std::time::Instant::now();
    while std::fs::read_dir(out.join("manifest")).map(|d| d.count()).unwrap_or(0) == 0 && t0.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap();
    let status = child.wait().unwrap();
    let committed = Dataset::open(&out).unwrap().committed("pairs").unwrap().len();
    let total = reference.len().div_ceil(4);
    println!("killed: signal {:?}, {committed} of {total} shards committed", status.signal());
    assert!(committed < total, "the kill came after the build had finished: nothing to resume");
    let o = bin().args(["--threads", "1", "build"]).arg(&config).arg("--out").arg(&out).args(["--no-progress", "--scene-cache", "0"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(support::digests(&out), reference, "the resumed build holds the rows of the uninterrupted one, bit for bit");
}

#[test]
fn scene_methods_are_checked_before_any_work() {
    let _timing = crate::support::timed();
    let base = synthetic_config(1, 30, 10, 1, 160, 120, 4);
    let cases = [
        (format!("{base}[inpaint]\nmethod = \"scene\"\nfallback = {{ method = \"scene\", fallback = {{ method = \"none\" }} }}\n"), "fallback of `scene`"),
        (format!("{base}[correct.condition]\nmethod = \"scene\"\nmargin = -1.0\nfallback = {{ method = \"none\" }}\n"), "margin"),
        (format!("{base}[scene]\nevery = 0\n[inpaint]\n{SCENE_FILL}\n"), "scene.every"),
        (format!("{base}[successive]\nviews = 2\n[inpaint]\n{SCENE_FILL}\n"), "successive"),
    ];
    for (text, needle) in cases {
        let e = BuildConfig::from_toml(&text, "t").and_then(|c| c.validate()).unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
    }
    // A config without scene methods keeps the canonical TOML (and hashes) it had before scenes existed.
    let plain = BuildConfig::from_toml(&base, "t").unwrap();
    assert!(!plain.to_toml().contains("[scene]") && !plain.uses_scene());
}

#[test]
fn scene_depth_is_the_ray_cast_of_the_fused_frames() {
    let _timing = crate::support::timed();
    // The stage's scene against an independent fusion of the same frames with the library's TSDF.
    use pointreggpt::scene::{fuse_scene, window_frames};
    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 40, intrinsics: Intrinsics::new(146.25, 146.25, 80.0, 60.0, 160, 120).unwrap(), ..Default::default() }, 4).unwrap();
    let config = SceneConfig { block: 10, reach: 10, every: 2, ..SceneConfig::default() };
    let frames = window_frames(&config, 1, (0, 39), |_| true, &[]);
    assert_eq!(frames.positions(), (0..30).step_by(2).collect::<Vec<_>>().as_slice());
    let scene = fuse_scene(&frames, |p| Ok(seq.frame(p)), &config.tsdf).unwrap();
    let mut volume = pointreggpt::tsdf::TsdfVolume::new(config.tsdf.clone()).unwrap();
    for p in (0..30).step_by(2) {
        let f = seq.frame(p);
        volume.integrate(&f.depth, &f.intrinsics, &f.t_world_from_camera.unwrap()).unwrap();
    }
    let k = Intrinsics::new(100.0, 100.0, 64.0, 64.0, 128, 128).unwrap();
    let a: DepthMap = scene.depth_at(&k, &seq.poses[15]).unwrap();
    let b = volume.raycast(&k, &seq.poses[15]).unwrap();
    assert_eq!(scene.frames, 15);
    assert_eq!(a, b);
    assert!(a.valid_count() > a.data().len() / 2, "the scene is seen from a frame of its window");
}
