//! `cargo bench --bench networks`: CPU inference of the two networks (`pointreggpt::nn`) against PyTorch
//! running the same architecture with the same weights, in the same run, then our tiny presets alone.
//!
//! 1. The diffusion denoiser, paper preset (≈ 38.4 M parameters), one forward at 256×256, batch 4.
//! 2. The correction network, paper preset with DepthAugment (≈ 34.1 M), one forward at 256×256, batch 1.
//! 3. Ours only: the tiny presets' forwards (batch 1), the tiny diffusion inpainter at 25 DDIM steps
//!    and the fill of `pipelines/demo.toml` at its own settings (seconds per pair).
//!
//! Both sides run under no-grad with the same libtorch intra-op thread count (`THREADS`, or
//! `POINTREGGPT_BENCH_THREADS`). The Rust side times ours, writes each network's variables with
//! `nn::checkpoint::write_safetensors` (the authors' state-dict keys), its inputs and our output, and runs
//! `benchmarks/peers/networks_peers.py DIR`: a plain-PyTorch mirror of the U-Net that loads those weights
//! with strict key matching, prints its parameter count, its median time and the largest difference
//! between its output and ours (the check that both are the same network). Without PyTorch
//! (`scripts/install-network-peers.sh` installs it) the table shows ours with the reason the peer is
//! unavailable.

use pointreggpt::diffusion::checkpoint::load_denoiser;
use pointreggpt::diffusion::{ddnm_sample, Problem, SamplerOptions, Schedule};
use pointreggpt::nn::checkpoint::write_safetensors;
use pointreggpt::nn::correction::{CorrectionNet, CorrectionNetConfig};
use pointreggpt::nn::denoiser::{Denoiser, DenoiserConfig};
use pointreggpt::nn::unet::parameter_count;
use pointreggpt::nn::{load_correction, Preset};
use pointreggpt::rng::Rng;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Instant;
use tch::{nn, Device, Kind, Tensor};

#[path = "common/mod.rs"]
mod common;
use common::{cpu_model, load_average, median_ms};

/// libtorch intra-op threads of both sides (the machine has 2 cores).
const THREADS: i32 = 2;
const SIZE: i64 = 256;
const DENOISER_BATCH: i64 = 4;
const CORRECTION_BATCH: i64 = 1;
/// Paper presets: a forward takes seconds, so few runs (both sides use the same counts).
const WARMUP: usize = 1;
const REPS: usize = 3;
/// Tiny presets: milliseconds per forward.
const TINY_WARMUP: usize = 2;
const TINY_REPS: usize = 10;
const DDIM_STEPS: usize = 25;
const DDIM_REPS: usize = 3;
/// The official sampler's steps, for the extrapolated per-pair cost of the paper denoiser.
const OFFICIAL_STEPS: usize = 250;
/// Largest |PyTorch − ours| still called the same network (float32, same libtorch kernels).
const SAME_TOLERANCE: f64 = 1e-3;
const SEED: i64 = 7;

fn main() {
    let load = load_average();
    let threads = threads();
    tch::set_num_threads(threads);
    tch::manual_seed(SEED);
    let tmp = tempfile::tempdir().unwrap_or_else(|e| fail(&format!("creating a temp dir: {e}")));
    let dir = tmp.path();

    let mut nets = [denoiser_paper(dir), correction_paper(dir)];
    write_params(dir, threads, &nets);
    let mut report = Peer::default();
    let mut peer = PeerSession::start(dir, threads, &mut report);
    let paper: Vec<PaperRun> = nets.iter_mut().map(|n| time_paper(n, &mut peer, &mut report)).collect();
    if let Some(p) = peer {
        p.quit();
    }
    drop(nets);
    let tiny = run_tiny();

    print_header(&load, threads, &report);
    print_paper(&paper, &report);
    print_check(&paper, &report);
    print_tiny(&tiny, &paper[0]);
}

// ------------------------------------------------------------------------------------------------
// Helpers

fn fail(message: &str) -> ! {
    eprintln!("networks bench: {message}");
    std::process::exit(1);
}

fn threads() -> i32 {
    match std::env::var("POINTREGGPT_BENCH_THREADS") {
        Ok(v) if !v.trim().is_empty() => v
            .trim()
            .parse()
            .ok()
            .filter(|n| *n > 0)
            .unwrap_or_else(|| fail(&format!("POINTREGGPT_BENCH_THREADS={v} is not a positive integer"))),
        _ => THREADS,
    }
}

