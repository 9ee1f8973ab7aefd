//! The boost protocol as one resumable run: the training pairs of every condition, one descriptor per
//! condition and training seed in `<out>/<condition>/seed-<k>/`, each scored on the same benchmark with
//! the same sampling and RANSAC seeds, and the table. A unit (condition × seed) is done when its scores
//! on this scoring ([`scores_name`]: benchmark folder, selection, evaluation settings) exist (written
//! atomically, after training finished), so a rerun skips it; a unit trained for another scoring is only
//! scored; an interrupted training resumes from its last checkpoint. The training settings are recorded
//! in `<out>/boost-settings.json` by the first run, and a rerun with other ones is refused.

use super::conditions::{Condition, Generator};
use super::data::{generated_pairs, generator_config, open_one, real_pairs, OverlapPair};
use super::histogram::{histogram, match_histogram, EDGES};
use super::scores_file;
use super::settings;
use super::table::{format_csv, format_paired_csv, format_text, summarize};
use crate::atomic::{write_atomic, Publish};
use crate::error::{Error, Result};
use crate::pipeline::BuildConfig;
use crate::registration::benchmark::{find_benchmarks, Benchmark};
use crate::registration::evaluate::sample_indices;
use crate::registration::{evaluate, Descriptor, EvalConfig, PairScore};
use crate::rng::Rng;
use crate::training::descriptor::data::TrainPair;
use crate::training::descriptor::train::{train_descriptor, DescriptorTrainOptions, LATEST};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Everything a boost run needs.
pub struct BoostConfig {
    /// The posed training sequence and its frames `first .. first + frames`.
    pub sequence: PathBuf,
    pub first: usize,
    pub frames: usize,
    /// Real pairs: a source frame every `real_every` frames, partners `real_gaps` frames later.
    pub real_every: usize,
    pub real_gaps: Vec<usize>,
    /// The evaluation benchmark folder, and the benchmarks of it to score (empty: all).
    pub bench: PathBuf,
    pub only: Vec<String>,
    pub conditions: Vec<Condition>,
    pub seeds: u64,
    /// Each training seed k > 0 also draws its own training pairs (real and generated, from the same
    /// pools); seed 0 keeps the protocol's draw. The spread over seeds then covers the draw too.
    pub redraw: bool,
    /// Training pairs per condition (C5/C6: C1's count; the 2x variants double it).
    pub pairs: usize,
    /// The descriptor training settings (`out`, `seed`, `resume` are set per unit).
    pub train: DescriptorTrainOptions,
    pub eval: EvalConfig,
    /// The classical generator's pipeline config (C3; C2 and C4 override its correction and fill).
    pub classical: BuildConfig,
    /// Folder of the neural generator's checkpoints.
    pub models: PathBuf,
    pub out: PathBuf,
    pub progress: bool,
}

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

/// `<out>/<condition>/seed-<k>`, or `seed-<k>-redrawn` when seed k > 0 drew its own pairs (C0, untrained:
/// `<out>/C0`).
pub fn unit_dir(out: &Path, c: Condition, seed: u64, redraw: bool) -> PathBuf {
    match (c.trains(), draw_index(seed, redraw)) {
        (false, _) => out.join(c.name()),
        (true, 0) => out.join(c.name()).join(format!("seed-{seed}")),
        (true, _) => out.join(c.name()).join(format!("seed-{seed}-redrawn")),
    }
}

/// Which draw of the training pairs seed `k` trains on: 0 (the protocol's) unless `redraw`.
fn draw_index(seed: u64, redraw: bool) -> u64 {
    if redraw {
        seed
    } else {
        0
    }
}

/// The random stream of draw `d` from a base stream: the base itself for draw 0.
fn for_draw(base: Rng, d: u64) -> Rng {
    if d == 0 {
        base
    } else {
        base.fork(1_000 + d)
    }
}

