//! `cargo bench --bench geometry`: times the geometry core on a real 7-Scenes frame against the Python peers (numpy, numba, Open3D, scipy, pykdtree) in the same run, and prints the table.
//!
//! Every implementation gets the same inputs: the Rust side loads the frames, times ours, writes the
//! inputs as `.npy` files and runs `benchmarks/peers/geometry_peers.py`, which prints one
//! tab-separated line per peer (`op, peer, ms, result`). See benchmarks/README.md.

use nalgebra::Isometry3;
use pointreggpt::geometry::{
    backproject, overlap, pose_to_rows, project_zbuffer, relative_pose, voxel_downsample, DepthMap, DepthRange,
    Intrinsics, Point,
};
use pointreggpt::sources::depth_png::read_depth_png;
use pointreggpt::sources::text::{read_intrinsics_file, read_pose_file};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

#[path = "common/mod.rs"]
mod common;
use common::{cpu_model, load_average, write_npy};

const SEQUENCE: &str = "7scenes-redkitchen";
const FRAME: u32 = 0;
const OTHER_FRAME: u32 = 20;
const RANGE: DepthRange = DepthRange::OFFICIAL;
const VOXEL: f32 = 0.025;
const RADIUS: f32 = 0.0375;
const WARMUP: usize = 3;
const REPS: usize = 20;
const TARGET_RATIO: f64 = 2.0;

/// One timed operation: its key in the peers' output, the peers expected, and the issue's target.
struct Op {
    key: &'static str,
    title: &'static str,
    peers: &'static [&'static str],
    /// The fastest peer the issue measured earlier on this machine: (name, ms).
    issue: Option<(&'static str, f64)>,
}

const OPS: [Op; 4] = [
    Op {
        key: "backproject",
        title: "depth -> points",
        peers: &["numpy", "open3d legacy create_from_depth_image", "open3d tensor create_from_depth_image"],
        issue: None,
    },
    Op {
        key: "zbuffer",
        title: "z-buffer re-projection",
        peers: &["numpy minimum.at", "numpy argsort+assign", "numba njit", "open3d tensor project_to_depth_image"],
        issue: Some(("numba", 4.3)),
    },
    Op {
        key: "voxel",
        title: "voxel downsample 2.5 cm",
        peers: &["numpy unique", "open3d legacy voxel_down_sample", "open3d tensor voxel_down_sample"],
        issue: Some(("open3d", 16.6)),
    },
    Op {
        key: "overlap",
        title: "overlap r=3.75 cm",
        peers: &[
            "scipy cKDTree (workers=-1)",
            "pykdtree",
            "open3d compute_point_cloud_distance",
            "open3d tensor NNS hybrid",
            "open3d KDTreeFlann loop",
        ],
        issue: Some(("pykdtree", 6.4)),
    },
];

/// The inputs every implementation works on.
struct Inputs {
    depth: DepthMap,
    k: Intrinsics,
    /// Frame `FRAME` back-projected: input of the z-buffer and the voxel grid.
    points: Vec<Point>,
    /// `t_other_from_frame`: the z-buffer's target camera and the overlap's alignment.
    pose: Isometry3<f64>,
    src: Vec<Point>,
    tgt: Vec<Point>,
}

/// One measurement: median milliseconds (None when the peer did not run) and a result summary.
#[derive(Clone, Debug)]
struct Timing {
    ms: Option<f64>,
    result: String,
}

fn main() {
    let load = load_average();
    let dir = data_dir();
    let inputs = load_inputs(&dir);
    let ours: Vec<Timing> = OPS.iter().map(|op| time_ours(op.key, &inputs)).collect();
    let peers = run_peers(&inputs);
    print_header(&inputs, &peers, &load);
    print_timings(&ours, &peers);
    print_targets(&ours, &peers);
    print_sanity(&ours, &peers);
}

// ------------------------------------------------------------------------------------------------
// Inputs

fn data_dir() -> PathBuf {
    let root = match std::env::var("POINTREGGPT_REAL_DATA") {
        Ok(v) if !v.trim().is_empty() => PathBuf::from(v),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/realdata"),
    };
    let dir = root.join(SEQUENCE);
    if !dir.join("camera-intrinsics.txt").is_file() {
        fail(&format!(
            "real data not found: {} has no camera-intrinsics.txt.\n\
             Set POINTREGGPT_REAL_DATA to the folder holding {SEQUENCE}/ (default: ../shared/realdata beside the crate).",
            dir.display()
        ));
    }
    dir
}