fn sorted_variables(vs: &nn::VarStore) -> Vec<(String, Tensor)> {
    let mut v: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

fn save(path: &Path, tensors: &[(String, Tensor)]) {
    write_safetensors(path, tensors, &BTreeMap::new()).unwrap_or_else(|e| fail(&e.to_string()));
}

/// `batch` depth maps in [0, 1] (metres / 10): a tilted plane with a box in front and ~15 % holes.
fn depth_input(batch: i64) -> Tensor {
    let n = SIZE as usize;
    let mut rng = Rng::new(SEED as u64);
    let mut v = Vec::with_capacity(batch as usize * n * n);
    for b in 0..batch as usize {
        for r in 0..n {
            for c in 0..n {
                let mut z = 0.15 + 0.2 * r as f64 / n as f64 + 0.01 * b as f64;
                if (64..160).contains(&r) && (80..176).contains(&c) {
                    z = 0.1;
                }
                v.push(if rng.uniform() < 0.15 { 0.0 } else { z as f32 });
            }
        }
    }
    Tensor::from_slice(&v).view([batch, 1, SIZE, SIZE])
}

/// Working-resolution intrinsics `[fx, fy, cx, cy]` of 7-Scenes / 3DMatch cameras (585 px at 640×480).
fn intrinsics(batch: i64) -> Vec<f32> {
    (0..batch)
        .flat_map(|b| [585.0 * 341.0 / 640.0 + b as f32, 585.0 * 256.0 / 480.0 + b as f32, 128.5, 128.0])
        .collect()
}

// ------------------------------------------------------------------------------------------------
// Paper presets: ours, the files the peer reads, then interleaved runs of both

/// One network timed against the peer.
struct PaperNet {
    key: &'static str,
    title: &'static str,
    input: String,
    params: i64,
    /// The network's description for params.json.
    spec: serde_json::Value,
    /// One forward of ours under no_grad (owns the network, its variables and the inputs).
    forward: Box<dyn FnMut() -> Tensor>,
}

/// Medians of one paper network.
struct PaperRun {
    key: &'static str,
    title: &'static str,
    input: String,
    params: i64,
    ms: f64,
    peer_ms: Option<f64>,
}

/// Our paper denoiser, its first forward (our warm-up, whose output the peer is compared with) and the
/// files for the peer.
fn denoiser_paper(dir: &Path) -> PaperNet {
    let config = DenoiserConfig::from_preset(Preset::Paper);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = Denoiser::new(&vs.root(), &config).unwrap_or_else(|e| fail(&e.to_string()));
    let b = DENOISER_BATCH;
    let x = Tensor::randn([b, 1, SIZE, SIZE], (Kind::Float, Device::Cpu));
    let t = Tensor::from_slice(&[999i64, 600, 250, 10][..b as usize]);
    let k = Tensor::from_slice(&intrinsics(b)).view([b, 4]);
    let out = tch::no_grad(|| net.forward(&x, &t, &k));
    save(&dir.join("denoiser.weights.safetensors"), &sorted_variables(&vs));
    let io = [("x", &x), ("t", &t.to_kind(Kind::Float)), ("k", &k), ("out", &out)];
    save(&dir.join("denoiser.io.safetensors"), &io.map(|(n, t)| (n.to_string(), t.shallow_clone())));
    PaperNet {
        key: "denoiser",
        title: "diffusion denoiser, paper",
        input: format!("{b}x1x{SIZE}x{SIZE}"),
        params: parameter_count(&vs),
        spec: serde_json::json!({
            "kind": "denoiser",
            "unet": config.unet,
            "intrinsics_scale": config.intrinsics_scale,
        }),
        forward: Box::new(move || {
            let _vs = &vs;
            tch::no_grad(|| net.forward(&x, &t, &k))
        }),
    }
}

/// Our paper correction network (with DepthAugment), as [`denoiser_paper`].
fn correction_paper(dir: &Path) -> PaperNet {
    let config = CorrectionNetConfig::from_preset(Preset::Paper, true);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = CorrectionNet::new(&vs.root(), &config).unwrap_or_else(|e| fail(&e.to_string()));
    let b = CORRECTION_BATCH;
    let depth = depth_input(b);
    let out = tch::no_grad(|| net.forward(&depth));
    save(&dir.join("correction.weights.safetensors"), &sorted_variables(&vs));
    let io = [("depth", &depth), ("out", &out)];
    save(&dir.join("correction.io.safetensors"), &io.map(|(n, t)| (n.to_string(), t.shallow_clone())));
    PaperNet {
        key: "correction",
        title: "correction net, paper",
        input: format!("{b}x1x{SIZE}x{SIZE}"),
        params: parameter_count(&vs),
        spec: serde_json::json!({ "kind": "correction", "augment": config.augment, "unet": config.unet }),
        forward: Box::new(move || {
            let _vs = &vs;
            tch::no_grad(|| net.forward(&depth))
        }),
    }
}

fn write_params(dir: &Path, threads: i32, nets: &[PaperNet]) {
    let specs: serde_json::Map<String, serde_json::Value> =
        nets.iter().map(|n| (n.key.to_string(), n.spec.clone())).collect();
    let params = serde_json::json!({ "threads": threads, "nets": specs });
    let path = dir.join("params.json");
    std::fs::write(&path, params.to_string()).unwrap_or_else(|e| fail(&format!("writing {}: {e}", path.display())));
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let mid = v.len() / 2;
    Some(if v.len() % 2 == 0 { (v[mid - 1] + v[mid]) / 2.0 } else { v[mid] })
}

/// Times one network: the peer's warm-up (its first output is the one compared with ours; ours ran in
/// the setup), then `REPS` rounds of one forward of ours and one of the peer, so both see the same load.
fn time_paper(net: &mut PaperNet, peer: &mut Option<PeerSession>, report: &mut Peer) -> PaperRun {
    let mut ours = Vec::with_capacity(REPS);
    let mut theirs = Vec::with_capacity(REPS);
    let mut alive = report.params.contains_key(net.key);
    for _ in 0..WARMUP.saturating_sub(1) {
        let _ = (net.forward)();
    }
    for _ in 0..WARMUP {
        alive = alive && peer.as_mut().is_some_and(|p| p.time(net.key, report).is_some());
    }
    for _ in 0..REPS {
        let start = Instant::now();
        let out = std::hint::black_box((net.forward)());
        ours.push(start.elapsed().as_secs_f64() * 1e3);
        drop(out);
        if alive {
            match peer.as_mut().and_then(|p| p.time(net.key, report)) {
                Some(ms) => theirs.push(ms),
                None => alive = false,
            }
        }
    }
    if alive {
        if let Some(p) = peer.as_mut() {
            p.diff(net.key, report);
        }
    }
    PaperRun {
        key: net.key,
        title: net.title,
        input: net.input.clone(),
        params: net.params,
        ms: median(ours).expect("REPS > 0"),
        // A partial series (the peer died midway) is not a median of the same runs: left out.
        peer_ms: if theirs.len() == REPS { median(theirs) } else { None },
    }
}

// ------------------------------------------------------------------------------------------------
// The PyTorch peer (benchmarks/peers/networks_peers.py), driven one command at a time

/// What the peer reported.
#[derive(Default)]
struct Peer {
    info: Vec<(String, String)>,
    params: BTreeMap<String, i64>,
    /// net -> (max |peer − ours|, max |ours|).
    diff: BTreeMap<String, (f64, f64)>,
    errors: BTreeMap<String, String>,
    /// Why the peer did not run (at all, or from some point on).
    unavailable: Option<String>,
}

impl Peer {
    /// Why `net` has no peer time.
    fn missing(&self, net: &str) -> String {
        self.errors
            .get(net)
            .or(self.unavailable.as_ref())
            .cloned()
            .unwrap_or_else(|| "the peer gave no time for every run".into())
    }

    /// Records one line of the peer's output; returns its fields.
    fn record(&mut self, line: &str) -> Vec<String> {
        let f: Vec<String> = line.split('\t').map(str::to_string).collect();
        match f.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
            ["info", name, value] => self.info.push((name.to_string(), value.to_string())),
            ["unavailable", reason] => self.unavailable = Some(reason.to_string()),
            ["error", net, message] => {
                self.errors.insert(net.to_string(), message.to_string());
            }
            ["params", net, n] => {
                if let Ok(n) = n.parse() {
                    self.params.insert(net.to_string(), n);
                }
            }
            ["diff", net, d, m] => {
                if let (Ok(d), Ok(m)) = (d.parse(), m.parse()) {
                    self.diff.insert(net.to_string(), (d, m));
                }
            }
            _ => {}
        }
        f
    }
}