/// A unit's scores on one scoring: `scores-<key>.tsv`, the key a hash of the benchmark folder (its
/// canonical path), the benchmarks selected of it and the evaluation settings, so a run on another
/// benchmark or with other sample counts scores the trained units again instead of reusing these.
pub fn scores_name(cfg: &BoostConfig) -> Result<String> {
    let bench = std::fs::canonicalize(&cfg.bench).map_err(|e| Error::io(&cfg.bench, e))?;
    let mut only = cfg.only.clone();
    only.sort();
    let key = format!("{}\n{only:?}\n{:?}", bench.display(), cfg.eval);
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
        "sequence": canonical(&cfg.sequence),
        "first": cfg.first,
        "frames": cfg.frames,
        "real_every": cfg.real_every,
        "real_gaps": cfg.real_gaps,
        "pairs": cfg.pairs,
        "train": train,
        "classical": cfg.classical,
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

/// A seeded subset of `k` of `items` (all when fewer), in their order.
fn subset<T: Copy>(items: &[T], k: usize, rng: &mut Rng) -> Vec<T> {
    let mut idx = sample_indices(items.len(), k, rng);
    idx.sort_unstable();
    idx.into_iter().map(|i| items[i]).collect()
}

/// The pools the training pairs are drawn from: every real candidate pair and every pair each generator
/// built (with the seed of its draw).
struct Pools {
    /// `None` when no condition to train uses real pairs.
    real: Option<Vec<OverlapPair>>,
    generated: BTreeMap<Generator, (Vec<OverlapPair>, u64)>,
}

/// One draw of the training pairs, as indices into the [`Pools`]: the real ones (matched to the drawn
/// classical pairs' overlap histogram) and each generator's, at most `cfg.pairs` of each.
struct TrainingData {
    real: Vec<usize>,
    generated: BTreeMap<Generator, Vec<usize>>,
}

fn build_pools(cfg: &BoostConfig, todo: &[Condition], log: &mut dyn FnMut(&str)) -> Result<Pools> {
    let mut gens: Vec<Generator> = todo.iter().filter_map(|c| c.generator()).collect();
    if todo.iter().any(|c| c.uses_real()) {
        gens.push(Generator::Classical); // the reference histogram of C1
    }
    gens.sort();
    gens.dedup();
    let samples_per_frame = ((cfg.pairs as f64 * 1.25 / cfg.frames.max(1) as f64).ceil() as u32).max(1);
    let mut generated = BTreeMap::new();
    for g in gens {
        log(&format!("building the {} generator's pairs ({} per frame of {} frames)", g.name(), samples_per_frame, cfg.frames));
        let config = generator_config(&cfg.classical, g, &cfg.models, &cfg.sequence, cfg.first, cfg.frames, samples_per_frame)?;
        let pairs = generated_pairs(&config, &cfg.out.join("data").join(g.name()), cfg.progress)?;
        generated.insert(g, (pairs, config.seed));
    }
    let mut real = None;
    if todo.iter().any(|c| c.uses_real()) {
        let seq = open_one(&cfg.sequence)?;
        log(&format!("making the real pairs of frames {}..{}", cfg.first, cfg.first + cfg.frames));
        let bar = crate::runtime::progress::bar(cfg.frames as u64, cfg.progress, "frames");
        real = Some(real_pairs(&seq, cfg.first, cfg.frames, cfg.real_every, &cfg.real_gaps, &mut || bar.inc(1))?);
        bar.finish_and_clear();
    }
    Ok(Pools { real, generated })
}

/// Draw `d` of the training pairs from the pools (draw 0: the protocol's), with its facts in `notes`.
fn draw(cfg: &BoostConfig, pools: &Pools, d: u64, notes: &mut Vec<String>) -> TrainingData {
    let tag = if d == 0 { String::new() } else { format!(" (draw {d})") };
    let mut generated = BTreeMap::new();
    for (&g, (pairs, seed)) in &pools.generated {
        let mut idx = sample_indices(pairs.len(), cfg.pairs, &mut for_draw(Rng::new(*seed).fork(g as u64), d));
        idx.sort_unstable();
        notes.push(format!("{}{tag}: {} generated pairs{}", g.name(), idx.len(), if idx.len() < cfg.pairs { " (all the build made: fewer than --pairs)" } else { "" }));
        generated.insert(g, idx);
    }
    let mut real = Vec::new();
    if let Some(candidates) = &pools.real {
        let classical = &pools.generated[&Generator::Classical].0;
        let reference: Vec<f64> = generated[&Generator::Classical].iter().map(|&i| classical[i].overlap).collect();
        let overlaps: Vec<f64> = candidates.iter().map(|p| p.overlap).collect();
        let m = match_histogram(&overlaps, &reference, &EDGES, cfg.pairs, &mut for_draw(Rng::new(cfg.classical.seed).fork(77), d));
        notes.push(format!(
            "real{tag}: {} candidate pairs (overlap histogram {:?} over bins from 10 % by 10 %); the classical pairs' histogram {:?}; \
             {} real pairs drawn to it{}",
            candidates.len(),
            histogram(&overlaps, &EDGES),
            histogram(&reference, &EDGES),
            m.indices.len(),
            if m.complete { String::new() } else { format!(" (fewer than --pairs {}: the scarcest bin allows no more at this histogram)", cfg.pairs) }
        ));
        real = m.indices;
    }
    TrainingData { real, generated }
}

/// The pairs condition `c` trains on.
fn condition_pairs<'a>(c: Condition, pools: &'a Pools, data: &TrainingData, seed: u64, d: u64) -> Vec<&'a OverlapPair> {
    let generated: &[usize] = c.generator().and_then(|g| data.generated.get(&g)).map_or(&[], |v| v);
    let pool: &'a [OverlapPair] = c.generator().and_then(|g| pools.generated.get(&g)).map_or(&[], |(p, _)| p);
    let real: &'a [OverlapPair] = pools.real.as_deref().unwrap_or(&[]);
    let (r, g) = c.mix(data.real.len(), generated.len());
    let rng = for_draw(Rng::new(seed).fork(c as u64), d);
    let mut out: Vec<&OverlapPair> = subset(&data.real, r, &mut rng.fork(0)).into_iter().map(|i| &real[i]).collect();
    out.extend(subset(generated, g, &mut rng.fork(1)).into_iter().map(|i| &pool[i]));
    out
}