fn fail(message: &str) -> ! {
    eprintln!("geometry bench: {message}");
    std::process::exit(1);
}

fn load_depth(dir: &Path, frame: u32) -> DepthMap {
    let path = dir.join(format!("frame-{frame:06}.depth.png"));
    let raw = read_depth_png(&path).unwrap_or_else(|e| fail(&e.to_string()));
    DepthMap::from_raw(raw.width, raw.height, &raw.data, 1000.0, &[0, 65535]).unwrap_or_else(|e| fail(&e.to_string()))
}

fn load_pose(dir: &Path, frame: u32) -> Isometry3<f64> {
    read_pose_file(&dir.join(format!("frame-{frame:06}.pose.txt"))).unwrap_or_else(|e| fail(&e.to_string()))
}

fn load_inputs(dir: &Path) -> Inputs {
    let depth = load_depth(dir, FRAME);
    let other = load_depth(dir, OTHER_FRAME);
    let k = read_intrinsics_file(&dir.join("camera-intrinsics.txt"), depth.width(), depth.height())
        .unwrap_or_else(|e| fail(&e.to_string()));
    let pose = relative_pose(&load_pose(dir, OTHER_FRAME), &load_pose(dir, FRAME));
    let points = backproject(&depth, &k, RANGE);
    let src = voxel_downsample(&points, VOXEL);
    let tgt = voxel_downsample(&backproject(&other, &k, RANGE), VOXEL);
    Inputs { depth, k, points, pose, src, tgt }
}

// ------------------------------------------------------------------------------------------------
// Ours

