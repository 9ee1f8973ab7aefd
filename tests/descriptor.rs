//! The learned descriptors (`pointreggpt train descriptor`): training on a generated dataset lowers the
//! loss and makes points of the same surface match on pairs it never saw, better than the same network
//! untrained (and, for the FPFH MLP, better than the FPFH it reads); `--resume` continues exactly; bad
//! input is refused with the path named.

mod support;

use pointreggpt::geometry::RadiusIndex;
use pointreggpt::nn::checkpoint::read_tensors;
use pointreggpt::registration::fpfh::{fpfh_features, FPFH_DIM};
use pointreggpt::registration::learned::{read_meta, DescriptorModel, DescriptorNet, LearnedDescriptor};
use pointreggpt::rng::Rng;
use pointreggpt::training::descriptor::data::{correspondences, load_pairs, TrainPair};
use std::path::{Path, PathBuf};
use support::{bin, synthetic_config};

/// Builds 32 pairs of two synthetic scenes drawn from `first_seed` into `dir/name`.
fn dataset(dir: &Path, name: &str, first_seed: u64) -> PathBuf {
    let config = dir.join("c.toml");
    std::fs::write(&config, synthetic_config(2, 24, 3, 2, 320, 240, 4)).unwrap();
    let out = dir.join(name);
    let o = bin()
        .args(["build", config.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-progress", "--set", &format!("source.first_seed={first_seed}")])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn train(data: &Path, out: &Path, steps: u64, extra: &[&str]) -> std::process::Output {
    bin()
        .args(["train", "descriptor", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"])
        .args(["--steps", &steps.to_string(), "--checkpoint-every", "10"])
        .args(extra)
        .output()
        .unwrap()
}

/// Share of corresponding points (64 per pair) whose nearest target descriptor (Euclidean, so raw FPFH
/// scores the way matching uses it) belongs to a target point within 10 cm of their partner: how often
/// descriptor matching finds the right place. `describe(cloud, keypoint indices)`.
fn matching_rate(pairs: &[TrainPair], describe: impl Fn(&[pointreggpt::geometry::Point], &[usize]) -> Vec<f32>, dim: usize) -> f64 {
    let (mut good, mut total) = (0usize, 0usize);
    let mut rng = Rng::new(5);
    for pair in pairs {
        let index = RadiusIndex::new(&pair.target, 0.0375);
        let (si, ti): (Vec<usize>, Vec<usize>) = correspondences(pair, &index, 64, false, &mut rng).into_iter().unzip();
        let (ds, dt) = (describe(&pair.source, &si), describe(&pair.target, &ti));
        for i in 0..si.len() {
            let dist = |j: usize| (0..dim).map(|c| (ds[i * dim + c] - dt[j * dim + c]).powi(2)).sum::<f32>();
            let best = (0..ti.len()).min_by(|&a, &b| dist(a).total_cmp(&dist(b))).unwrap();
            good += ((pair.target[ti[best]] - pair.target[ti[i]]).norm() < 0.10) as usize;
            total += 1;
        }
    }
    good as f64 / total as f64
}

/// The matching rate of `model`'s network with its initial weights (seeded).
fn untrained_rate(pairs: &[TrainPair], model: &DescriptorModel) -> f64 {
    tch::manual_seed(0);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = DescriptorNet::new(&vs.root(), model).unwrap();
    matching_rate(pairs, |c, k| net.describe(c, k), model.dim())
}

#[test]
fn training_lowers_the_loss_and_matches_unseen_pairs_better_than_the_untrained_network() {
    let dir = tempfile::tempdir().unwrap();
    let (train_set, held_out) = (dataset(dir.path(), "train", 11), dataset(dir.path(), "held", 100));
    let run = dir.path().join("run");
    let o = train(&train_set, &run, 120, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let log: Vec<serde_json::Value> = std::fs::read_to_string(run.join("loss.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let (first, last) = (&log[0], &log[log.len() - 1]);
    assert_eq!(last["step"], 120);
    assert!(last["loss"].as_f64().unwrap() < 0.9 * first["loss"].as_f64().unwrap(), "{first} -> {last}");

    let trained = LearnedDescriptor::load(&run.join("latest.safetensors")).unwrap();
    assert_eq!(trained.meta.step, 120);
    let pairs = load_pairs(&[held_out]).unwrap();
    let after = matching_rate(&pairs, |c, k| trained.describe(c, k), trained.dim());
    let before = untrained_rate(&pairs, &DescriptorModel::default());
    eprintln!("held-out matching rate: untrained {:.3}, trained {:.3}", before, after);
    assert!(after > before + 0.05, "untrained {before:.3}, trained {after:.3}");

    // The checkpoint is a `--descriptor` of `eval registration`: scored on the same single-frame pairs of
    // an unseen synthetic sequence as raw FPFH. (At this budget it does not beat FPFH yet: 6.4 % vs 6.6 %
    // IR; docs/lab/2026-12-02-patch-descriptor-first-measurement.md has the numbers. The test checks the wiring: the same pairs, a real IR.)
    let seq = dir.path().join("seq");
    let bench = dir.path().join("bench");
    let run_ok = |args: &[&str]| {
        let o = bin().args(args).output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    run_ok(&["synth", "--out", seq.to_str().unwrap(), "--frames", "40", "--seed", "200"]);
    run_ok(&["fragments", seq.join("synthetic-200").to_str().unwrap(), "--single-frames", "--out", bench.to_str().unwrap(), "--quiet"]);
    let checkpoint = run.join("latest.safetensors");
    let csv = run_ok(&["eval", "registration", bench.to_str().unwrap(), "--descriptor", checkpoint.to_str().unwrap(), "--compare", "fpfh", "--samples", "500", "--csv"]);
    let row = |csv: &str, name: &str| -> Vec<String> {
        let line = csv.lines().find(|l| l.starts_with(&format!("single-frame,{name},500,"))).unwrap_or_else(|| panic!("no row for {name}: {csv}"));
        line.split(',').map(str::to_string).collect()
    };
    let (learned, fpfh) = (row(&csv, checkpoint.to_str().unwrap()), row(&csv, "fpfh:0.125"));
    assert_eq!(learned[3], fpfh[3], "the same pair count");
    assert!(learned[3].parse::<usize>().unwrap() >= 5, "{csv}");
    // The paired difference is over the same pairs: its mean is the difference of the two IR means.
    let diff = csv.lines().skip_while(|l| !l.starts_with("benchmark,samples,pairs,ir_diff_pp")).nth(1).expect("the paired rows");
    let d: Vec<&str> = diff.split(',').collect();
    let (ir, ir_fpfh): (f64, f64) = (learned[5].parse().unwrap(), fpfh[5].parse().unwrap());
    assert_eq!(d[2], learned[3], "{diff}");
    assert!((d[3].parse::<f64>().unwrap() - (ir - ir_fpfh)).abs() < 2e-3, "paired mean {} vs {ir} - {ir_fpfh}", d[3]);
    // The wiring scores the trained network, not something else: the same network after one step (still
    // at its initial weights, near enough) registers these pairs worse.
    let barely = dir.path().join("barely");
    assert!(train(&train_set, &barely, 1, &[]).status.success());
    let barely_ckpt = barely.join("latest.safetensors");
    let csv1 = run_ok(&["eval", "registration", bench.to_str().unwrap(), "--descriptor", barely_ckpt.to_str().unwrap(), "--samples", "500", "--csv"]);
    let ir1: f64 = row(&csv1, barely_ckpt.to_str().unwrap())[5].parse().unwrap();
    eprintln!("held-out synthetic single-frame pairs, IR at 500 samples: learned {ir} %, FPFH {ir_fpfh} %, after one step {ir1} %");
    assert!(ir > ir1, "trained {ir} % vs one step {ir1} %");
}

/// The cheap baseline of issue 16: an MLP on 3-radius FPFH. Trained briefly it matches held-out pairs
/// better than untrained and better than the raw FPFH it reads, scores in `eval registration`, and a
/// patch network cannot resume its checkpoint.
#[test]
fn the_fpfh_mlp_baseline_trains_and_scores() {
    let dir = tempfile::tempdir().unwrap();
    let (train_set, held_out) = (dataset(dir.path(), "train", 11), dataset(dir.path(), "held", 100));
    let run = dir.path().join("run");
    let o = train(&train_set, &run, 150, &["--model", "fpfh-mlp"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("fpfh-mlp descriptor"), "{}", String::from_utf8_lossy(&o.stdout));
    let log: Vec<serde_json::Value> = std::fs::read_to_string(run.join("loss.jsonl")).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let (first, last) = (&log[0], &log[log.len() - 1]);
    assert!(last["loss"].as_f64().unwrap() < 0.9 * first["loss"].as_f64().unwrap(), "{first} -> {last}");

    let checkpoint = run.join("latest.safetensors");
    let trained = LearnedDescriptor::load(&checkpoint).unwrap();
    let radii = vec![0.075f32, 0.125, 0.2];
    assert_eq!(trained.meta.model, DescriptorModel::fpfh_mlp(radii.clone(), 128, 32));
    let pairs = load_pairs(&[held_out]).unwrap();
    let after = matching_rate(&pairs, |c, k| trained.describe(c, k), trained.dim());
    let before = untrained_rate(&pairs, &trained.meta.model);
    let raw = matching_rate(
        &pairs,
        |c, k| {
            let f = fpfh_features(c, &radii);
            k.iter().flat_map(|&i| f[i * 99..(i + 1) * 99].to_vec()).collect()
        },
        FPFH_DIM * 3,
    );
    eprintln!("held-out matching rate: untrained MLP {before:.3}, raw FPFH {raw:.3}, trained MLP {after:.3}");
    assert!(after > before + 0.03 && after > raw + 0.02, "untrained {before:.3}, raw FPFH {raw:.3}, trained {after:.3}");

    // It is a `--descriptor` of `eval registration`, scored on the same pairs as FPFH.
    let (seq, bench) = (dir.path().join("seq"), dir.path().join("bench"));
    assert!(bin().args(["synth", "--out", seq.to_str().unwrap(), "--frames", "40", "--seed", "200"]).output().unwrap().status.success());
    let o = bin().args(["fragments", seq.join("synthetic-200").to_str().unwrap(), "--single-frames", "--out", bench.to_str().unwrap(), "--quiet"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = bin().args(["eval", "registration", bench.to_str().unwrap(), "--descriptor", checkpoint.to_str().unwrap(), "--samples", "500", "--csv"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = String::from_utf8_lossy(&o.stdout).into_owned();
    let line = csv.lines().find(|l| l.starts_with(&format!("single-frame,{},500,", checkpoint.display()))).unwrap_or_else(|| panic!("{csv}"));
    let ir: f64 = line.split(',').nth(5).unwrap().parse().unwrap();
    assert!(ir > 1.0 && ir <= 100.0, "{csv}");

    // A patch network cannot resume it.
    let o = train(&train_set, &run, 160, &["--resume"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("holds another network"), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn resume_continues_exactly_and_bad_input_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "train", 11);
    let (once, twice) = (dir.path().join("once"), dir.path().join("twice"));
    assert!(train(&data, &once, 20, &["--points", "32"]).status.success());
    assert!(train(&data, &twice, 10, &["--points", "32"]).status.success());
    let o = train(&data, &twice, 20, &["--points", "32", "--resume"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("steps 11..=20"));
    let sorted = |p: PathBuf| -> std::collections::BTreeMap<String, tch::Tensor> { read_tensors(&p).unwrap().into_iter().collect() };
    let (a, b) = (sorted(once.join("latest.safetensors")), sorted(twice.join("latest.safetensors")));
    assert_eq!(a.len(), b.len());
    for ((ka, ta), (kb, tb)) in a.iter().zip(&b) {
        assert_eq!(ka, kb);
        assert!(ta.allclose(tb, 1e-6, 1e-7, false), "{ka} differs after resume");
    }
    assert_eq!(read_meta(&twice.join("latest.safetensors")).unwrap().step, 20);

    // Another network shape cannot resume this checkpoint; a missing dataset is named.
    let o = train(&data, &twice, 30, &["--points", "32", "--resume", "--dim", "16"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("holds another network"), "{}", String::from_utf8_lossy(&o.stderr));
    // Real pairs come as a benchmark folder (`fragments --single-frames`): every pair of it trains.
    let seq = dir.path().join("seq");
    let bench = dir.path().join("bench");
    assert!(bin().args(["synth", "--out", seq.to_str().unwrap(), "--frames", "40", "--seed", "300"]).output().unwrap().status.success());
    let o = bin().args(["fragments", seq.join("synthetic-300").to_str().unwrap(), "--single-frames", "--out", bench.to_str().unwrap()]).output().unwrap();
    let pairs = String::from_utf8_lossy(&o.stdout).split(" pairs").next().and_then(|s| s.rsplit(' ').next()).and_then(|n| n.parse::<usize>().ok());
    assert!(o.status.success() && pairs.is_some_and(|n| n > 0), "{}", String::from_utf8_lossy(&o.stdout));
    let o = train(&bench, &dir.path().join("real"), 3, &["--points", "16"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains(&format!("{} training pairs", pairs.unwrap())), "{}", String::from_utf8_lossy(&o.stdout));

    // Real + generated at a ratio, trained by exposure with the generated pairs' known-point rules and
    // noise: the counts are the bench's pairs and at most twice as many of the dataset's ok rows (counted
    // here), and the step count follows the epochs.
    let real = pairs.unwrap();
    let generated = pointreggpt::shards::dataset::Dataset::open(&data).unwrap().read_pairs().unwrap().iter().filter(|r| r.status == pointreggpt::shards::Status::Ok).count();
    let mix = dir.path().join("mix");
    let o = bin()
        .args(["train", "descriptor", "--data", bench.to_str().unwrap(), "--data", data.to_str().unwrap(), "--out", mix.to_str().unwrap(), "--quiet"])
        .args(["--generated-ratio", "2", "--epochs", "1.5", "--known-positives", "--drop-filled", "--noise", "0.005", "--rotation", "10", "--points", "16"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let g = generated.min(2 * real);
    assert!(stdout.contains(&format!("{} training pairs ({real} real, {g} generated)", real + g)), "{stdout}");
    let steps = ((1.5 * (real + g) as f64) / 4.0).ceil() as u64;
    let log = std::fs::read_to_string(mix.join("loss.jsonl")).unwrap();
    let last: serde_json::Value = serde_json::from_str(log.lines().last().unwrap()).unwrap();
    assert_eq!(last["step"].as_u64().unwrap(), steps, "{log}");
    // A ratio without real pairs is refused.
    let o = bin().args(["train", "descriptor", "--data", data.to_str().unwrap(), "--out", dir.path().join("r").to_str().unwrap(), "--generated-ratio", "1"]).output().unwrap();
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("needs real pairs"), "{}", String::from_utf8_lossy(&o.stderr));

    let missing = dir.path().join("nowhere");
    let o = train(&missing, &dir.path().join("x"), 5, &[]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("nowhere"), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `eval registration` with a checkpoint describes only the points some sample count draws: the scores
/// (IR, RANSAC, the official error, per pair and count) equal those of describing every point, and a
/// keypoint's row equals its row when the whole cloud is described.
#[test]
fn describing_only_the_sampled_points_gives_the_same_scores() {
    use pointreggpt::registration::benchmark::find_benchmarks;
    use pointreggpt::registration::{evaluate, Descriptor, EvalConfig};
    let dir = tempfile::tempdir().unwrap();
    let (seq, bench) = (dir.path().join("seq"), dir.path().join("bench"));
    assert!(bin().args(["synth", "--out", seq.to_str().unwrap(), "--frames", "40", "--seed", "400"]).output().unwrap().status.success());
    let o = bin().args(["fragments", seq.join("synthetic-400").to_str().unwrap(), "--single-frames", "--out", bench.to_str().unwrap(), "--quiet"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run = dir.path().join("run");
    let o = train(&bench, &run, 2, &["--points", "16"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let checkpoint = run.join("latest.safetensors");
    let d = Descriptor::parse(checkpoint.to_str().unwrap(), "--descriptor").unwrap();

    let benches = find_benchmarks(&bench).unwrap();
    let b = benches.iter().max_by_key(|b| b.pairs.len()).unwrap();
    assert!(b.pairs.len() >= 3, "{} pairs", b.pairs.len());
    let sampled = EvalConfig { samples: vec![200, 50], voxel: 0.06, ..Default::default() };
    let all = EvalConfig { describe_all: true, ..sampled.clone() };
    let (a, e) = (evaluate(b, &[d.clone()], &sampled, &mut || {}).unwrap(), evaluate(b, &[d.clone()], &all, &mut || {}).unwrap());
    assert_eq!(a[0].len(), 2 * b.pairs.len());
    assert_eq!(format!("{a:?}"), format!("{e:?}"), "scores differ when every point is described");

    // The rows themselves, on one cloud: describing 200 of its points gives their rows of the full description.
    let cloud = pointreggpt::geometry::voxel_downsample(&pointreggpt::ply::read_ply(&b.pairs[0].source_path).unwrap(), 0.025);
    assert!(cloud.len() > 1000, "a cloud much larger than the sample: {}", cloud.len());
    let keys: Vec<usize> = (0..cloud.len()).step_by(cloud.len() / 200).collect();
    let (full, some) = (d.describe(&cloud), d.describe_at(&cloud, &keys));
    for (r, &k) in keys.iter().enumerate() {
        for c in 0..full.dim {
            assert!((full.row(k)[c] - some.row(r)[c]).abs() < 1e-5, "point {k} component {c}: {} vs {}", full.row(k)[c], some.row(r)[c]);
        }
    }
}
