//! The boost protocol as one resumable run: the training pairs of every condition, one descriptor per
//! condition and training seed in `<out>/<condition>/seed-<k>/`, each scored on the same benchmark with
//! the same sampling and RANSAC seeds, and the table. A unit (condition × seed) is done when its scores
//! on this scoring ([`scores_name`]: benchmark folder, selection, evaluation settings) exist (written
//! atomically, after training finished), so a rerun skips it; a unit trained for another scoring is only
//! scored; an interrupted training resumes from its last checkpoint. The training settings are recorded
//! in `<out>/boost-settings.json` by the first run, and a rerun with other ones is refused.

use super::conditions::{comparisons, Condition};
pub use super::config::BoostConfig;
use super::draw::{build_pools, condition_pairs, draw, TrainingData};
use super::scores_file;
use super::settings;
use super::table::{format_csv, format_paired_csv, format_text, summarize};
use crate::atomic::{write_atomic, Publish};
use crate::error::{Error, Result};
use crate::export::rows::sanitize;
use crate::registration::benchmark::{find_benchmarks, Benchmark};
use crate::registration::{evaluate, Descriptor, EvalConfig, PairScore};
use crate::training::descriptor::data::TrainPair;
use crate::sources::OpenOptions;
use crate::training::descriptor::train::{train_descriptor, DescriptorTrainOptions, LATEST};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What a run did.
pub struct BoostReport {
    /// The table (text), also in `<out>/boost.txt`.
    pub text: String,
    /// Facts about the data (pair counts, histogram matching).
    pub notes: Vec<String>,
    /// Units trained in this run (before being scored; the other trained units were trained before).
    pub units_trained: usize,
    /// Units scored in this run, and units whose scores on this scoring existed.
    pub units_run: usize,
    pub units_skipped: usize,
}

/// `<out>/<condition>/seed-<k>`, or `seed-<k>-redrawn` when seed k > 0 drew its own pairs (untrained:
/// `<out>/<condition>`). The condition's name is made file-name safe (`frag+nofill:8` → `frag_nofill_8`).
pub fn unit_dir(out: &Path, c: &Condition, seed: u64, redraw: bool) -> PathBuf {
    let dir = out.join(sanitize(&c.name));
    match (c.trains(), draw_index(seed, redraw)) {
        (false, _) => dir,
        (true, 0) => dir.join(format!("seed-{seed}")),
        (true, _) => dir.join(format!("seed-{seed}-redrawn")),
    }
}

/// Which draw of the training pairs seed `k` trains on: 0 (the protocol's) unless `redraw`.
pub(super) fn draw_index(seed: u64, redraw: bool) -> u64 {
    if redraw {
        seed
    } else {
        0
    }
}

/// A unit's scores on one scoring: `scores-<key>.tsv`, the key a hash of the benchmark folder (its
/// canonical path), the benchmarks selected of it and the evaluation settings, so a run on another
/// benchmark or with other sample counts scores the trained units again instead of reusing these.
pub fn scores_name(cfg: &BoostConfig) -> Result<String> {
    let benches: Vec<String> = cfg.bench.iter().map(|b| std::fs::canonicalize(b).map(|p| p.display().to_string()).map_err(|e| Error::io(b, e))).collect::<Result<_>>()?;
    let mut only = cfg.only.clone();
    only.sort();
    let key = format!("{}\n{only:?}\n{:?}", benches.join("\n"), cfg.eval);
    Ok(format!("scores-{}.tsv", &blake3::hash(key.as_bytes()).to_hex()[..16]))
}