/// Median wall time in ms of `f` over `REPS` runs after `WARMUP` runs, and its last result.
fn median_ms<T>(mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = None;
    for _ in 0..WARMUP {
        out = Some(black_box(f()));
    }
    let mut times = Vec::with_capacity(REPS);
    for _ in 0..REPS {
        let start = Instant::now();
        out = Some(black_box(f()));
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let mid = times.len() / 2;
    let median = if times.len() % 2 == 0 { (times[mid - 1] + times[mid]) / 2.0 } else { times[mid] };
    (median, out.expect("at least one run"))
}

/// Times our implementation of `op`; the result string uses the peers' format so the two compare.
fn time_ours(op: &str, x: &Inputs) -> Timing {
    let (ms, result) = match op {
        "backproject" => {
            let (ms, p) = median_ms(|| backproject(&x.depth, &x.k, RANGE));
            (ms, format!("points={}", p.len()))
        }
        "zbuffer" => {
            let (ms, p) = median_ms(|| project_zbuffer(&x.points, &x.pose, &x.k, false));
            (ms, format!("known={}", p.known.iter().filter(|k| **k).count()))
        }
        "voxel" => {
            let (ms, v) = median_ms(|| voxel_downsample(&x.points, VOXEL));
            (ms, format!("voxels={}", v.len()))
        }
        "overlap" => {
            let (ms, o) = median_ms(|| overlap(&x.src, &x.tgt, &x.pose, RADIUS));
            (ms, format!("src={:.6} tgt={:.6}", o.source, o.target))
        }
        other => unreachable!("unknown op {other}"),
    };
    Timing { ms: Some(ms), result }
}

// ------------------------------------------------------------------------------------------------
// Peers: .npy hand-off and the Python script's tab-separated output

/// What the peers' script reported.
struct Peers {
    /// (op, peer) -> timing.
    timings: Vec<(String, String, Timing)>,
    /// `info` lines: (name, value).
    info: Vec<(String, String)>,
    /// Why no peer ran at all, if so.
    failure: Option<String>,
}

impl Peers {
    fn get(&self, op: &str, peer: &str) -> Timing {
        self.timings.iter().find(|(o, p, _)| o == op && p == peer).map(|(_, _, t)| t.clone()).unwrap_or_else(|| {
            Timing {
                ms: None,
                result: if self.failure.is_some() { "peers did not run".into() } else { "not installed".into() },
            }
        })
    }
}


fn f32_bytes(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(f32::to_le_bytes).collect()
}

fn f64_bytes(v: impl IntoIterator<Item = f64>) -> Vec<u8> {
    v.into_iter().flat_map(f64::to_le_bytes).collect()
}

fn write_points(path: &Path, points: &[Point]) {
    write_npy(path, "<f4", &[points.len(), 3], &f32_bytes(points.iter().flat_map(|p| [p.x, p.y, p.z])));
}

fn write_inputs(dir: &Path, x: &Inputs) {
    let (w, h) = (x.depth.width() as usize, x.depth.height() as usize);
    write_npy(&dir.join("depth.npy"), "<f4", &[h, w], &f32_bytes(x.depth.data().iter().copied()));
    write_npy(&dir.join("intrinsics.npy"), "<f8", &[4], &f64_bytes([x.k.fx, x.k.fy, x.k.cx, x.k.cy]));
    write_points(&dir.join("points.npy"), &x.points);
    write_points(&dir.join("src.npy"), &x.src);
    write_points(&dir.join("tgt.npy"), &x.tgt);
    for name in ["pose_reproj.npy", "pose_overlap.npy"] {
        write_npy(&dir.join(name), "<f8", &[4, 4], &f64_bytes(pose_to_rows(&x.pose)));
    }
    let params = [RANGE.near as f64, RANGE.far as f64, VOXEL as f64, RADIUS as f64, REPS as f64];
    write_npy(&dir.join("params.npy"), "<f8", &[5], &f64_bytes(params));
}

/// Runs the peers' script on the same inputs; a missing interpreter or package is reported, not fatal.
fn run_peers(x: &Inputs) -> Peers {
    let tmp = tempfile::tempdir().unwrap_or_else(|e| fail(&format!("creating a temp dir: {e}")));
    write_inputs(tmp.path(), x);
    let python = std::env::var("PYTHON").ok().filter(|p| !p.is_empty()).unwrap_or_else(|| "python3".into());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benchmarks/peers/geometry_peers.py");
    let output = Command::new(&python).arg(&script).arg(tmp.path()).stderr(Stdio::inherit()).output();
    match output {
        Err(e) => Peers { timings: vec![], info: vec![], failure: Some(format!("{python} did not start: {e}")) },
        Ok(out) => {
            let mut peers = parse_peers(&String::from_utf8_lossy(&out.stdout));
            if !out.status.success() {
                peers.failure = Some(format!("peers script failed ({})", out.status));
            }
            peers
        }
    }
}

/// Parses `op\tpeer\tms\tresult` lines (ms may be `n/a`) and `info\tname\tvalue` lines.
fn parse_peers(stdout: &str) -> Peers {
    let mut peers = Peers { timings: vec![], info: vec![], failure: None };
    for line in stdout.lines() {
        let f: Vec<&str> = line.split('\t').collect();
        match f.as_slice() {
            ["info", name, value] => peers.info.push((name.to_string(), value.to_string())),
            [op, peer, ms, result] => {
                let timing = Timing { ms: ms.parse().ok(), result: result.to_string() };
                peers.timings.push((op.to_string(), peer.to_string(), timing));
            }
            _ => {}
        }
    }
    peers
}

// ------------------------------------------------------------------------------------------------
// Report



fn print_header(x: &Inputs, peers: &Peers, load: &str) {
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0);
    println!();
    println!("== Geometry benchmark: ours vs Python peers ==");
    println!(
        "machine: {} | {cores} cores | ours: {} rayon threads | load average at start: {}",
        cpu_model(),
        rayon::current_num_threads(),
        load
    );
    if load.parse::<f64>().is_ok_and(|l| l > 0.5) {
        println!("WARNING: load average {load} at start: other processes share the cores, so timings are noisy");
    }
    let versions: Vec<String> = peers.info.iter().map(|(n, v)| format!("{n} {v}")).collect();
    println!("peers:   {}", if versions.is_empty() { "none ran".to_string() } else { versions.join(", ") });
    if let Some(f) = &peers.failure {
        println!("         ({f})");
    }
    println!(
        "input:   {SEQUENCE} frame-{FRAME:06} {}x{}, depth {}-{} m -> {} points; overlap: frame-{FRAME:06} {} vs frame-{OTHER_FRAME:06} {} voxelised points",
        x.depth.width(),
        x.depth.height(),
        RANGE.near,
        RANGE.far,
        x.points.len(),
        x.src.len(),
        x.tgt.len()
    );
    println!("timing:  median of {REPS} runs after {WARMUP} warm-ups (peers: same, fewer for slow ones; inputs converted beforehand)");
}

