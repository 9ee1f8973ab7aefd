//! How a dataset's work units group into shards, and which shards a worker owns.
//!
//! Shard `k` holds units `[k·shard_size, (k+1)·shard_size)`; worker `i` of `N` owns the shards with
//! `k mod N = i`. Both depend only on the config, so every worker and every resume agree.

use super::ManifestEntry;
use crate::error::{Error, Result};
use std::collections::{BTreeMap, BTreeSet};

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
    committed: &BTreeMap<u64, ManifestEntry>,
) -> (Vec<u64>, BTreeSet<u64>, u64) {
    let owned: Vec<u64> = (0..shard_count(shard_size, total_units)).filter(|k| k % workers == worker).collect();
    let todo: BTreeSet<u64> = owned.iter().copied().filter(|k| !committed.contains_key(k)).collect();
    let units = todo.iter().map(|&k| { let (a, b) = shard_units(k, shard_size, total_units); b - a }).sum();
    (owned, todo, units)
}

/// Checks `--worker i --workers N`.
pub fn check_worker(worker: u64, workers: u64) -> Result<()> {
    if workers == 0 || worker >= workers {
        return Err(Error::config("--worker", format!("worker index {worker} must be below the worker count {workers}")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_ranges_tile_the_units_and_workers_split_the_shards() {
        assert_eq!(shard_count(10, 25), 3);
        assert_eq!(shard_units(2, 10, 25), (20, 25));
        let all: Vec<u64> = (0..shard_count(7, 50)).flat_map(|k| { let (a, b) = shard_units(k, 7, 50); a..b }).collect();
        assert_eq!(all, (0..50).collect::<Vec<_>>());
        let (owned, todo, units) = plan_shards(50, 7, 1, 3, &BTreeMap::new());
        assert_eq!(owned, vec![1, 4, 7]);
        assert_eq!(todo.into_iter().collect::<Vec<_>>(), vec![1, 4, 7]);
        assert_eq!(units, 7 + 7 + 1, "shard 7 holds units 49..50");
        assert!(check_worker(3, 3).is_err() && check_worker(0, 0).is_err() && check_worker(2, 3).is_ok());
    }
}
