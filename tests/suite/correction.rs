//! The depth-correction network: DepthAugment, the U-Net's size and official key layout, training,
//! checkpoints, the `Corrector` wrapper, the CLI, and the shipped checkpoint against the handcrafted
//! filters on held-out synthetic scenes.

use crate::support;

use pointreggpt::correction::{CorrectionConfig, Corrector, UnetCorrector};
use pointreggpt::geometry::DepthMap;
use pointreggpt::labels::{run_labels, LabelsConfig};
use pointreggpt::nn::checkpoint::{infer_official_config, save_official_layout};
use pointreggpt::nn::unet::parameter_count;
use pointreggpt::nn::*;
use pointreggpt::pipeline::BuildOptions;
use pointreggpt::training::correction::data::LabelSet;
use pointreggpt::training::correction::evaluate::{evaluate_net, handcrafted_rows, THRESHOLDS};
use pointreggpt::training::correction::train::{train_correction, TrainOptions};
use pointreggpt::rng::Rng;
use pointreggpt::runtime::CancelToken;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use tch::{nn, Device, Tensor};

/// The shipped default checkpoint.
const SHIPPED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/correction-tiny.safetensors");

/// A label config of one synthetic scene fused in windows of 30 frames.
fn labels_config(first_seed: u64, scenes: u32, frames: usize, samples: u32, size: u32) -> LabelsConfig {
    toml::from_str(&format!(
        "seed = 3\nsamples_per_window = {samples}\nshard_size = 4\ntau_gt = 0.05\n\
         [source]\nkind = \"synthetic\"\nscenes = {scenes}\nfirst_seed = {first_seed}\n[source.synthetic]\nframes = {frames}\n\
         [window]\nframes = 30\nstride = 30\n[tsdf]\nvoxel_size_m = 0.01\ntruncation_m = 0.04\nmax_depth_m = 6.0\n\
         [clouds]\nsparse_voxel = 0.025\n[working]\nsize = {size}\n"
    ))
    .unwrap()
}

fn make_labels(config: &LabelsConfig, out: &Path) {
    let opts = BuildOptions { strict: true, ..BuildOptions::into_folder(out.to_path_buf()) };
    run_labels(config, &opts, &CancelToken::new()).unwrap();
}

/// A small fixed label set (2 windows x 4 samples of 64x64), made once per test binary.
fn small_labels() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep().join("labels-small");
        make_labels(&labels_config(40, 1, 60, 4, 64), &dir);
        dir
    })
}

fn tiny_net(augment: bool, seed: i64) -> (nn::VarStore, CorrectionNet) {
    tch::manual_seed(seed);
    let vs = nn::VarStore::new(Device::Cpu);
    let net = CorrectionNet::new(&vs.root(), &CorrectionNetConfig::from_preset(Preset::Tiny, augment)).unwrap();
    (vs, net)
}

fn random_depth(b: i64, h: i64, w: i64, hole_rate: f64, seed: u64) -> Tensor {
    let mut r = Rng::new(seed);
    let v: Vec<f32> =
        (0..b * h * w).map(|_| if r.uniform() < hole_rate { 0.0 } else { r.uniform_range(0.05, 0.6) as f32 }).collect();
    Tensor::from_slice(&v).view([b, 1, h, w])
}