fn ms_cell(ms: Option<f64>) -> String {
    ms.map(|m| format!("{m:.3}")).unwrap_or_else(|| "n/a".into())
}

fn print_timings(ours: &[Timing], peers: &Peers) {
    println!();
    println!("{:<24} {:>10}  {:<38} {:>10}  {:>10}", "operation", "ours (ms)", "peer", "peer (ms)", "peer/ours");
    println!("{}", "-".repeat(98));
    for (op, our) in OPS.iter().zip(ours) {
        for (i, name) in op.peers.iter().enumerate() {
            let (title, ours_ms) = if i == 0 { (op.title, ms_cell(our.ms)) } else { ("", String::new()) };
            let t = peers.get(op.key, name);
            let (ms, ratio) = match (t.ms, our.ms) {
                (Some(p), Some(o)) => (ms_cell(Some(p)), format!("{:.2}x", p / o)),
                _ => (format!("n/a ({})", t.result), String::new()),
            };
            println!("{title:<24} {ours_ms:>10}  {name:<38} {ms:>10}  {ratio:>10}");
        }
    }
}

fn fastest_peer<'a>(op: &'a Op, peers: &Peers) -> Option<(&'a str, f64)> {
    op.peers
        .iter()
        .filter_map(|name| peers.get(op.key, name).ms.map(|ms| (*name, ms)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

fn verdict(ratio: f64) -> &'static str {
    if ratio >= TARGET_RATIO {
        "MET"
    } else {
        "MISSED"
    }
}

fn print_targets(ours: &[Timing], peers: &Peers) {
    println!();
    println!("Target: ours >= {TARGET_RATIO}x faster than the fastest peer (ratio = fastest peer ms / ours ms)");
    for (op, our) in OPS.iter().zip(ours) {
        let o = our.ms.expect("ours always runs");
        let now = match fastest_peer(op, peers) {
            Some((name, ms)) => format!("now: {name} {ms:.3} ms -> {:.2}x {}", ms / o, verdict(ms / o)),
            None => "now: no peer ran".into(),
        };
        let issue = match op.issue {
            Some((name, ms)) => {
                format!(" | issue's earlier figure: {name} {ms} ms -> {:.2}x {}", ms / o, verdict(ms / o))
            }
            None => " | (no issue figure)".into(),
        };
        println!("  {:<24} ours {o:.3} ms | {now}{issue}", op.title);
    }
}

/// "yes" when two results are equal; for counts (`name=N`) that differ, the peer's difference.
fn agreement(ours: &str, peer: &str) -> String {
    if ours == peer {
        return "yes".into();
    }
    let count = |s: &str| s.split_once('=').and_then(|(_, n)| n.parse::<i64>().ok());
    match (count(ours), count(peer)) {
        (Some(a), Some(b)) => format!("differs ({:+}, {:+.2}%)", b - a, (b - a) as f64 * 100.0 / a.max(1) as f64),
        _ => "differs".into(),
    }
}

fn print_sanity(ours: &[Timing], peers: &Peers) {
    println!();
    println!("Sanity: results on the same inputs (Open3D's voxel grid origin and pixel rounding differ from ours)");
    println!("{:<24} {:<38} {:<30} {:<30} same?", "operation", "peer", "ours", "peer");
    println!("{}", "-".repeat(130));
    for (op, our) in OPS.iter().zip(ours) {
        for name in op.peers {
            let t = peers.get(op.key, name);
            let (value, same) = match t.ms {
                Some(_) => (t.result.clone(), agreement(&our.result, &t.result)),
                None => ("n/a".to_string(), String::new()),
            };
            println!("{:<24} {name:<38} {:<30} {value:<30} {same}", op.title, our.result);
        }
    }
}
