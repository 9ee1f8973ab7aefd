//! The boost protocol as one resumable run: the training pairs of every condition, one descriptor per
//! condition and training seed in `<out>/<condition>/seed-<k>/`, each scored on the same benchmark with
//! the same sampling and RANSAC seeds, and the table. A unit (condition × seed) is done when its scores
//! on this scoring ([`scores_name`]: benchmark folder, selection, evaluation settings) exist (written
//! atomically, after training finished), so a rerun skips it; a unit trained for another scoring is only
//! scored; an interrupted training resumes from its last checkpoint. The training settings are recorded
//! in `<out>/boost-settings.json` by the first run, and a rerun with other ones is refused.

use super::conditions::{comparisons, Condition, Generator, Real, Source};
use super::data::{fragment_pairs, generated_pairs, generator_config, open_one, real_pairs, OverlapPair, SourceFrames};
use super::histogram::{histogram, match_histogram, EDGES};
use super::scores_file;
use super::settings;
use super::table::{format_csv, format_paired_csv, format_text, summarize};
use crate::atomic::{write_atomic, Publish};
use crate::error::{Error, Result};
use crate::export::rows::sanitize;
use crate::pipeline::BuildConfig;
use crate::registration::benchmark::{find_benchmarks, Benchmark};
use crate::registration::evaluate::sample_indices;
use crate::registration::{evaluate, Descriptor, EvalConfig, PairScore};
use crate::rng::Rng;
use crate::training::descriptor::data::TrainPair;
use crate::training::descriptor::train::{train_descriptor, DescriptorTrainOptions, LATEST};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Everything a boost run needs.
pub struct BoostConfig {
    /// The posed training sequence and its frames `first .. first + frames`.
    pub sequence: PathBuf,
    pub first: usize,
    pub frames: usize,
    /// Real single-frame pairs: a source frame every `real_every` frames, partners `real_gaps` frames later.
    pub real_every: usize,
    pub real_gaps: Vec<usize>,
    /// Real fragment pairs: fragments of `fragment_frames` frames every `fragment_stride` frames.
    pub fragment_frames: usize,
    pub fragment_stride: usize,
    /// Where generated pairs take their source frames from.
    pub source_frames: SourceFrames,
    /// The generator whose pairs' source-side overlap histogram the real single-frame pairs are matched to.
    pub reference: Generator,
    /// The evaluation benchmark folders, and the benchmarks of them to score (empty: all).
    pub bench: Vec<PathBuf>,
    pub only: Vec<String>,
    pub conditions: Vec<Condition>,
    /// Paired differences asked for besides the default ones (names).
    pub compare: Vec<(String, String)>,
    pub seeds: u64,
    /// Each training seed k > 0 also draws its own training pairs (real and generated, from the same
    /// pools); seed 0 keeps the protocol's draw. The spread over seeds then covers the draw too.
    pub redraw: bool,
    /// Training pairs per condition without a real base, the most real base pairs, and the generated
    /// pool's size beyond what the mixes need.
    pub pairs: usize,
    /// The descriptor training settings (`out`, `seed`, `resume` are set per unit).
    pub train: DescriptorTrainOptions,
    pub eval: EvalConfig,
    /// The classical generator's pipeline config (the other generators override its correction and fill).
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
        "sequence": canonical(&cfg.sequence),
        "first": cfg.first,
        "frames": cfg.frames,
        "real_every": cfg.real_every,
        "real_gaps": cfg.real_gaps,
        "fragment_frames": cfg.fragment_frames,
        "fragment_stride": cfg.fragment_stride,
        "source_frames": cfg.source_frames,
        "reference": cfg.reference.name(),
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

/// The pools the training pairs are drawn from: every real candidate pair of each kind and every pair
/// each generator built (with the seed of its build).
struct Pools {
    single: Option<Vec<OverlapPair>>,
    fragments: Option<Vec<OverlapPair>>,
    generated: BTreeMap<Generator, (Vec<OverlapPair>, u64)>,
}

impl Pools {
    fn real(&self, r: Real) -> &[OverlapPair] {
        match r {
            Real::Single => self.single.as_deref(),
            Real::Fragments(_) => self.fragments.as_deref(),
        }
        .unwrap_or(&[])
    }
}

/// One draw of the training pairs, as orders of indices into the [`Pools`]: a condition takes the first
/// pairs of each order it uses, so mixes at different ratios share their pairs, and every generator's
/// order lists the same work units (paired unit by unit) as far as each pool has them.
struct TrainingData {
    /// The real single-frame pairs matched to the reference generator's histogram.
    single: Vec<usize>,
    fragments: Vec<usize>,
    generated: BTreeMap<Generator, Vec<usize>>,
}

impl TrainingData {
    fn order(&self, source: &Source) -> &[usize] {
        match source {
            Source::Real(Real::Single) => &self.single,
            Source::Real(Real::Fragments(_)) => &self.fragments,
            Source::Generated(g) => self.generated.get(g).map_or(&[], |v| v),
        }
    }
}

/// How many base pairs condition `c` draws: all of its real pool's order up to --pairs (`fragN`: N).
fn base_count(c: &Condition, data: &TrainingData, pairs: usize) -> usize {
    match c.base() {
        Some(Real::Fragments(Some(n))) => n.min(data.fragments.len()),
        Some(r) => data.order(&Source::Real(r)).len().min(pairs),
        None => 0,
    }
}

fn build_pools(cfg: &BoostConfig, todo: &[&Condition], log: &mut dyn FnMut(&str)) -> Result<Pools> {
    let uses = |r: fn(&Real) -> bool| todo.iter().any(|c| c.reals().any(|x| r(&x)));
    let seq = if uses(|_| true) { Some(open_one(&cfg.sequence)?) } else { None };
    let mut single = None;
    if uses(|r| *r == Real::Single) {
        log(&format!("making the real single-frame pairs of frames {}..{}", cfg.first, cfg.first + cfg.frames));
        let bar = crate::runtime::progress::bar(cfg.frames as u64, cfg.progress, "frames");
        single = Some(real_pairs(seq.as_ref().expect("opened"), cfg.first, cfg.frames, cfg.real_every, &cfg.real_gaps, &mut || bar.inc(1))?);
        bar.finish_and_clear();
    }
    let mut fragments = None;
    if uses(|r| matches!(r, Real::Fragments(_))) {
        log(&format!("fusing fragments of {} frames every {} frames of frames {}..{}", cfg.fragment_frames, cfg.fragment_stride, cfg.first, cfg.first + cfg.frames));
        let bar = crate::runtime::progress::bar(0, cfg.progress, "fragments");
        fragments = Some(fragment_pairs(seq.as_ref().expect("opened"), cfg.first, cfg.frames, cfg.fragment_frames, cfg.fragment_stride, &mut || bar.inc(1))?);
        bar.finish_and_clear();
    }
    let mut gens: Vec<Generator> = todo.iter().flat_map(|c| c.generators()).collect();
    if single.is_some() {
        gens.push(cfg.reference); // the reference histogram of the real single-frame pairs
    }
    gens.sort();
    gens.dedup();
    // Enough generated pairs for every mix: --pairs, or the largest ratio times the largest real base.
    let real_base = |r: Real| match r {
        Real::Single => cfg.pairs,
        Real::Fragments(n) => n.unwrap_or(usize::MAX).min(fragments.as_ref().map_or(0, |f| f.len())).min(cfg.pairs),
    };
    let needed = todo
        .iter()
        .flat_map(|c| {
            let base = c.base().map(real_base);
            c.parts.iter().skip(base.is_some() as usize).map(move |p| (p.factor * base.unwrap_or(cfg.pairs) as f64).ceil() as usize)
        })
        .chain([cfg.pairs])
        .max()
        .unwrap_or(cfg.pairs);
    let sources = match cfg.source_frames {
        SourceFrames::EveryFrame => cfg.frames,
        SourceFrames::FragmentStarts { per, stride } => {
            crate::registration::benchmark::make::fragments_within(cfg.first, cfg.first + cfg.frames, per, stride).len()
        }
    };
    let samples_per_frame = ((needed as f64 * 1.25 / sources.max(1) as f64).ceil() as u32).max(1);
    let mut generated = BTreeMap::new();
    for g in gens {
        log(&format!("building the {} generator's pairs ({} per source frame of {} source frames)", g.name(), samples_per_frame, sources));
        let config = generator_config(&cfg.classical, g, &cfg.models, &cfg.sequence, (cfg.first, cfg.frames), cfg.source_frames, samples_per_frame)?;
        let pairs = generated_pairs(&config, &cfg.out.join("data").join(g.name()), cfg.progress)?;
        generated.insert(g, (pairs, config.seed));
    }
    Ok(Pools { single, fragments, generated })
}

/// Draw `d` of the training pairs from the pools (draw 0: the protocol's), with its facts in `notes`.
fn draw(cfg: &BoostConfig, pools: &Pools, d: u64, notes: &mut Vec<String>) -> TrainingData {
    let tag = if d == 0 { String::new() } else { format!(" (draw {d})") };
    // Generated: one seeded order of the work units every pool holds, then each pool's own remaining
    // units, so the first pairs of every generator share their units.
    let mut generated = BTreeMap::new();
    if let Some((_, (_, seed))) = pools.generated.iter().next() {
        let units = |pairs: &[OverlapPair]| -> BTreeSet<u64> { pairs.iter().filter_map(|p| p.unit).collect() };
        let mut common: Option<BTreeSet<u64>> = None;
        for (pairs, _) in pools.generated.values() {
            let u = units(pairs);
            common = Some(match common {
                None => u,
                Some(c) => c.intersection(&u).copied().collect(),
            });
        }
        let common: Vec<u64> = common.unwrap_or_default().into_iter().collect();
        let rng = for_draw(Rng::new(*seed).fork(0x6E), d);
        let shared: Vec<u64> = sample_indices(common.len(), common.len(), &mut rng.fork(0)).into_iter().map(|i| common[i]).collect();
        for (&g, (pairs, _)) in &pools.generated {
            let at: BTreeMap<u64, usize> = pairs.iter().enumerate().filter_map(|(i, p)| p.unit.map(|u| (u, i))).collect();
            let mut order: Vec<usize> = shared.iter().map(|u| at[u]).collect();
            let rest: Vec<usize> = (0..pairs.len()).filter(|i| pairs[*i].unit.is_none_or(|u| !common.binary_search(&u).is_ok())).collect();
            order.extend(sample_indices(rest.len(), rest.len(), &mut rng.fork(1 + 2 * g.kind as u64 + g.lo as u64)).into_iter().map(|k| rest[k]));
            notes.push(format!("{}{tag}: {} generated pairs, {} of their units in every generator's pool", g.name(), pairs.len(), common.len()));
            generated.insert(g, order);
        }
    }
    let mut single = Vec::new();
    if let Some(candidates) = &pools.single {
        let (pool, _) = &pools.generated[&cfg.reference];
        let reference: Vec<f64> = generated[&cfg.reference].iter().take(cfg.pairs).map(|&i| pool[i].source_overlap).collect();
        let overlaps: Vec<f64> = candidates.iter().map(|p| p.source_overlap).collect();
        let m = match_histogram(&overlaps, &reference, &EDGES, cfg.pairs, &mut for_draw(Rng::new(cfg.classical.seed).fork(77), d));
        notes.push(format!(
            "single{tag}: {} candidate real pairs (source-side overlap histogram {:?} over bins from 10 % by 10 %); the {} generator's {:?}; \
             {} real pairs drawn to it{}",
            candidates.len(),
            histogram(&overlaps, &EDGES),
            cfg.reference.name(),
            histogram(&reference, &EDGES),
            m.indices.len(),
            if m.complete { String::new() } else { format!(" (fewer than --pairs {}: the scarcest bin allows no more at this histogram)", cfg.pairs) }
        ));
        let mut idx = m.indices;
        let perm = sample_indices(idx.len(), idx.len(), &mut for_draw(Rng::new(cfg.classical.seed).fork(78), d));
        idx = perm.into_iter().map(|k| idx[k]).collect();
        single = idx;
    }
    let mut fragments = Vec::new();
    if let Some(f) = &pools.fragments {
        fragments = sample_indices(f.len(), f.len(), &mut for_draw(Rng::new(cfg.classical.seed).fork(79), d));
        let lo = f.iter().filter(|p| p.overlap <= 0.3).count();
        notes.push(format!("fragments{tag}: {} real fragment pairs ({} at 10-30 % overlap, {} above)", f.len(), lo, f.len() - lo));
    }
    TrainingData { single, fragments, generated }
}

/// The pairs condition `c` trains on: the first pairs of each of its sources' orders, counted from the base.
fn condition_pairs<'a>(c: &Condition, pools: &'a Pools, data: &TrainingData, pairs: usize) -> Vec<&'a OverlapPair> {
    let base = base_count(c, data, pairs);
    let counts = c.counts(base, pairs, |s| data.order(s).len());
    let mut out = Vec::new();
    for (part, k) in c.parts.iter().zip(counts) {
        let pool: &'a [OverlapPair] = match part.source {
            Source::Real(r) => pools.real(r),
            Source::Generated(g) => pools.generated.get(&g).map_or(&[], |(p, _)| p),
        };
        out.extend(data.order(&part.source).iter().take(k).map(|&i| &pool[i]));
    }
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
    if cfg.conditions.is_empty() || cfg.seeds == 0 || cfg.pairs == 0 || cfg.frames == 0 || cfg.bench.is_empty() {
        return Err(Error::config("eval boost", "benchmarks, conditions, --seeds, --pairs and --frames must not be empty or zero"));
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
            per_seed.push(scores_file::read(&dir_of(c, k).join(&scores_name))?);
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