#[test]
fn depth_augment_matches_a_brute_force_reference_on_maps_with_holes() {
    let _timing = crate::support::timed();
    let (b, h, w) = (3i64, 21i64, 17i64);
    let d = random_depth(b, h, w, 0.5, 1);
    // Large holes too: a 6x6 empty block, where the official fallback gives 0.
    let d = d.copy();
    let _ = d.narrow(2, 4, 6).narrow(3, 5, 6).fill_(0.0);
    let got = depth_augment(&d);
    assert_eq!(got.size(), vec![b, 3, h, w]);
    let dv: Vec<f32> = Vec::try_from(d.flatten(0, -1)).unwrap();
    let gv: Vec<f32> = Vec::try_from(got.flatten(0, -1)).unwrap();
    let plane = (h * w) as usize;
    let mut fallbacks = 0;
    for bi in 0..b as usize {
        for y in 0..h {
            for x in 0..w {
                let mut m = f32::INFINITY;
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (yy, xx) = (y + dy, x + dx);
                        if yy >= 0 && xx >= 0 && yy < h && xx < w {
                            let z = dv[bi * plane + (yy * w + xx) as usize];
                            if z > 0.0 {
                                m = m.min(z);
                            }
                        }
                    }
                }
                if m.is_infinite() {
                    m = 0.0;
                    fallbacks += 1;
                }
                let i = (y * w + x) as usize;
                let z = dv[bi * plane + i];
                assert_eq!(gv[bi * 3 * plane + i], z);
                assert_eq!(gv[bi * 3 * plane + plane + i], m, "batch {bi} pixel ({x}, {y})");
                assert_eq!(gv[bi * 3 * plane + 2 * plane + i], m - z);
            }
        }
    }
    assert!(fallbacks >= 16, "the empty block exercises the fallback ({fallbacks})");
}

/// The authors' `MaskUnet` / `Unet` state-dict keys and shapes, written from the reference's description
/// (§4.1, §5.1), independently of our module code.
fn official_keys(
    dim: i64,
    mults: &[i64],
    in_ch: i64,
    cond: Option<i64>,
    final_seq: bool,
) -> BTreeMap<String, Vec<i64>> {
    let mut k = BTreeMap::new();
    let mut add = |n: String, s: &[i64]| {
        k.insert(n, s.to_vec());
    };
    fn resnet(add: &mut dyn FnMut(String, &[i64]), p: &str, ci: i64, co: i64, cond: Option<i64>) {
        if let Some(c) = cond {
            add(format!("{p}.mlp.1.weight"), &[2 * co, c]);
            add(format!("{p}.mlp.1.bias"), &[2 * co]);
        }
        for (b, i) in [("block1", ci), ("block2", co)] {
            add(format!("{p}.{b}.proj.weight"), &[co, i, 3, 3]);
            add(format!("{p}.{b}.proj.bias"), &[co]);
            add(format!("{p}.{b}.norm.weight"), &[co]);
            add(format!("{p}.{b}.norm.bias"), &[co]);
        }
        if ci != co {
            add(format!("{p}.res_conv.weight"), &[co, ci, 1, 1]);
            add(format!("{p}.res_conv.bias"), &[co]);
        }
    }
    fn attention(add: &mut dyn FnMut(String, &[i64]), p: &str, d: i64, linear: bool) {
        add(format!("{p}.fn.norm.g"), &[1, d, 1, 1]);
        add(format!("{p}.fn.fn.to_qkv.weight"), &[384, d, 1, 1]);
        let out = if linear { format!("{p}.fn.fn.to_out.0") } else { format!("{p}.fn.fn.to_out") };
        add(format!("{out}.weight"), &[d, 128, 1, 1]);
        add(format!("{out}.bias"), &[d]);
        if linear {
            add(format!("{p}.fn.fn.to_out.1.g"), &[1, d, 1, 1]);
        }
    }
    let dims: Vec<i64> = std::iter::once(dim).chain(mults.iter().map(|m| dim * m)).collect();
    let pairs: Vec<(i64, i64)> = dims.windows(2).map(|w| (w[0], w[1])).collect();
    let last = pairs.len() - 1;
    add("init_conv.weight".into(), &[dim, in_ch, 7, 7]);
    add("init_conv.bias".into(), &[dim]);
    for (i, &(ci, co)) in pairs.iter().enumerate() {
        resnet(&mut add, &format!("downs.{i}.0"), ci, ci, cond);
        resnet(&mut add, &format!("downs.{i}.1"), ci, ci, cond);
        attention(&mut add, &format!("downs.{i}.2"), ci, true);
        add(format!("downs.{i}.3.weight"), &[co, ci, if i == last { 3 } else { 4 }, if i == last { 3 } else { 4 }]);
        add(format!("downs.{i}.3.bias"), &[co]);
    }
    let mid = *dims.last().unwrap();
    resnet(&mut add, "mid_block1", mid, mid, cond);
    attention(&mut add, "mid_attn", mid, false);
    resnet(&mut add, "mid_block2", mid, mid, cond);
    for (i, &(ci, co)) in pairs.iter().rev().enumerate() {
        resnet(&mut add, &format!("ups.{i}.0"), co + ci, co, cond);
        resnet(&mut add, &format!("ups.{i}.1"), co + ci, co, cond);
        attention(&mut add, &format!("ups.{i}.2"), co, true);
        let up = if i == last { format!("ups.{i}.3") } else { format!("ups.{i}.3.1") };
        add(format!("{up}.weight"), &[ci, co, 3, 3]);
        add(format!("{up}.bias"), &[ci]);
    }
    resnet(&mut add, "final_res_block", 2 * dim, dim, cond);
    let f = if final_seq { "final_conv.0" } else { "final_conv" };
    add(format!("{f}.weight"), &[1, dim, 1, 1]);
    add(format!("{f}.bias"), &[1]);
    k
}

