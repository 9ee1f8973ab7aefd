//! Checkpoint files: safetensors written and read through the `safetensors` crate (a round trip read back
//! by tch and by the crate, corrupt and truncated files, a save interrupted before its rename), the shipped
//! checkpoints, and the authors' checkpoints saved the way their trainers save them
//! (`tests/python/official_checkpoints.py`), converted by `scripts/convert-official.py` and loaded by our
//! loaders weight for weight.
//!
//! The conversion needs PyTorch and safetensors in Python (`scripts/install-test-deps.sh`, which `make test`
//! runs): those tests fail, not skip, without them.

use crate::support;

use pointreggpt::diffusion::checkpoint::{group, load_denoiser};
use pointreggpt::nn::checkpoint::{read_header, read_meta, read_tensors, write_safetensors};
use pointreggpt::nn::{load_correction, Preset, UnetConfig};
use pointreggpt::atomic::TempName;
use safetensors::tensor::{Dtype, SafeTensors};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;
use crate::support::python;
use tch::{Device, Kind, Tensor};

fn meta(pairs: &[(&str, &str)]) -> BTreeMap<String, String> {
    pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

fn le_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

#[test]
fn a_round_trip_is_read_back_by_tch_and_by_the_crate() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.safetensors");
    let a = [1.5f32, -2.0, 3.25, 0.0, 7.0, f32::MIN_POSITIVE];
    // Saved as f32 whatever they are: an f64 tensor, a transposed (non-contiguous) view, a scalar.
    let tensors = vec![
        ("a.b".to_string(), Tensor::from_slice(&a).view([2, 3])),
        ("t".to_string(), Tensor::from_slice(&a).view([2, 3]).tr()),
        ("d".to_string(), Tensor::from_slice(&[0.1f64, 1e-3])),
        ("s".to_string(), Tensor::from(-4.5f32)),
    ];
    let info = meta(&[("pointreggpt", "{\"x\": 1}"), ("k", "v")]);
    write_safetensors(&p, &tensors, &info).unwrap();
    let expected: BTreeMap<&str, (Vec<usize>, Vec<u8>)> = BTreeMap::from([
        ("a.b", (vec![2, 3], le_bytes(&a))),
        ("t", (vec![3, 2], le_bytes(&[a[0], a[3], a[1], a[4], a[2], a[5]]))),
        ("d", (vec![2], le_bytes(&[0.1f64 as f32, 1e-3f64 as f32]))),
        ("s", (vec![], le_bytes(&[-4.5]))),
    ]);
    // The crate, on the whole file.
    let bytes = std::fs::read(&p).unwrap();
    let (_, header) = SafeTensors::read_metadata(&bytes).unwrap();
    assert_eq!(header.metadata().clone().unwrap(), info.clone().into_iter().collect::<HashMap<_, _>>());
    let file = SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(file.len(), expected.len());
    for (name, (shape, data)) in &expected {
        let view = file.tensor(name).unwrap();
        assert_eq!((view.dtype(), view.shape(), view.data()), (Dtype::F32, &shape[..], &data[..]), "{name}");
    }
    // tch's reader.
    for (name, t) in Tensor::read_safetensors(&p).unwrap() {
        let (shape, data) = &expected[name.as_str()];
        let mut got = vec![0u8; data.len()];
        t.copy_data_u8(&mut got, t.numel());
        assert_eq!((t.size().iter().map(|&d| d as usize).collect::<Vec<_>>(), got), (shape.clone(), data.clone()));
    }
    // Ours: the header alone, and the tensors.
    let (m, shapes) = read_header(&p).unwrap();
    assert_eq!(m, info);
    assert_eq!(shapes.len(), 4);
    assert_eq!(shapes["t"], vec![3, 2]);
    for (name, t) in read_tensors(&p).unwrap() {
        assert!(t.equal(&tensors.iter().find(|(n, _)| *n == name).unwrap().1.to_kind(Kind::Float)), "{name}");
    }
    // No metadata: no `__metadata__` entry at all, as the authors' converted files.
    write_safetensors(&p, &tensors[..1], &BTreeMap::new()).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    assert!(SafeTensors::read_metadata(&bytes).unwrap().1.metadata().is_none());
    assert!(!String::from_utf8_lossy(&bytes).contains("__metadata__"));
    // Only the checkpoint is in the folder: no temporary file is left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    let twice = [0, 0].map(|i| (tensors[i].0.clone(), tensors[i].1.shallow_clone()));
    assert!(write_safetensors(&p, &twice, &info).unwrap_err().to_string().contains("`a.b` given twice"));
}

