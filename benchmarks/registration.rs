//! `cargo bench --bench registration`: the registration core (`pointreggpt::registration`) against Open3D
//! 0.19, in the same run and on the same inputs: normals + FPFH per cloud, and RANSAC on feature matches
//! per pair (matching included, as Open3D's `registration_ransac_based_on_feature_matching` does it).
//!
//! Inputs: redkitchen frames 0 and 20 at full resolution, back-projected (0.5–10 m) and voxelised at
//! 2.5 cm by ours (fragment-sized clouds). FPFH: normals r = 5 cm / 30 neighbours, FPFH r = 12.5 cm / 100
//! neighbours, on the same points. RANSAC: both get OUR FPFH of 5000 sampled points per cloud (same
//! points, same features), distance 5 cm, 3-point samples, edge-length 0.9 and distance checkers; once
//! with a fixed budget of 10,000 iterations (confidence 1: pure throughput) and once as the protocol runs
//! it (50,000 iterations, confidence 0.999). Peer: `benchmarks/peers/registration_peers.py DIR`.
//! Target: ours at least 2× faster than Open3D on FPFH and on RANSAC per pair.

use pointreggpt::geometry::{backproject, relative_pose, voxel_downsample, DepthRange, Point};
use pointreggpt::registration::evaluate::sample_indices;
use pointreggpt::registration::fpfh::fpfh;
use pointreggpt::registration::matching::{match_features, Features};
use pointreggpt::registration::metrics::rre_rte;
use pointreggpt::registration::normals::estimate_normals;
use pointreggpt::registration::ransac::{ransac, RansacConfig};
use pointreggpt::rng::Rng;
use pointreggpt::sources::{open_sequences, Layout};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{cpu_model, load_average, write_npy};

const SEQUENCE: &str = "7scenes-redkitchen";
const FRAMES: [usize; 2] = [0, 20];
const REPS: usize = 3;
const SAMPLES: usize = 5000;
const TARGET_RATIO: f64 = 2.0;

fn fail(message: &str) -> ! {
    eprintln!("registration bench: {message}");
    std::process::exit(1);
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

fn time<T>(reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut last = f();
    let mut ms = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        last = f();
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    (median(ms), last)
}

fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(|x| (x as f64).to_le_bytes()).collect()
}

