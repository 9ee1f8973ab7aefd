//! `build --device` (issue 50): the networks on the CPU unchanged bit for bit, a GPU asked for on a machine
//! without one refused before any work with a message naming the device, and the GPU Kubernetes template
//! valid and its pods' command refused here the same way.

use crate::support::{bin, python, synthetic_config};
use std::process::Command;

/// A small synthetic build that runs both networks: the correction U-Net on the condition and the output,
/// and the diffusion refiner (one step from push–pull).
fn network_config(dir: &std::path::Path) -> std::path::PathBuf {
    let models = format!("{}/models", env!("CARGO_MANIFEST_DIR"));
    let text = format!(
        "{}[correct.condition]\nmethod = \"unet\"\ncheckpoint = \"{models}/correction-tiny.safetensors\"\nthreshold = 0.5\n\
         [correct.output]\nmethod = \"unet\"\ncheckpoint = \"{models}/correction-tiny.safetensors\"\nthreshold = 0.5\n\
         [inpaint]\nmethod = \"diffusion\"\ncheckpoint = \"{models}/diffusion-tiny-holes.safetensors\"\nsteps = 1\neta = 0.0\nstart = \"push_pull\"\nstart_step = 0\n",
        synthetic_config(1, 20, 10, 2, 160, 120, 2)
    );
    let path = dir.join("networks.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn the_cpu_device_gives_the_rows_of_the_default_and_a_missing_gpu_is_refused_before_any_work() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let config = network_config(dir.path());
    let build = |out: &str, extra: &[&str]| {
        let o = bin().args(["--threads", "2", "build"]).arg(&config).arg("--out").arg(dir.path().join(out)).arg("--no-progress").args(extra).output().unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (ok, err) = build("default", &[]);
    assert!(ok, "{err}");
    let (ok, err) = build("cpu", &["--device", "cpu"]);
    assert!(ok, "{err}");
    let (a, b) = (crate::support::digests(dir.path().join("default")), crate::support::digests(dir.path().join("cpu")));
    assert_eq!(a.len(), 4);
    assert_eq!(a, b, "--device cpu builds the rows of the default, bit for bit");
    // No GPU here (a CPU libtorch): refused at once, naming the device; no dataset folder is made.
    assert_eq!(tch::Cuda::device_count(), 0, "this test expects a machine without CUDA");
    for (device, needle) in [("cuda", "CUDA device 0 is not available"), ("cuda:1", "CUDA device 1 is not available"), ("tpu", "unknown device `tpu`")] {
        let out = format!("refused-{}", device.replace(':', "-"));
        let (ok, err) = build(&out, &["--device", device]);
        assert!(!ok && err.contains("--device") && err.contains(needle), "{device}: {err}");
        assert!(!dir.path().join(&out).exists(), "{device}: a refused build must not create its dataset");
    }
}

#[test]
fn the_gpu_kubernetes_template_validates_and_its_command_is_refused_without_a_gpu() {
    let _timing = crate::support::timed();
    let file = format!("{}/pipelines/k8s-build-job-gpu.yaml", env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(python()).args(["-m", "kubernetes_validate", "--strict", "-k", "1.37.0", &file]).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success() && text.contains("passed for resource job/pointreggpt-build-gpu"), "{text}");
    // Each pod gets one GPU and puts the networks on it.
    let o = Command::new(python())
        .args(["-c", "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))", &file])
        .output()
        .unwrap();
    let job: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let container = &job["spec"]["template"]["spec"]["containers"][0];
    assert_eq!(container["resources"]["limits"]["nvidia.com/gpu"], 1);
    let command: Vec<String> = container["command"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    let at = command.iter().position(|a| a == "--device").expect("the command asks for a device");
    assert_eq!(command[at + 1], "cuda");
    // Run here (the binary for `pointreggpt`, no GPU): refused before reading the config or the bucket.
    let o = bin().args(&command[1..]).env("JOB_COMPLETION_INDEX", "0").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("CUDA device 0 is not available"), "{err}");
}
