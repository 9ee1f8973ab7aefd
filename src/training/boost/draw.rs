//! The training pairs of one `eval boost` run: the pools (every real candidate pair and every pair each
//! generator built) and the draws of them the units train on, generated pairs paired unit by unit.

use super::conditions::{Condition, Generator, Real, Source};
use super::data::{fragment_pairs, generated_pairs, generator_config, open_one, real_pairs, OverlapPair, SourceFrames};
use super::histogram::{histogram, match_histogram, EDGES};
use super::config::{BoostConfig, TrainingSequence};
use crate::error::Result;
use crate::registration::evaluate::permutation;
use crate::rng::Rng;
use std::collections::{BTreeMap, BTreeSet};

/// The random stream of draw `d` from a base stream: the base itself for draw 0.
fn for_draw(base: Rng, d: u64) -> Rng {
    if d == 0 {
        base
    } else {
        base.fork(1_000 + d)
    }
}

/// The pools the training pairs are drawn from: every real candidate pair of each kind and every pair
/// each generator built (with the seed of its build).
pub struct Pools {
    /// Facts about the pools (frames left out for want of a pose).
    pub notes: Vec<String>,
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
pub struct TrainingData {
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

pub fn build_pools(cfg: &BoostConfig, todo: &[&Condition], log: &mut dyn FnMut(&str)) -> Result<Pools> {
    let uses = |r: fn(&Real) -> bool| todo.iter().any(|c| c.reals().any(|x| r(&x)));
    let mut notes = Vec::new();
    let seqs = if uses(|_| true) {
        let mut seqs = Vec::new();
        for t in &cfg.sequences {
            let seq = open_one(&t.path, &cfg.open)?;
            let unposed = seq.unposed(t.first..(t.first + t.frames).min(seq.frames.len()), cfg.strict)?;
            if unposed > 0 {
                notes.push(format!("{}: {unposed} of frames {}..{} have no camera pose: left out of the real pairs ({})", seq.name, t.first, t.first + t.frames, seq.poses.describe()));
            }
            seqs.push(seq);
        }
        seqs
    } else {
        Vec::new()
    };
    let mut single = None;
    if uses(|r| *r == Real::Single) {
        let mut pairs = Vec::new();
        for (seq, t) in seqs.iter().zip(&cfg.sequences) {
            log(&format!("making the real single-frame pairs of {} frames {}..{}", seq.name, t.first, t.first + t.frames));
            let bar = crate::runtime::progress::bar(t.frames as u64, cfg.progress, "frames");
            pairs.extend(real_pairs(seq, t.first, t.frames, cfg.real_every, &cfg.real_gaps, &mut || bar.inc(1))?);
            bar.finish_and_clear();
        }
        single = Some(pairs);
    }
    let mut fragments = None;
    if uses(|r| matches!(r, Real::Fragments(_))) {
        let mut pairs = Vec::new();
        for (seq, t) in seqs.iter().zip(&cfg.sequences) {
            log(&format!("fusing fragments of {} frames every {} frames of {} frames {}..{}", cfg.fragment_frames, cfg.fragment_stride, seq.name, t.first, t.first + t.frames));
            let bar = crate::runtime::progress::bar(0, cfg.progress, "fragments");
            pairs.extend(fragment_pairs(seq, t.first, t.frames, cfg.fragment_frames, cfg.fragment_stride, &mut || bar.inc(1))?);
            bar.finish_and_clear();
        }
        fragments = Some(pairs);
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
    let sources_of = |t: &TrainingSequence| match cfg.source_frames {
        SourceFrames::EveryFrame => t.frames,
        SourceFrames::FragmentStarts { per, stride } => crate::registration::benchmark::make::fragments_within(t.first, t.first + t.frames, per, stride).len(),
    };
    let sources: usize = cfg.sequences.iter().map(sources_of).sum();
    let samples_per_frame = ((needed as f64 * 1.25 / sources.max(1) as f64).ceil() as u32).max(1);
    let mut generated = BTreeMap::new();
    for g in gens {
        log(&format!("building the {} generator's pairs ({} per source frame of {} source frames)", g.name(), samples_per_frame, sources));
        let mut pairs = Vec::new();
        let mut seed = 0;
        for (k, t) in cfg.sequences.iter().enumerate() {
            let config = generator_config(&cfg.classical, g, &cfg.models, (&t.path, &cfg.open), (t.first, t.frames), cfg.source_frames, samples_per_frame)?;
            // One sequence keeps the layout of a single-sequence run; several get a dataset each, their
            // units numbered apart so pairs of different generators still pair up by unit.
            let out = cfg.out.join("data").join(g.name());
            let out = if cfg.sequences.len() == 1 { out } else { out.join(format!("{k}")) };
            pairs.extend(generated_pairs(&config, &out, cfg.progress)?.into_iter().map(|mut p| {
                p.unit = p.unit.map(|u| u + ((k as u64) << 40));
                p
            }));
            seed = config.seed;
        }
        generated.insert(g, (pairs, seed));
    }
    Ok(Pools { single, fragments, generated, notes })
}

/// Draw `d` of the training pairs from the pools (draw 0: the protocol's), with its facts in `notes`.
pub fn draw(cfg: &BoostConfig, pools: &Pools, d: u64, notes: &mut Vec<String>) -> TrainingData {
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
        let shared: Vec<u64> = permutation(common.len(), &mut rng.fork(0)).into_iter().map(|i| common[i]).collect();
        for (&g, (pairs, _)) in &pools.generated {
            let at: BTreeMap<u64, usize> = pairs.iter().enumerate().filter_map(|(i, p)| p.unit.map(|u| (u, i))).collect();
            let mut order: Vec<usize> = shared.iter().map(|u| at[u]).collect();
            let rest: Vec<usize> = (0..pairs.len()).filter(|i| pairs[*i].unit.is_none_or(|u| !common.binary_search(&u).is_ok())).collect();
            order.extend(permutation(rest.len(), &mut rng.fork(1 + 2 * g.kind as u64 + g.lo as u64)).into_iter().map(|k| rest[k]));
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
        let perm = permutation(idx.len(), &mut for_draw(Rng::new(cfg.classical.seed).fork(78), d));
        idx = perm.into_iter().map(|k| idx[k]).collect();
        single = idx;
    }
    let mut fragments = Vec::new();
    if let Some(f) = &pools.fragments {
        fragments = permutation(f.len(), &mut for_draw(Rng::new(cfg.classical.seed).fork(79), d));
        let lo = f.iter().filter(|p| p.overlap <= 0.3).count();
        notes.push(format!("fragments{tag}: {} real fragment pairs ({} at 10-30 % overlap, {} above)", f.len(), lo, f.len() - lo));
    }
    TrainingData { single, fragments, generated }
}

/// The pairs condition `c` trains on: the first pairs of each of its sources' orders, counted from the base.
pub fn condition_pairs<'a>(c: &Condition, pools: &'a Pools, data: &TrainingData, pairs: usize) -> Vec<&'a OverlapPair> {
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