fn shapes(vs: &nn::VarStore) -> BTreeMap<String, Vec<i64>> {
    vs.variables().into_iter().map(|(k, v)| (k, v.size())).collect()
}

#[test]
fn paper_presets_have_the_reference_sizes_and_the_official_state_dict_keys() {
    let _timing = crate::support::timed();
    // Correction: MaskUnet(64, (1, 2, 4, 8)) with DepthAugment, about 34.1 M parameters.
    let vs = nn::VarStore::new(Device::Cpu);
    let _net = CorrectionNet::new(&vs.root(), &CorrectionNetConfig::from_preset(Preset::Paper, true)).unwrap();
    let ours = shapes(&vs);
    assert_eq!(
        ours,
        official_keys(64, &[1, 2, 4, 8], 3, None, true),
        "variable names and shapes follow the official state dict"
    );
    let n = parameter_count(&vs) as f64;
    assert!((n / 34.1e6 - 1.0).abs() < 0.02, "correction paper preset: {n} parameters");
    // The shapes alone identify the preset (how an official checkpoint is loaded).
    let inferred = infer_official_config(Path::new("mem"), &ours).unwrap();
    assert_eq!(inferred, CorrectionNetConfig::from_preset(Preset::Paper, true));

    // Diffusion: the same skeleton with 1 input channel and FiLM from the 512-wide embedding, plus the
    // time and intrinsics MLPs (64 -> 256 -> 256 and 4 -> 256 -> 256), about 38.4 M parameters.
    let vs = nn::VarStore::new(Device::Cpu);
    let cfg = Preset::Paper.diffusion_unet();
    cfg.validate("unet").unwrap();
    let _unet = Unet::new(&vs.root(), &cfg);
    assert_eq!(shapes(&vs), official_keys(64, &[1, 2, 4, 8], 1, Some(512), false));
    let mlps = (64 * 256 + 256 + 256 * 256 + 256) + (4 * 256 + 256 + 256 * 256 + 256);
    let n = (parameter_count(&vs) + mlps) as f64;
    assert!((n / 38.4e6 - 1.0).abs() < 0.02, "diffusion paper preset: {n} parameters");

    // The tiny preset stays small enough to ship.
    let (vs, _) = tiny_net(true, 0);
    assert!(parameter_count(&vs) < 1_000_000);
}

#[test]
fn training_on_a_small_label_set_lowers_the_loss() {
    let _timing = crate::support::timed();
    let set = LabelSet::open(small_labels()).unwrap();
    assert_eq!((set.len(), set.width, set.height), (8, 64, 64));
    let dir = tempfile::tempdir().unwrap();
    let mut opts = TrainOptions::for_preset(Preset::Tiny, dir.path().join("run"));
    (opts.epochs, opts.batch, opts.crop, opts.lr) = (8, 4, None, 3e-3);
    let report = train_correction(&set, &set, &opts, |_| {}).unwrap();
    let losses: Vec<f64> = report.epochs.iter().map(|e| e.train_loss).collect();
    eprintln!("losses {losses:?}");
    assert!(losses[losses.len() - 1] < 0.7 * losses[0], "{losses:?}");
    for f in ["latest.safetensors", "best.safetensors", "metrics.jsonl"] {
        assert!(dir.path().join("run").join(f).exists(), "{f}");
    }
    // The learning rate decays by 0.95 per epoch.
    let lr: Vec<f64> = report.epochs.iter().map(|e| e.lr).collect();
    assert!((lr[3] / lr[2] - 0.95).abs() < 1e-12);
}