struct PeerSession {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl PeerSession {
    /// Starts the script on the files in `dir` and reads its report up to `ready`. None (with the reason
    /// in `report.unavailable`) when Python, torch or the script is not there.
    fn start(dir: &Path, threads: i32, report: &mut Peer) -> Option<PeerSession> {
        let python = std::env::var("PYTHON").ok().filter(|p| !p.is_empty()).unwrap_or_else(|| "python3".into());
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benchmarks/peers/networks_peers.py");
        let spawned = Command::new(&python)
            .arg(&script)
            .arg(dir)
            .env("OMP_NUM_THREADS", threads.to_string())
            .env("MKL_NUM_THREADS", threads.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn();
        let mut child = match spawned {
            Ok(c) => c,
            Err(e) => {
                report.unavailable = Some(format!("{python} did not start: {e}"));
                return None;
            }
        };
        let stdin = child.stdin.take().expect("piped stdin");
        let stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut session = PeerSession { child, stdin, stdout };
        loop {
            match session.read_line(report) {
                Some(f) if f[0] == "ready" => return Some(session),
                Some(_) => {}
                None => {
                    let status = session.child.wait().map(|s| s.to_string()).unwrap_or_default();
                    report.unavailable.get_or_insert(format!("the peer script exited before it was ready ({status})"));
                    return None;
                }
            }
        }
    }

    /// The next line (recorded in `report`), or None at the end of the peer's output.
    fn read_line(&mut self, report: &mut Peer) -> Option<Vec<String>> {
        let mut line = String::new();
        match self.stdout.read_line(&mut line) {
            Ok(n) if n > 0 => Some(report.record(line.trim_end_matches(['\n', '\r']))),
            _ => None,
        }
    }

    /// Sends `command net` and returns the fields of its answer (`time`/`diff`/`error` for `net`).
    fn request(&mut self, command: &str, net: &str, report: &mut Peer) -> Option<Vec<String>> {
        if writeln!(self.stdin, "{command} {net}").and_then(|_| self.stdin.flush()).is_err() {
            report.unavailable.get_or_insert("the peer script stopped reading its commands".into());
            return None;
        }
        loop {
            match self.read_line(report) {
                Some(f) if f.len() >= 2 && f[1] == net && ["time", "diff", "error"].contains(&f[0].as_str()) => {
                    return Some(f)
                }
                Some(_) => {}
                None => {
                    let status = self.child.wait().map(|s| s.to_string()).unwrap_or_default();
                    report.unavailable.get_or_insert(format!("the peer script exited ({status})"));
                    return None;
                }
            }
        }
    }

    /// One timed forward of the peer, in ms.
    fn time(&mut self, net: &str, report: &mut Peer) -> Option<f64> {
        let f = self.request("time", net, report)?;
        if f[0] == "time" {
            f.get(2).and_then(|ms| ms.parse().ok())
        } else {
            None
        }
    }

    fn diff(&mut self, net: &str, report: &mut Peer) {
        self.request("diff", net, report);
    }

    fn quit(mut self) {
        let _ = writeln!(self.stdin, "quit").and_then(|_| self.stdin.flush());
        drop(self.stdin);
        let _ = self.child.wait();
    }
}

// ------------------------------------------------------------------------------------------------
// Tiny presets (ours only)

struct TinyRun {
    denoiser_ms: f64,
    /// One forward of four views.
    denoiser_b4_ms: f64,
    denoiser_params: i64,
    denoiser_weights: String,
    correction_ms: f64,
    correction_params: i64,
    correction_weights: String,
    /// Seconds per pair of `ddnm_sample` at `DDIM_STEPS`, batch 1.
    ddim_s: f64,
    known_fraction: f64,
    /// Seconds per pair of the `[inpaint]` of `pipelines/demo.toml` (push–pull and sampling), or
    /// why it could not run.
    demo_fill: std::result::Result<(f64, String), String>,
}

fn model_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models").join(name)
}

/// The shipped tiny denoiser when there is one, else an untrained tiny network.
fn tiny_denoiser() -> (nn::VarStore, Denoiser, String) {
    let path = model_path("diffusion-tiny.safetensors");
    if path.is_file() {
        match load_denoiser(&path, Device::Cpu) {
            Ok((vs, net, _)) if net.config.preset == Some(Preset::Tiny) => {
                return (vs, net, "models/diffusion-tiny.safetensors".into())
            }
            Ok(_) => eprintln!("networks bench: {} is not the tiny preset; timing an untrained one", path.display()),
            Err(e) => eprintln!("networks bench: {e}; timing an untrained tiny denoiser"),
        }
    }
    let vs = nn::VarStore::new(Device::Cpu);
    let net =
        Denoiser::new(&vs.root(), &DenoiserConfig::from_preset(Preset::Tiny)).unwrap_or_else(|e| fail(&e.to_string()));
    (vs, net, "untrained (no models/diffusion-tiny.safetensors)".into())
}

/// The shipped tiny correction network when there is one, else an untrained one.
fn tiny_correction() -> (nn::VarStore, CorrectionNet, String) {
    let path = model_path("correction-tiny.safetensors");
    if path.is_file() {
        match load_correction(&path, Device::Cpu) {
            Ok((vs, net, _)) if net.config.preset == Some(Preset::Tiny) => {
                return (vs, net, "models/correction-tiny.safetensors".into())
            }
            Ok(_) => eprintln!("networks bench: {} is not the tiny preset; timing an untrained one", path.display()),
            Err(e) => eprintln!("networks bench: {e}; timing an untrained tiny correction network"),
        }
    }
    let vs = nn::VarStore::new(Device::Cpu);
    let config = CorrectionNetConfig::from_preset(Preset::Tiny, true);
    let net = CorrectionNet::new(&vs.root(), &config).unwrap_or_else(|e| fail(&e.to_string()));
    (vs, net, "untrained (no models/correction-tiny.safetensors)".into())
}

fn run_tiny() -> TinyRun {
    let (dvs, denoiser, denoiser_weights) = tiny_denoiser();
    let x = Tensor::randn([1, 1, SIZE, SIZE], (Kind::Float, Device::Cpu));
    let t = Tensor::from_slice(&[500i64]);
    let k = Tensor::from_slice(&intrinsics(1)).view([1, 4]);
    let (denoiser_ms, _) = median_ms(TINY_WARMUP, TINY_REPS, || tch::no_grad(|| denoiser.forward(&x, &t, &k)));
    // `[inpaint] batch = 4`: four views per forward pass.
    let (x4, t4, k4) = (x.repeat([4, 1, 1, 1]), t.repeat([4]), k.repeat([4, 1]));
    let (denoiser_b4_ms, _) = median_ms(TINY_WARMUP, TINY_REPS, || tch::no_grad(|| denoiser.forward(&x4, &t4, &k4)));

    let (cvs, correction, correction_weights) = tiny_correction();
    let depth = depth_input(1);
    let (correction_ms, _) = median_ms(TINY_WARMUP, TINY_REPS, || tch::no_grad(|| correction.forward(&depth)));

    // One inpainting problem: the normalised depth map with a re-projection-like mask (~65 % known).
    let n = SIZE as usize;
    let d: Vec<f32> = Vec::try_from(depth.flatten(0, -1)).expect("float depth");
    let mut rng = Rng::new(11);
    let known: Vec<bool> = (0..n * n).map(|i| d[i] > 0.0 && (i % n) < 3 * n / 4 && rng.uniform() < 0.85).collect();
    let y: Vec<f32> = d.iter().map(|v| v * 2.0 - 1.0).collect();
    let schedule = Schedule::official();
    // The official sampler (η = 1, from pure noise) with fewer steps.
    let opts = SamplerOptions { steps: DDIM_STEPS, ..SamplerOptions::OFFICIAL };
    let problem = [Problem { y: &y, known: &known, intrinsics: [311.0, 312.0, 128.5, 128.0], seed: 3, init: None }];
    let (ddim_ms, _) =
        median_ms(1, DDIM_REPS, || ddnm_sample(&denoiser, &schedule, &opts, n, n, &problem, Device::Cpu));
    let metres: Vec<f32> = d.iter().map(|v| v * 10.0).collect();
    let demo_fill = demo_fill_seconds(metres, &known);
    TinyRun {
        denoiser_ms,
        denoiser_b4_ms,
        denoiser_params: parameter_count(&dvs),
        denoiser_weights,
        correction_ms,
        correction_params: parameter_count(&cvs),
        correction_weights,
        ddim_s: ddim_ms / 1e3,
        known_fraction: known.iter().filter(|k| **k).count() as f64 / known.len() as f64,
        demo_fill,
    }
}

/// Seconds per pair of the demo fill on one view, and its settings.
fn demo_fill_seconds(depth: Vec<f32>, known: &[bool]) -> std::result::Result<(f64, String), String> {
    use pointreggpt::geometry::{DepthMap, Intrinsics};
    use pointreggpt::inpainting::{InpaintConfig, InpaintContext};
    // Its model paths resolve against its folder.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/demo.toml");
    let config: pointreggpt::pipeline::BuildConfig = pointreggpt::pipeline::load::load_toml(&path, &[]).map_err(|e| e.to_string())?;
    let desc = match &config.inpaint {
        InpaintConfig::Diffusion(c) => format!(
            "{}, {} steps from {:?} at step {}, eta {}",
            c.checkpoint, c.steps, c.start, c.start_step, c.eta
        ),
        other => format!("{other:?}"),
    };
    config.validate().map_err(|e| e.to_string())?;
    let inpainter = config.inpaint.build().map_err(|e| e.to_string())?;
    let n = SIZE as u32;
    let map = DepthMap::new(n, n, depth).map_err(|e| e.to_string())?;
    let ctx = InpaintContext { intrinsics: Intrinsics::new(311.0, 312.0, 128.5, 128.0, n, n).map_err(|e| e.to_string())?, seed: 3, t_target_from_source: nalgebra::Isometry3::identity() };
    let (ms, _) = median_ms(1, DDIM_REPS, || inpainter.inpaint(&map, known, &ctx));
    Ok((ms / 1e3, desc))
}

// ------------------------------------------------------------------------------------------------
// Report



fn libtorch_version() -> String {
    match std::env::var("LIBTORCH") {
        Ok(dir) if !dir.is_empty() => std::fs::read_to_string(Path::new(&dir).join("build-version"))
            .map(|v| format!("libtorch {} ({dir})", v.trim()))
            .unwrap_or_else(|_| format!("libtorch at {dir}")),
        _ => "libtorch (see .cargo/config.toml)".into(),
    }
}

fn print_header(load: &str, threads: i32, peer: &Peer) {
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0);
    println!();
    println!("== Networks benchmark: ours (tch, {}) vs PyTorch, CPU inference ==", libtorch_version());
    println!(
        "machine: {} | {cores} cores | intra-op threads: ours {} (set {threads}), PyTorch set {threads} | load average at start: {load}",
        cpu_model(),
        tch::get_num_threads(),
    );
    if load.parse::<f64>().is_ok_and(|l| l > 0.5) {
        println!("WARNING: load average {load} at start: other processes share the cores, so timings are noisy");
    }
    let versions: Vec<String> = peer.info.iter().map(|(n, v)| format!("{n} {v}")).collect();
    match &peer.unavailable {
        Some(reason) => println!("peer:    unavailable: {reason}"),
        None => println!("peer:    {}", if versions.is_empty() { "none ran".into() } else { versions.join(", ") }),
    }
    println!(
        "timing:  one forward under no_grad, float32, random weights (PyTorch's default init), the same inputs; \
         median of {REPS} runs after {WARMUP} warm-up, ours and PyTorch's runs interleaved (tiny presets: {TINY_REPS} after {TINY_WARMUP})"
    );
    println!("         ratio = PyTorch ms / ours ms (> 1: ours faster)");
    println!(
        "note:    both sides run libtorch's own CPU kernels (ours is assembled from the same torch 2.13 wheel), so the \
         ratio measures per-call overhead and noise; expect ~1"
    );
}

