//! The frames a build draws from, in a fixed order, and the work units and shards over them.
//!
//! Unit `u` is (frame `u / samples_per_frame`, sample `u % samples_per_frame`); shard `k` holds units
//! `[k·shard_size, (k+1)·shard_size)`. Both orders depend only on the config and the input listing.

use super::config::{BuildConfig, SelectConfig, SourceConfig};
use crate::error::{Error, Result};
use crate::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use crate::sources::{open_sequences, Frame, FrameRef};
use std::sync::{Arc, Mutex};

/// Where one catalog frame's depth comes from.
#[derive(Clone, Debug)]
pub enum FrameOrigin {
    /// A frame on disk.
    Disk(FrameRef),
    /// Frame `index` of the synthetic sequence with this `seed`, rendered on demand.
    Synthetic { seed: u64, index: usize },
}

/// One selected source frame.
#[derive(Clone, Debug)]
pub struct CatalogFrame {
    /// Sequence (scene) name.
    pub scene: String,
    /// Unique frame key.
    pub key: String,
    pub origin: FrameOrigin,
}

/// The selected frames of a build.
pub struct Catalog {
    pub frames: Vec<CatalogFrame>,
    pub samples_per_frame: u32,
    synthetic: SyntheticConfig,
    /// The last synthetic sequence generated (units arrive in frame order, so one is enough).
    cache: Mutex<Option<Arc<SyntheticSequence>>>,
}

impl Catalog {
    /// Lists the frames of `config.source`, applying `config.select`.
    pub fn open(config: &BuildConfig) -> Result<Catalog> {
        let mut frames = Vec::new();
        let synthetic = match &config.source {
            SourceConfig::Synthetic { scenes, first_seed, synthetic } => {
                for s in 0..*scenes as u64 {
                    let seed = first_seed + s;
                    let scene = format!("synthetic-{seed}");
                    for index in select(synthetic.frames, &config.select) {
                        frames.push(CatalogFrame { key: format!("{scene}/frame-{index:06}"), scene: scene.clone(), origin: FrameOrigin::Synthetic { seed, index } });
                    }
                }
                synthetic.clone()
            }
            SourceConfig::Directory { path, layout } => {
                for seq in open_sequences(path, *layout)? {
                    for i in select(seq.frames.len(), &config.select) {
                        let f = &seq.frames[i];
                        frames.push(CatalogFrame { scene: seq.name.clone(), key: f.key.clone(), origin: FrameOrigin::Disk(f.clone()) });
                    }
                }
                SyntheticConfig::default()
            }
        };
        if frames.is_empty() {
            return Err(Error::config("select", "no frame is selected from the source"));
        }
        Ok(Catalog { frames, samples_per_frame: config.samples_per_frame, synthetic, cache: Mutex::new(None) })
    }

    /// Total number of work units.
    pub fn units(&self) -> u64 {
        self.frames.len() as u64 * self.samples_per_frame as u64
    }

    /// (frame index, sample index) of unit `u`.
    pub fn unit(&self, u: u64) -> (usize, u32) {
        ((u / self.samples_per_frame as u64) as usize, (u % self.samples_per_frame as u64) as u32)
    }

    /// Decodes frame `i` (renders it, for synthetic frames).
    pub fn load(&self, i: usize) -> Result<Frame> {
        match &self.frames[i].origin {
            FrameOrigin::Disk(f) => f.load(),
            FrameOrigin::Synthetic { seed, index } => {
                let seq = {
                    let mut cache = self.cache.lock().expect("catalog cache");
                    match cache.as_ref().filter(|s| s.seed == *seed) {
                        Some(s) => s.clone(),
                        None => {
                            let s = Arc::new(SyntheticSequence::generate(&self.synthetic, *seed)?);
                            *cache = Some(s.clone());
                            s
                        }
                    }
                };
                Ok(seq.frame(*index))
            }
        }
    }
}

/// Indices `offset, offset + every, ...` below `n`, at most `max_per_sequence` of them (0 = all).
fn select(n: usize, s: &SelectConfig) -> Vec<usize> {
    let it = (s.offset..n).step_by(s.every.max(1));
    if s.max_per_sequence == 0 {
        it.collect()
    } else {
        it.take(s.max_per_sequence).collect()
    }
}

/// The unit range `[first, end)` of shard `k`.
pub fn shard_units(k: u64, shard_size: u64, total_units: u64) -> (u64, u64) {
    let first = k * shard_size;
    (first, (first + shard_size).min(total_units))
}

/// Number of shards covering `total_units`.
pub fn shard_count(shard_size: u64, total_units: u64) -> u64 {
    total_units.div_ceil(shard_size)
}

/// The shards a worker owns (`k mod workers == worker`) and, of those, the ones still to do (not in
/// `committed`), with their unit count.
pub fn plan_shards(
    total_units: u64,
    shard_size: u64,
    worker: u64,
    workers: u64,
    committed: &std::collections::BTreeMap<u64, crate::shards::ManifestEntry>,
) -> (Vec<u64>, std::collections::BTreeSet<u64>, u64) {
    let owned: Vec<u64> = (0..shard_count(shard_size, total_units)).filter(|k| k % workers == worker).collect();
    let todo: std::collections::BTreeSet<u64> = owned.iter().copied().filter(|k| !committed.contains_key(k)).collect();
    let units = todo.iter().map(|&k| { let (a, b) = shard_units(k, shard_size, total_units); b - a }).sum();
    (owned, todo, units)
}

/// Checks `--worker i --workers N`.
pub fn check_worker(worker: u64, workers: u64) -> crate::Result<()> {
    if workers == 0 || worker >= workers {
        return Err(crate::Error::config("--worker", format!("worker index {worker} must be below the worker count {workers}")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selection_and_shard_ranges() {
        let s = SelectConfig { every: 50, offset: 0, max_per_sequence: 0 };
        assert_eq!(select(120, &s), vec![0, 50, 100]);
        let s = SelectConfig { every: 2, offset: 1, max_per_sequence: 3 };
        assert_eq!(select(100, &s), vec![1, 3, 5]);
        assert_eq!(shard_count(10, 25), 3);
        assert_eq!(shard_units(2, 10, 25), (20, 25));
        let all: Vec<u64> = (0..shard_count(7, 50)).flat_map(|k| { let (a, b) = shard_units(k, 7, 50); a..b }).collect();
        assert_eq!(all, (0..50).collect::<Vec<_>>());
    }
}