#[test]
fn a_drop_weight_trades_kept_wrong_depths_for_dropped_good_ones() {
    let _timing = crate::support::timed();
    // The same run with drop pixels weighted 1 and 20: the weighted network keeps fewer wrong depths and
    // drops more good ones at the same tau_m.
    let set = LabelSet::open(small_labels()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let confusion = |w: f64| {
        let mut opts = TrainOptions::for_preset(Preset::Tiny, dir.path().join(format!("w{w}")));
        (opts.epochs, opts.batch, opts.crop, opts.lr, opts.drop_weight) = (6, 4, None, 3e-3, w);
        train_correction(&set, &set, &opts, |_| {}).unwrap();
        let (_vs, net, _) = load_correction(&opts.out.join("latest.safetensors"), Device::Cpu).unwrap();
        evaluate_net(&net, Device::Cpu, &set, 4, &[0.5]).remove(0).metrics()
    };
    let (plain, weighted) = (confusion(1.0), confusion(20.0));
    eprintln!("FP/map {} -> {}, FN/map {} -> {}", plain.fp_per_map, weighted.fp_per_map, plain.fn_per_map, weighted.fn_per_map);
    assert!(weighted.fn_per_map > plain.fn_per_map);
    assert!(weighted.fp_per_map < 0.8 * plain.fp_per_map);
}

fn outputs(net: &CorrectionNet, x: &Tensor) -> Tensor {
    tch::no_grad(|| net.forward(x))
}

#[test]
fn a_saved_and_loaded_checkpoint_gives_bit_identical_outputs() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (vs, net) = tiny_net(true, 5);
    let x = random_depth(2, 32, 40, 0.4, 2);
    let mut meta = CheckpointMeta::untrained(&net.config);
    meta.epoch = 7;
    meta.best_metric = Some(0.5);
    let p = dir.path().join("c.safetensors");
    save_correction(&p, &vs, &meta).unwrap();
    let (_vs2, net2, meta2) = load_correction(&p, Device::Cpu).unwrap();
    assert_eq!(meta2, meta);
    assert!(outputs(&net, &x).equal(&outputs(&net2, &x)));
    // A checkpoint of another network is refused with the tensor's name.
    let (vs3, _) = tiny_net(false, 5);
    let mut vs_aug = nn::VarStore::new(Device::Cpu);
    let _n = CorrectionNet::new(&vs_aug.root(), &CorrectionNetConfig::from_preset(Preset::Tiny, true)).unwrap();
    let q = dir.path().join("noaug.safetensors");
    save_official_layout(&q, &vs3).unwrap();
    let err = pointreggpt::nn::checkpoint::load_weights(&q, &mut vs_aug).unwrap_err().to_string();
    assert!(err.contains("init_conv.weight"), "{err}");
}

#[test]
fn the_official_key_layout_round_trips_without_renaming() {
    let _timing = crate::support::timed();
    // Save our weights exactly as a converted `model-best.pt` looks (official keys, no metadata), load it
    // back: the config comes from the shapes, the outputs are bit-identical.
    let dir = tempfile::tempdir().unwrap();
    for augment in [true, false] {
        let (vs, net) = tiny_net(augment, 11);
        let p = dir.path().join(format!("official-{augment}.safetensors"));
        save_official_layout(&p, &vs).unwrap();
        let (meta, file_shapes) = pointreggpt::nn::checkpoint::read_header(&p).unwrap();
        assert!(meta.is_empty());
        assert!(
            file_shapes.contains_key("downs.0.0.block1.proj.weight") && file_shapes.contains_key("final_conv.0.weight")
        );
        // tch's own safetensors reader sees the same names.
        let names: std::collections::BTreeSet<String> =
            Tensor::read_safetensors(&p).unwrap().into_iter().map(|(n, _)| n).collect();
        assert_eq!(names, file_shapes.keys().cloned().collect());
        let (_vs2, net2, meta2) = load_correction(&p, Device::Cpu).unwrap();
        assert_eq!(meta2.net.augment, augment);
        assert_eq!(meta2.net.unet.dim, 8);
        assert_eq!(meta2.net, net.config);
        let x = random_depth(1, 24, 32, 0.3, 4);
        assert!(outputs(&net, &x).equal(&outputs(&net2, &x)));
    }
}