fn print_paper(runs: &[PaperRun], peer: &Peer) {
    println!();
    println!("{:<28} {:<13} {:>11}  {:>13}  {:>10}", "network", "input", "ours (ms)", "PyTorch (ms)", "peer/ours");
    println!("{}", "-".repeat(82));
    for r in runs {
        let (p, ratio) = match r.peer_ms {
            Some(p) => (format!("{p:.1}"), format!("{:.2}x", p / r.ms)),
            None => ("n/a".into(), String::new()),
        };
        println!("{:<28} {:<13} {:>11.1}  {p:>13}  {ratio:>10}", r.title, r.input, r.ms);
    }
    for r in runs.iter().filter(|r| r.peer_ms.is_none()) {
        println!("  {}: peer unavailable: {}", r.title, peer.missing(r.key));
    }
}

fn print_check(runs: &[PaperRun], peer: &Peer) {
    println!();
    println!("Same network? our variables loaded into the PyTorch mirror by key (strict), outputs on the same input:");
    println!(
        "{:<28} {:>12}  {:>14}  {:>18}  {:>10}  verdict",
        "network", "params ours", "params PyTorch", "max|PyTorch-ours|", "max|ours|"
    );
    println!("{}", "-".repeat(100));
    for r in runs {
        let theirs = peer.params.get(r.key).map_or("n/a".into(), |n| n.to_string());
        let (diff, scale) = match peer.diff.get(r.key) {
            Some((d, m)) => (format!("{d:.2e}"), format!("{m:.2e}")),
            None => ("n/a".into(), "n/a".into()),
        };
        let verdict = match (peer.params.get(r.key), peer.diff.get(r.key)) {
            (Some(n), Some((d, _))) if *n == r.params && *d <= SAME_TOLERANCE => "same".to_string(),
            (Some(n), _) if *n != r.params => "DIFFERENT parameter counts".into(),
            (_, Some(_)) => format!("OUTPUTS DIFFER (> {SAME_TOLERANCE:.0e})"),
            _ => "not checked".into(),
        };
        println!("{:<28} {:>12}  {theirs:>14}  {diff:>18}  {scale:>10}  {verdict}", r.title, r.params);
    }
}