fn score_all(benches: &[Benchmark], d: &Descriptor, eval: &EvalConfig) -> Result<Vec<PairScore>> {
    let mut out = Vec::new();
    for b in benches {
        out.extend(evaluate(b, std::slice::from_ref(d), eval, &mut || {})?.remove(0));
    }
    Ok(out)
}

/// Runs (or resumes) the protocol and writes `<out>/boost.txt`, `boost.csv` and `boost-paired.csv`.
pub fn run_boost(cfg: &BoostConfig, log: &mut dyn FnMut(&str)) -> Result<BoostReport> {
    if cfg.conditions.is_empty() || cfg.seeds == 0 || cfg.pairs == 0 || cfg.frames == 0 {
        return Err(Error::config("eval boost", "conditions, --seeds, --pairs and --frames must not be empty or zero"));
    }
    let benches: Vec<Benchmark> = find_benchmarks(&cfg.bench)?.into_iter().filter(|b| cfg.only.is_empty() || cfg.only.contains(&b.name)).collect();
    if benches.is_empty() {
        return Err(Error::input(&cfg.bench, "no benchmark pairs to score (check --only)"));
    }
    settings::check(&cfg.out, &training_settings(cfg))?;
    // Seed-major: every condition's seed 0 first, so an interrupted run has compared all conditions once.
    let units: Vec<(Condition, u64)> =
        (0..cfg.seeds).flat_map(|k| cfg.conditions.iter().filter(move |c| c.trains() || k == 0).map(move |&c| (c, k))).collect();
    let scores_name = scores_name(cfg)?;
    let dir_of = |c: Condition, k: u64| unit_dir(&cfg.out, c, k, cfg.redraw);
    let todo: Vec<(Condition, u64)> = units.iter().copied().filter(|&(c, k)| !dir_of(c, k).join(&scores_name).exists()).collect();
    // Units trained before (scored on another benchmark) are only scored: no data to build for them.
    let to_train: Vec<(Condition, u64)> = todo.iter().copied().filter(|&(c, k)| c.trains() && !trained(&dir_of(c, k))).collect();
    let mut notes = Vec::new();
    let pools = if to_train.is_empty() {
        None
    } else {
        let conds: Vec<Condition> = to_train.iter().map(|u| u.0).collect();
        Some(build_pools(cfg, &conds, log)?)
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
                let pairs = condition_pairs(c, pools, data, cfg.classical.seed, d);
                bar.set_message(format!("{} seed {k}: training on {} pairs", c.name(), pairs.len()));
                log(&format!("{} seed {k}: training on {} pairs", c.name(), pairs.len()));
                std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
                let listing: String = pairs.iter().map(|p| format!("{}\t{}\n", p.pair.key, p.overlap)).collect();
                write_atomic(&dir, &dir.join(TRAINING_PAIRS), format!("key\toverlap\n{listing}").as_bytes(), Publish::Replace)?;
                let pairs: Vec<TrainPair> = pairs.into_iter().map(|p| p.pair.clone()).collect();
                let opts = DescriptorTrainOptions { seed: k, out: dir.clone(), resume: true, progress: false, ..cfg.train.clone() };
                train_descriptor(&pairs, &opts, |_| {})?;
            }
            let path = dir.join(LATEST);
            Descriptor::Learned { model: Arc::new(crate::registration::learned::LearnedDescriptor::load(&path)?), path }
        } else {
            Descriptor::Fpfh { radii: vec![crate::registration::descriptor::DEFAULT_FPFH_RADIUS] }
        };
        bar.set_message(format!("{} seed {k}: evaluating", c.name()));
        let scores = score_all(&benches, &descriptor, &cfg.eval)?;
        scores_file::write(&dir.join(&scores_name), &scores)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut results: BTreeMap<Condition, Vec<Vec<PairScore>>> = BTreeMap::new();
    let mut by_condition = units.clone();
    by_condition.sort();
    for &(c, k) in &by_condition {
        results.entry(c).or_default().push(scores_file::read(&dir_of(c, k).join(&scores_name))?);
    }
    let (table, paired) = summarize(&results);
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