fn main() {
    let load = load_average();
    let root = std::env::var("POINTREGGPT_REAL_DATA").ok().filter(|v| !v.is_empty()).map(PathBuf::from).unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/realdata"));
    let seq = open_sequences(&root.join(SEQUENCE), Layout::Auto).unwrap_or_else(|e| fail(&format!("{e} (set POINTREGGPT_REAL_DATA)"))).remove(0);
    let frames: Vec<_> = FRAMES.iter().map(|&f| seq.frames[f].load().unwrap_or_else(|e| fail(&e.to_string()))).collect();
    let clouds: Vec<Vec<Point>> = frames.iter().map(|f| voxel_downsample(&backproject(&f.depth, &f.intrinsics, DepthRange::OFFICIAL), 0.025)).collect();
    let t_gt = relative_pose(&frames[1].t_world_from_camera.unwrap(), &frames[0].t_world_from_camera.unwrap());

    // Normals and FPFH, ours.
    let mut rows: Vec<(String, f64, Option<f64>, String)> = Vec::new();
    let (mut normals, mut feats) = (Vec::new(), Vec::new());
    let (mut n_ms, mut f_ms) = (0.0, 0.0);
    for c in &clouds {
        let (ms, n) = time(REPS, || estimate_normals(c, 0.05, 30));
        n_ms += ms;
        let (ms2, f) = time(REPS, || fpfh(c, &n, 0.125, 100));
        f_ms += ms2;
        normals.push(n);
        feats.push(Features { dim: 33, data: f });
    }
    // Sampled points and their features, the same for both RANSACs.
    let rng = Rng::new(7);
    let idx: Vec<Vec<usize>> = clouds.iter().enumerate().map(|(k, c)| sample_indices(c.len(), SAMPLES, &mut rng.fork(k as u64))).collect();
    let pts: Vec<Vec<Point>> = clouds.iter().zip(&idx).map(|(c, i)| i.iter().map(|&k| c[k]).collect()).collect();
    let sel: Vec<Features> = feats.iter().zip(&idx).map(|(f, i)| f.select(i)).collect();

    let dir = tempfile::tempdir().unwrap();
    for (k, c) in clouds.iter().enumerate() {
        write_npy(&dir.path().join(format!("cloud{k}.npy")), "<f8", &[c.len(), 3], &f32_bytes(c.iter().flat_map(|p| [p.x, p.y, p.z])));
        write_npy(&dir.path().join(format!("sampled{k}.npy")), "<f8", &[pts[k].len(), 3], &f32_bytes(pts[k].iter().flat_map(|p| [p.x, p.y, p.z])));
        write_npy(&dir.path().join(format!("features{k}.npy")), "<f8", &[sel[k].len(), 33], &f32_bytes(sel[k].data.iter().copied()));
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benchmarks/peers/registration_peers.py");
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let peer = Command::new(&python).arg(&script).arg(dir.path()).arg(REPS.to_string()).output();
    let peer_ms = |key: &str| -> Option<(f64, String)> {
        let o = peer.as_ref().ok().filter(|o| o.status.success())?;
        String::from_utf8_lossy(&o.stdout).lines().find_map(|l| {
            let f: Vec<&str> = l.split('\t').collect();
            (f.first() == Some(&key)).then(|| (f[1].parse().unwrap_or(f64::NAN), f.get(2).unwrap_or(&"").to_string()))
        })
    };

    rows.push(("normals (2 clouds)".into(), n_ms, peer_ms("normals").map(|p| p.0), String::new()));
    rows.push(("FPFH (2 clouds)".into(), f_ms, peer_ms("fpfh").map(|p| p.0), String::new()));
    for (key, iters, conf) in [("ransac_fixed", 10_000usize, 1.0f64), ("ransac_protocol", 50_000, 0.999)] {
        let cfg = RansacConfig { max_iterations: iters, confidence: conf, seed: 3, ..RansacConfig::default() };
        let (ms, r) = time(REPS, || {
            let corr = match_features(&sel[0], &sel[1], false);
            ransac(&pts[0], &pts[1], &corr, &cfg)
        });
        let r = r.unwrap_or_else(|| fail("RANSAC found nothing"));
        let (rre, rte) = rre_rte(&t_gt, &r.t_target_from_source);
        let peer = peer_ms(key);
        rows.push((
            format!("RANSAC per pair, {iters} it, conf {conf}"),
            ms,
            peer.as_ref().map(|p| p.0),
            format!("ours: {} it, {} inliers, RRE {rre:.2} deg, RTE {:.3} m; Open3D: {}", r.iterations, r.inliers, rte, peer.map(|p| p.1).unwrap_or_default()),
        ));
    }

    println!("Machine: {}, load average {load} at start; rayon threads {}", cpu_model(), rayon::current_num_threads());
    println!("Clouds: frames {FRAMES:?} of {SEQUENCE}, full resolution, 2.5 cm voxels: {} and {} points; {SAMPLES} sampled per cloud for RANSAC", clouds[0].len(), clouds[1].len());
    match &peer {
        Ok(o) if o.status.success() => {}
        Ok(o) => println!("Open3D peer failed: {}", String::from_utf8_lossy(&o.stderr).lines().last().unwrap_or("")),
        Err(e) => println!("Open3D peer could not start ({python}: {e})"),
    }
    println!("\n{:<38} {:>10} {:>12} {:>10}  {}", "operation", "ours ms", "Open3D ms", "O3D/ours", "notes");
    for (name, ours, theirs, note) in &rows {
        let ratio = theirs.map(|t| t / ours);
        println!("{:<38} {:>10.1} {:>12} {:>10}  {}", name, ours, theirs.map(|t| format!("{t:.1}")).unwrap_or("n/a".into()), ratio.map(|r| format!("{r:.2}")).unwrap_or("n/a".into()), note);
    }
    println!();
    for (name, ours, theirs, _) in rows.iter().filter(|r| !r.0.starts_with("normals")) {
        match theirs {
            Some(t) => println!("Target (ours >= {TARGET_RATIO}x faster than Open3D) {name}: {:.2}x {}", t / ours, if t / ours >= TARGET_RATIO { "MET" } else { "MISSED" }),
            None => println!("Target {name}: n/a (Open3D not installed: scripts/install-bench-peers.sh)"),
        }
    }
}