#[test]
fn corrupt_and_truncated_files_give_errors_naming_the_file() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.safetensors");
    let t = Tensor::from_slice(&[1f32, 2.0, 3.0, 4.0]);
    write_safetensors(&good, &[("w".into(), t)], &meta(&[("k", "v")])).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let header_len = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut bad_offsets = br#"{"w":{"dtype":"F32","shape":[2],"data_offsets":[0,4]}}"#.to_vec();
    bad_offsets.resize(56, b' ');
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("short", b"abc".to_vec(), "shorter than 8 bytes"),
        ("cut-data", bytes[..bytes.len() - 4].to_vec(), "truncated"),
        ("cut-header", bytes[..header_len - 3].to_vec(), "truncated"),
        ("huge-header", [&u64::MAX.to_le_bytes()[..], &bytes[8..]].concat(), "header length"),
        ("not-json", [&4u64.to_le_bytes()[..], b"abcd"].concat(), "not a JSON object"),
        ("offsets", [&56u64.to_le_bytes()[..], &bad_offsets, &[0u8; 4]].concat(), "tensor `w`"),
    ];
    for (name, content, why) in cases {
        let p = dir.path().join(format!("{name}.safetensors"));
        std::fs::write(&p, &content).unwrap();
        // tch's reader refuses them too: they are really broken.
        assert!(Tensor::read_safetensors(&p).is_err(), "{name}");
        for err in [read_header(&p).map(|_| ()), read_tensors(&p).map(|_| ()), read_meta(&p).map(|_| ())] {
            let err = err.unwrap_err().to_string();
            assert!(err.contains(&p.display().to_string()), "{name}: {err}");
            assert!(err.contains("not a valid safetensors file"), "{name}: {err}");
        }
        let err = read_header(&p).unwrap_err().to_string();
        assert!(err.contains(why), "{name}: {err}");
    }
}

#[test]
fn a_save_interrupted_before_the_rename_leaves_the_previous_checkpoint_loadable() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("latest.safetensors");
    let save = |step: &str, w: &[f32], path: &Path| {
        write_safetensors(path, &[("w".into(), Tensor::from_slice(w))], &meta(&[("step", step)])).unwrap()
    };
    save("1", &[1.0, 2.0, 3.0], &p);
    let before = std::fs::read(&p).unwrap();
    // The save of step 2 died after writing half its temporary file (in the checkpoint's folder, under
    // the name write_atomic gives it) and before the rename: its process no longer runs.
    let other = tempfile::tempdir().unwrap();
    save("2", &[4.0, 5.0, 6.0], &other.path().join("x.safetensors"));
    let step2 = std::fs::read(other.path().join("x.safetensors")).unwrap();
    let dead = TempName { pid: 4_194_304 + 17, ..TempName::new("latest.safetensors") };
    let crashed = dir.path().join(dead.file_name());
    std::fs::write(&crashed, &step2[..step2.len() / 2]).unwrap();
    // A save of this process still running (another thread's) is not stale.
    let running = dir.path().join(TempName::new("latest.safetensors").file_name());
    std::fs::write(&running, b"partial").unwrap();
    assert_eq!(std::fs::read(&p).unwrap(), before, "the target is untouched");
    assert_eq!(read_header(&p).unwrap().0["step"], "1");
    let w = &read_tensors(&p).unwrap()[0].1;
    assert_eq!(Vec::<f32>::try_from(w).unwrap(), vec![1.0, 2.0, 3.0]);
    // The next save replaces the checkpoint and removes the dead process's temporary file only.
    save("3", &[7.0, 8.0, 9.0], &p);
    assert_eq!(read_header(&p).unwrap().0["step"], "3");
    assert!(!crashed.exists() && running.exists());
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn run_python(args: &[&Path]) -> Output {
    support::python_command().args(args).output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The fixture's folder, written afresh once per run of this test binary.
fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let ok = support::python_command().args(["-c", "import torch, safetensors"]).status().is_ok_and(|s| s.success());
        assert!(ok, "{} cannot import torch and safetensors, which these tests need: run scripts/install-test-deps.sh", python());
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("convert-fixture");
        let _ = std::fs::remove_dir_all(&dir);
        let o = run_python(&[&repo("tests/python/official_checkpoints.py"), &dir]);
        assert!(o.status.success(), "fixture failed: {}", stderr(&o));
        dir
    })
}

fn convert(kind: &str, src: &Path, dst: &Path) -> Output {
    support::python_command().arg(repo("scripts/convert-official.py")).arg(kind).arg(src).arg(dst).output().unwrap()
}

/// The fixture's original weights under `prefix`, read by tch (not by our reader).
fn originals(prefix: &str) -> HashMap<String, Tensor> {
    let all: HashMap<String, Tensor> =
        Tensor::read_safetensors(fixture().join("originals.safetensors")).unwrap().into_iter().collect();
    group(&all, prefix)
}