fn print_tiny(t: &TinyRun, denoiser: &PaperRun) {
    println!();
    println!("Ours only (no peer), batch 1, {SIZE}x{SIZE}:");
    println!("{:<44} {:>10}  {:>12}  weights", "what", "params", "time");
    println!("{}", "-".repeat(110));
    println!(
        "{:<44} {:>10}  {:>9.2} ms  {}",
        "tiny denoiser, one forward", t.denoiser_params, t.denoiser_ms, t.denoiser_weights
    );
    println!(
        "{:<44} {:>10}  {:>9.2} ms  per view ({:.2} ms for 4; batch 1 / batch 4 per view = {:.2}x)",
        "tiny denoiser, one forward at batch 4",
        t.denoiser_params,
        t.denoiser_b4_ms / 4.0,
        t.denoiser_b4_ms,
        t.denoiser_ms / (t.denoiser_b4_ms / 4.0)
    );
    println!(
        "{:<44} {:>10}  {:>9.2} ms  {}",
        "tiny correction net, one forward", t.correction_params, t.correction_ms, t.correction_weights
    );
    println!(
        "{:<44} {:>10}  {:>10.2} s  {} (per pair = {:.0} ms per step; {:.0}% known pixels, median of {DDIM_REPS} after 1 warm-up)",
        format!("tiny diffusion inpainter, {DDIM_STEPS} DDIM steps"),
        t.denoiser_params,
        t.ddim_s,
        t.denoiser_weights,
        t.ddim_s * 1e3 / DDIM_STEPS as f64,
        100.0 * t.known_fraction
    );
    match &t.demo_fill {
        Ok((secs, desc)) => println!(
            "{:<44} {:>10}  {:>10.2} s  {desc} (per pair, median of {DDIM_REPS} after 1 warm-up)",
            "demo.toml fill", t.denoiser_params, secs
        ),
        Err(e) => println!("{:<44} {:>10}  {:>12}  {e}", "demo.toml fill", "-", "n/a"),
    }
    let per_image_s = denoiser.ms / DENOISER_BATCH as f64 / 1e3;
    println!(
        "Derived, not measured: the paper denoiser at {OFFICIAL_STEPS} DDIM steps would take ~{:.0} s per pair on this CPU \
         ({:.2} s per image-forward at batch {DENOISER_BATCH} x {OFFICIAL_STEPS}); at {DDIM_STEPS} steps ~{:.0} s.",
        per_image_s * OFFICIAL_STEPS as f64,
        per_image_s,
        per_image_s * DDIM_STEPS as f64
    );
}