/// What the training of every unit depends on (not which conditions and seeds are run, nor the scoring,
/// which is keyed by [`scores_name`]), as JSON with one key per setting.
fn training_settings(cfg: &BoostConfig) -> serde_json::Value {
    // Canonical where the path exists (the models folder need not: only C4 and C6 read it).
    let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf()).display().to_string();
    // Per-unit fields are set by the run; the rest is what a unit trains with.
    let train = DescriptorTrainOptions { seed: 0, resume: true, progress: false, ..cfg.train.clone() };
    serde_json::json!({
        // One sequence keeps the keys a single-sequence run always recorded (so its runs resume).
        "sequence": (cfg.sequences.len() == 1).then(|| canonical(&cfg.sequences[0].path)),
        "first": (cfg.sequences.len() == 1).then(|| cfg.sequences[0].first),
        "frames": (cfg.sequences.len() == 1).then(|| cfg.sequences[0].frames),
        "sequences": (cfg.sequences.len() > 1).then(|| cfg.sequences.iter().map(|t| serde_json::json!({"path": canonical(&t.path), "first": t.first, "frames": t.frames})).collect::<Vec<_>>()),
        "real_every": cfg.real_every,
        "real_gaps": cfg.real_gaps,
        "fragment_frames": cfg.fragment_frames,
        "fragment_stride": cfg.fragment_stride,
        "source_frames": cfg.source_frames,
        "reference": cfg.reference.name(),
        "pairs": cfg.pairs,
        // Only when given, so the runs made before these options existed still resume.
        "open": (cfg.open != OpenOptions::default()).then(|| format!("{:?}", cfg.open)),
        "train": train,
        // Its paths as its file wrote them: the same settings wherever the run starts.
        "classical": crate::config_paths::relative_to_folder(&cfg.classical),
        "models": canonical(&cfg.models),
    })
}

/// Whether a unit finished training: its scores are written only after training, so any scores file
/// (of any scoring) says it did.
fn trained(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries.flatten().any(|e| e.file_name().to_str().is_some_and(|n| n.starts_with("scores") && n.ends_with(".tsv")))
    })
}

/// The keys and overlaps of a unit's training pairs.
pub const TRAINING_PAIRS: &str = "training-pairs.tsv";

fn score_all(benches: &[Benchmark], d: &Descriptor, eval: &EvalConfig) -> Result<Vec<PairScore>> {
    let mut out = Vec::new();
    for b in benches {
        out.extend(evaluate(b, std::slice::from_ref(d), eval, &mut || {})?.remove(0));
    }
    Ok(out)
}

