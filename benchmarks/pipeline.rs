//! End-to-end benchmark of the build on real 640×480 frames: pairs per second and peak memory of the
//! `pointreggpt build` process on the classical path at about 1k and 10k work units (memory must stay
//! flat), then with the shipped networks in place (correction U-Net; correction U-Net + diffusion fill).
//!
//! Input: the 400 7-Scenes redkitchen frames of `$POINTREGGPT_REAL_DATA` (default ../shared/realdata),
//! with `samples_per_frame` 3 (1,200 units) and 25 (10,000 units); the network runs take 400 and 100
//! units. Run: `cargo bench --bench pipeline`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Peak resident memory (VmHWM) of a running process, in KiB, or None once it has exited.
fn vm_hwm_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status.lines().find(|l| l.starts_with("VmHWM:"))?.split_whitespace().nth(1)?.parse().ok()
}

struct Run {
    units: u64,
    wall: Duration,
    peak_mib: f64,
    summary: String,
}

fn run(bin: &Path, config: &Path, out: &Path, samples: u32, units: u64) -> Run {
    let _ = std::fs::remove_dir_all(out);
    let t0 = Instant::now();
    let mut child = Command::new(bin)
        .args(["build"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .arg("--no-progress")
        .args(["--set", &format!("samples_per_frame={samples}")])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start pointreggpt");
    let mut peak = 0;
    while child.try_wait().expect("wait").is_none() {
        if let Some(k) = vm_hwm_kib(child.id()) {
            peak = peak.max(k);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let wall = t0.elapsed();
    let output = child.wait_with_output().expect("output");
    assert!(output.status.success(), "build failed");
    let summary = String::from_utf8_lossy(&output.stdout).to_string();
    Run { units, wall, peak_mib: peak as f64 / 1024.0, summary }
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let data = std::env::var_os("POINTREGGPT_REAL_DATA").map(PathBuf::from).unwrap_or_else(|| root.join("../shared/realdata"));
    let frames = data.join("7scenes-redkitchen");
    assert!(frames.is_dir(), "missing {}: set POINTREGGPT_REAL_DATA", frames.display());
    let bin = root.join("target/release/pointreggpt");
    assert!(bin.is_file(), "build the release binary first (cargo build --release)");
    let work = std::env::temp_dir().join("pointreggpt-bench-pipeline");
    std::fs::create_dir_all(&work).unwrap();
    let config = work.join("bench.toml");
    let base = format!(
        "seed = 1\nshard_size = 200\n[source]\nkind = \"directory\"\npath = \"{}\"\n[output]\ndepth_maps = true\n",
        frames.display()
    );
    std::fs::write(&config, &base).unwrap();
    let models = root.join("models");
    let unet = format!(
        "[correct.condition]\nmethod = \"unet\"\ncheckpoint = \"{}\"\nthreshold = 0.99\n",
        models.join("correction-tiny.safetensors").display()
    );
    let unet_config = work.join("bench-unet.toml");
    std::fs::write(&unet_config, format!("{base}{unet}")).unwrap();
    let diffusion_config = work.join("bench-diffusion.toml");
    std::fs::write(
        &diffusion_config,
        format!(
            "{base}{unet}[select]\nevery = 4\n[inpaint]\nmethod = \"diffusion\"\ncheckpoint = \"{}\"\nsteps = 10\nstart = \"push_pull\"\nstart_step = 50\n",
            models.join("diffusion-tiny.safetensors").display()
        ),
    )
    .unwrap();

    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string()))
        .unwrap_or_default();
    println!("machine: {cpu}, {} cores", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    println!("input: 400 real 7-Scenes frames (640x480 16-bit PNG), classical path (min-pool, push-pull), depth maps stored\n");
    println!("{:>8} {:>9} {:>10} {:>14}", "units", "wall s", "pairs/s", "peak RSS MiB");
    let mut runs = Vec::new();
    for samples in [3u32, 25] {
        let r = run(&bin, &config, &work.join(format!("ds-{samples}")), samples, 400 * samples as u64);
        println!("{:>8} {:>9.1} {:>10.1} {:>14.0}", r.units, r.wall.as_secs_f64(), r.units as f64 / r.wall.as_secs_f64(), r.peak_mib);
        runs.push(r);
    }
    let (small, large) = (&runs[0], &runs[1]);
    let rate = large.units as f64 / large.wall.as_secs_f64();
    println!("\ntarget >= 50 pairs/s on 2 cores: {:.1} -> {}", rate, if rate >= 50.0 { "met" } else { "NOT met" });
    let flat = large.peak_mib < 1024.0 && small.peak_mib < 1024.0;
    println!(
        "target peak RSS < 1 GiB at both sizes, flat: {:.0} MiB vs {:.0} MiB (ratio {:.2}) -> {}",
        small.peak_mib,
        large.peak_mib,
        large.peak_mib / small.peak_mib,
        if flat { "met" } else { "NOT met" }
    );
    println!("\nstage breakdown of the 10k run:\n{}", large.summary.lines().skip(4).take(10).collect::<Vec<_>>().join("\n"));

    println!("\nwith the shipped networks (models/*-tiny.safetensors, one libtorch thread per worker):");
    println!("{:<58} {:>6} {:>8} {:>9} {:>13}", "path", "units", "wall s", "pairs/s", "vs classical");
    let classical = small.units as f64 / small.wall.as_secs_f64();
    println!("{:<58} {:>6} {:>8.1} {:>9.1} {:>13}", "classical (min-pool, push-pull), from above", small.units, small.wall.as_secs_f64(), classical, "1.00x");
    let network_runs = [
        ("correction U-Net @0.99 + push-pull", &unet_config, 400u64),
        ("correction U-Net @0.99 + diffusion 10 steps (push-pull start 50)", &diffusion_config, 100),
    ];
    for (name, cfg, units) in network_runs {
        let r = run(&bin, cfg, &work.join("ds-net"), 1, units);
        let rate = r.units as f64 / r.wall.as_secs_f64();
        println!("{:<58} {:>6} {:>8.1} {:>9.2} {:>12.3}x", name, r.units, r.wall.as_secs_f64(), rate, rate / classical);
    }
    let _ = std::fs::remove_dir_all(&work);
}