/// Every weight of `loaded` equals the original of the same name, and the two name sets are equal.
fn assert_same_weights(what: &str, loaded: &HashMap<String, Tensor>, original: &HashMap<String, Tensor>) {
    let names = |m: &HashMap<String, Tensor>| m.keys().cloned().collect::<BTreeSet<_>>();
    assert_eq!(names(loaded), names(original), "{what}: names");
    assert!(loaded.len() > 100, "{what}: {} tensors", loaded.len());
    for (name, t) in loaded {
        assert!(t.equal(&original[name]), "{what}: `{name}` differs from the original");
    }
}

#[test]
fn the_authors_checkpoints_convert_and_load_weight_for_weight() {
    let _timing = crate::support::timed();
    let dir = fixture();
    let out = tempfile::tempdir().unwrap();

    let correction = out.path().join("models/correction-official.safetensors");
    let o = convert("correction", &dir.join("model-best.pt"), &correction);
    assert!(o.status.success(), "{}", stderr(&o));
    let (vs, _net, meta) = load_correction(&correction, Device::Cpu).unwrap();
    // The tiny widths with the authors' attention (our tiny correction preset has none).
    let with_attention = UnetConfig { attention: true, ..Preset::Tiny.correction_unet(true) };
    assert_eq!(meta.net.unet, with_attention, "widths inferred from the shapes");
    assert_same_weights("correction", &vs.variables(), &originals("correction."));

    let diffusion = out.path().join("models/diffusion-official.safetensors");
    let o = convert("diffusion", &dir.join("model-1.pt"), &diffusion);
    assert!(o.status.success(), "{}", stderr(&o));
    let (vs, _net, meta) = load_denoiser(&diffusion, Device::Cpu).unwrap();
    assert_eq!(meta.net.unet, UnetConfig { attention: true, ..Preset::Tiny.diffusion_unet() });
    assert_eq!(meta.net.intrinsics_scale, 1.0, "the authors feed raw intrinsics");
    assert_same_weights("diffusion (EMA, what sampling uses)", &vs.variables(), &originals("ema."));
    // The online network is there too, once: the EMA's `online_model` (the same tensors) is not written
    // again, and the bookkeeping buffers (`ema.step`, `ema.initted`) are not floats.
    let file: HashMap<String, Tensor> = read_tensors(&diffusion).unwrap().into_iter().collect();
    assert_same_weights("diffusion (online)", &group(&file, "model.model."), &originals("online."));
    assert!(file.contains_key("model.betas") && file.contains_key("ema.ema_model.betas"));
    assert!(!file.keys().any(|k| k.starts_with("ema.online_model.") || k == "ema.step" || k == "ema.initted"));
}

#[test]
fn the_converter_refuses_the_wrong_kind_and_files_without_the_trainers_keys() {
    let _timing = crate::support::timed();
    let dir = fixture();
    let out = tempfile::tempdir().unwrap();
    let text = out.path().join("notes.pt");
    std::fs::write(&text, "not a checkpoint").unwrap();
    let cases: [(&str, PathBuf, &str); 5] = [
        ("correction", dir.join("model-1.pt"), "convert it with `diffusion`"),
        ("diffusion", dir.join("model-best.pt"), "convert it with `correction`"),
        ("diffusion", dir.join("not-a-trainer.pt"), "has no `model` entry"),
        ("correction", text.clone(), "torch.load cannot read it"),
        ("correction", out.path().join("missing.pt"), "no such file"),
    ];
    for (kind, src, why) in cases {
        let dst = out.path().join("x.safetensors");
        let o = convert(kind, &src, &dst);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{kind} {}: {err}", src.display());
        assert!(err.contains(&src.display().to_string()) && err.contains(why), "{kind} {}: {err}", src.display());
        assert!(!dst.exists());
    }
    let o = convert("unet", &dir.join("model-1.pt"), &out.path().join("x.safetensors"));
    assert!(!o.status.success() && stderr(&o).contains("invalid choice"), "{}", stderr(&o));
    assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 1, "no output or temporary file is left");
}

#[test]
fn the_shipped_checkpoints_read_the_same_through_ours_and_tch() {
    let _timing = crate::support::timed();
    let mut n = 0;
    for entry in std::fs::read_dir(repo("models")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("safetensors") {
            continue;
        }
        n += 1;
        let theirs: HashMap<String, Tensor> = Tensor::read_safetensors(&path).unwrap().into_iter().collect();
        let ours: HashMap<String, Tensor> = read_tensors(&path).unwrap().into_iter().collect();
        assert_same_weights(&path.display().to_string(), &ours, &theirs);
        let (_, shapes) = read_header(&path).unwrap();
        assert!(theirs.iter().all(|(k, t)| shapes[k] == t.size()), "{}", path.display());
        let name = path.file_name().unwrap().to_string_lossy();
        if name.starts_with("correction") {
            load_correction(&path, Device::Cpu).unwrap();
        } else {
            load_denoiser(&path, Device::Cpu).unwrap();
        }
    }
    assert!(n >= 4, "{n} shipped checkpoints");
}