#[test]
fn the_corrector_keeps_empty_pixels_and_respects_the_threshold() {
    let _timing = crate::support::timed();
    let (vs, net) = tiny_net(true, 21);
    let mut r = Rng::new(8);
    let (w, h) = (40u32, 24u32);
    let data: Vec<f32> =
        (0..w * h).map(|_| if r.uniform() < 0.3 { 0.0 } else { r.uniform_range(0.5, 4.0) as f32 }).collect();
    let depth = DepthMap::new(w, h, data.clone()).unwrap();
    // Through a file: parallel tests share torch's global RNG, so a seed alone does not pin the weights.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.safetensors");
    save_correction(&path, &vs, &CheckpointMeta::untrained(&net.config)).unwrap();
    let c = UnetCorrector::load(&path, 0.5, Device::Cpu).unwrap();
    tch::set_num_threads(1); // as keep_mask runs, so the probabilities below are the same numbers
    let p = c.probabilities(&[&depth], 1).pop().unwrap();
    let mut valid: Vec<f32> = p.iter().zip(&data).filter(|(_, z)| **z > 0.0).map(|(p, _)| *p).collect();
    valid.sort_by(f32::total_cmp);
    let median = valid[valid.len() / 2];
    for threshold in [median, 0.999_999] {
        let c = UnetCorrector::load(&path, threshold, Device::Cpu).unwrap();
        let keep = c.keep_mask(&depth);
        assert_eq!(c.name(), "unet");
        for i in 0..data.len() {
            if data[i] == 0.0 {
                assert!(keep[i], "empty pixel {i} dropped");
            } else {
                assert_eq!(keep[i], p[i] > threshold, "pixel {i}: p {} threshold {threshold}", p[i]);
            }
        }
        let dropped = keep.iter().filter(|k| !**k).count();
        if threshold == median {
            assert!(dropped > 0 && dropped < valid.len(), "{dropped}");
        }
    }
}

#[test]
fn a_pipeline_config_names_a_unet_checkpoint() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (vs, net) = tiny_net(true, 2);
    let p = dir.path().join("m.safetensors");
    save_correction(&p, &vs, &CheckpointMeta::untrained(&net.config)).unwrap();
    let text = format!("method = \"unet\"\ncheckpoint = \"{}\"\nthreshold = 0.99\npreset = \"tiny\"\n", p.display());
    let c: CorrectionConfig = toml::from_str(&text).unwrap();
    c.validate("correct.condition").unwrap();
    assert_eq!(toml::from_str::<CorrectionConfig>(&toml::to_string(&c).unwrap()).unwrap(), c);
    let corrector = c.build();
    let depth = DepthMap::new(16, 16, vec![1.5; 256]).unwrap();
    assert_eq!(corrector.keep_mask(&depth).len(), 256);

    let bad: CorrectionConfig = toml::from_str(&text.replace("m.safetensors", "missing.safetensors")).unwrap();
    let err = bad.validate("correct.condition").unwrap_err().to_string();
    assert!(err.contains("correct.condition") && err.contains("missing.safetensors"), "{err}");
    let bad: CorrectionConfig = toml::from_str(&text.replace("0.99", "1.5")).unwrap();
    assert!(bad.validate("correct.condition").unwrap_err().to_string().contains("threshold"));
    let bad: CorrectionConfig = toml::from_str(&text.replace("tiny", "paper")).unwrap();
    assert!(bad.validate("correct.condition").unwrap_err().to_string().contains("preset"));
}