/// Runs (or resumes) the protocol and writes `<out>/boost.txt`, `boost.csv` and `boost-paired.csv`.
pub fn run_boost(cfg: &BoostConfig, log: &mut dyn FnMut(&str)) -> Result<BoostReport> {
    if cfg.conditions.is_empty() || cfg.seeds == 0 || cfg.pairs == 0 || cfg.sequences.is_empty() || cfg.sequences.iter().any(|t| t.frames == 0) || cfg.bench.is_empty() {
        return Err(Error::config("eval boost", "benchmarks, conditions, sequences, --seeds, --pairs and --frames must not be empty or zero"));
    }
    let mut benches: Vec<Benchmark> = Vec::new();
    for b in &cfg.bench {
        benches.extend(find_benchmarks(b)?.into_iter().filter(|b| cfg.only.is_empty() || cfg.only.contains(&b.name)));
    }
    if benches.is_empty() {
        return Err(Error::input(&cfg.bench[0], "no benchmark pairs to score (check --only)"));
    }
    settings::check(&cfg.out, &training_settings(cfg))?;
    // Seed-major: every condition's seed 0 first, so an interrupted run has compared all conditions once.
    let units: Vec<(&Condition, u64)> =
        (0..cfg.seeds).flat_map(|k| cfg.conditions.iter().filter(move |c| c.trains() || k == 0).map(move |c| (c, k))).collect();
    let scores_name = scores_name(cfg)?;
    let dir_of = |c: &Condition, k: u64| unit_dir(&cfg.out, c, k, cfg.redraw);
    let todo: Vec<(&Condition, u64)> = units.iter().copied().filter(|&(c, k)| !dir_of(c, k).join(&scores_name).exists()).collect();
    // Units trained before (scored on another benchmark) are only scored: no data to build for them.
    let to_train: Vec<(&Condition, u64)> = todo.iter().copied().filter(|&(c, k)| c.trains() && !trained(&dir_of(c, k))).collect();
    let mut notes = Vec::new();
    let pools = if to_train.is_empty() {
        None
    } else {
        let conds: Vec<&Condition> = to_train.iter().map(|u| u.0).collect();
        let pools = build_pools(cfg, &conds, log)?;
        notes.extend(pools.notes.iter().cloned());
        Some(pools)
    };
    // The draws the units to train need, each made once.
    let mut draws: BTreeMap<u64, TrainingData> = BTreeMap::new();
    let bar = crate::runtime::progress::bar(units.len() as u64, cfg.progress, "units");
    bar.inc((units.len() - todo.len()) as u64);
    for &(c, k) in &todo {
        let dir = dir_of(c, k);
        let descriptor = if c.trains() {
            if to_train.contains(&(c, k)) {
                let d = draw_index(k, cfg.redraw);
                let pools = pools.as_ref().expect("built for the units to train");
                let data = draws.entry(d).or_insert_with(|| draw(cfg, pools, d, &mut notes));
                let pairs = condition_pairs(c, pools, data, cfg.pairs);
                if pairs.is_empty() {
                    return Err(Error::config("--conditions", format!("{}: no training pairs (see {})", c.name, cfg.out.join("data-notes.txt").display())));
                }
                let steps = cfg.train.total_steps(pairs.len());
                bar.set_message(format!("{} seed {k}: training on {} pairs, {steps} steps", c.name, pairs.len()));
                log(&format!("{} seed {k}: training on {} pairs, {steps} steps", c.name, pairs.len()));
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                let listing: String = pairs.iter().map(|p| format!("{}\t{}\t{}\n", p.pair.key, p.overlap, p.source_overlap)).collect();
                write_atomic(&dir, &dir.join(TRAINING_PAIRS), format!("key\toverlap\tsource_overlap\n{listing}").as_bytes(), Publish::Replace)?;
                let pairs: Vec<TrainPair> = pairs.into_iter().map(|p| p.pair.clone()).collect();
                let opts = DescriptorTrainOptions { seed: k, out: dir.clone(), resume: true, progress: false, ..cfg.train.clone() };
                train_descriptor(&pairs, &opts, |_| {})?;
            }
            let path = dir.join(LATEST);
            Descriptor::Learned { model: Arc::new(crate::registration::learned::LearnedDescriptor::load(&path)?), path }
        } else {
            Descriptor::Fpfh { radii: vec![crate::registration::descriptor::DEFAULT_FPFH_RADIUS] }
        };
        bar.set_message(format!("{} seed {k}: evaluating", c.name));
        let scores = score_all(&benches, &descriptor, &cfg.eval)?;
        scores_file::write(&dir.join(&scores_name), &scores)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut results: Vec<(String, Vec<Vec<PairScore>>)> = Vec::new();
    for c in &cfg.conditions {
        let mut per_seed = Vec::new();
        for &(_, k) in units.iter().filter(|(u, _)| u.name == c.name) {
            let mut scores = scores_file::read(&dir_of(c, k).join(&scores_name))?;
            if cfg.by_scene {
                scores.iter_mut().for_each(|s| s.benchmark = format!("{} {}", s.benchmark, s.scene));
            }
            per_seed.push(scores);
        }
        results.push((c.name.clone(), per_seed));
    }
    let (table, paired) = summarize(&results, &comparisons(&cfg.conditions, &cfg.compare));
    let text = format_text(&table, &paired);
    for (name, body) in [("boost.txt", text.clone()), ("boost.csv", format_csv(&table)), ("boost-paired.csv", format_paired_csv(&paired))] {
        write_atomic(&cfg.out, &cfg.out.join(name), body.as_bytes(), Publish::Replace)?;
    }
    if !notes.is_empty() {
        let path = cfg.out.join("data-notes.txt");
        let mut old = std::fs::read_to_string(&path).unwrap_or_default();
        old.push_str(&notes.iter().map(|n| format!("{n}\n")).collect::<String>());
        write_atomic(&cfg.out, &path, old.as_bytes(), Publish::Replace)?;
    }
    Ok(BoostReport { text, notes, units_trained: to_train.len(), units_run: todo.len(), units_skipped: units.len() - todo.len() })
}