#[test]
fn train_and_eval_commands_run_resume_and_write_the_table() {
    let _timing = crate::support::timed();
    let labels = small_labels();
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let train = |epochs: &str, resume: bool| {
        let mut cmd = support::bin();
        cmd.args(["train", "correction", "--labels"]).arg(labels).arg("--val-labels").arg(labels);
        cmd.args(["--epochs", epochs, "--batch", "4", "--crop", "32", "--quiet", "--out"]).arg(&run);
        if resume {
            cmd.arg("--resume");
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let first = train("1", false);
    assert!(first.contains("8 training maps (64x64") && first.contains("trained epochs 1..=1"), "{first}");
    let second = train("2", true);
    assert!(second.contains("trained epochs 2..=2"), "{second}");
    let meta = pointreggpt::nn::checkpoint::read_meta(&run.join("latest.safetensors")).unwrap();
    assert_eq!(meta.epoch, 2);
    assert!((meta.next_lr - 2e-3 * 0.95 * 0.95).abs() < 1e-12, "{}", meta.next_lr);

    let csv = dir.path().join("eval.csv");
    let o = support::bin()
        .args(["eval", "correction", "--labels"])
        .arg(labels)
        .arg("--checkpoint")
        .arg(run.join("latest.safetensors"))
        .arg("--checkpoint-noaug")
        .arg(run.join("best.safetensors"))
        .arg("--out")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(
        table.contains("min-pool") && table.contains("median") && table.contains("U-Net + DepthAugment"),
        "{table}"
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(text.lines().count(), 1 + 2 + 2 + 2, "{text}");
    assert!(text.starts_with("method,tau_m,miou,"));
}

#[test]
fn the_shipped_checkpoint_beats_the_handcrafted_filters_on_held_out_scenes() {
    let _timing = crate::support::timed();
    // Fresh labels of scenes the checkpoint never saw (training used seeds 100-107, validation 500-501).
    let dir = tempfile::tempdir().unwrap();
    make_labels(&labels_config(900, 4, 120, 2, 256), &dir.path().join("held-out"));
    let set = LabelSet::open(&dir.path().join("held-out")).unwrap();
    assert_eq!(set.len(), 32);
    let (_vs, net, meta) = load_correction(Path::new(SHIPPED), Device::Cpu).unwrap();
    assert_eq!(meta.net.preset, Some(Preset::Tiny));
    let unet = evaluate_net(&net, Device::Cpu, &set, 4, &THRESHOLDS);
    let (u05, u099) = (unet[0].metrics(), unet[1].metrics());
    let filters = handcrafted_rows(&set).unwrap();
    let best_miou = filters.iter().map(|r| r.metrics.miou).fold(0.0, f64::max);
    let least_fp = filters.iter().map(|r| r.metrics.fp_per_map).fold(f64::INFINITY, f64::min);
    eprintln!(
        "held-out: U-Net mIoU@0.5 {:.2}, FP/map@0.99 {:.1}; filters: {}",
        100.0 * u05.miou,
        u099.fp_per_map,
        filters
            .iter()
            .map(|r| format!("{} mIoU {:.2} FP/map {:.1}", r.method, 100.0 * r.metrics.miou, r.metrics.fp_per_map))
            .collect::<Vec<_>>()
            .join("; ")
    );
    // The target is +10 mIoU points at tau_m 0.5. The shipped tiny network reaches +10.5 on the 64 held-out
    // maps of docs/lab/2026-12-01-correction-tiny-training-and-evaluation.md and +8.1 on these 32 (same
    // entry): asserted is a margin it keeps on both, and far fewer wrong depths kept at 0.99.
    assert!(u05.miou > best_miou + 0.07, "U-Net mIoU@0.5 {:.4} vs best filter {:.4}", u05.miou, best_miou);
    assert!(u099.fp_per_map < 0.1 * least_fp, "U-Net FP/map@0.99 {:.1} vs filters {:.1}", u099.fp_per_map, least_fp);
}
