//! The shard sink: gathers rows per shard and commits each shard once all its units are in.

use super::PairUnit;
use crate::error::{Error, Result};
use crate::runtime::Sink;
use crate::shards::dataset::Dataset;
use crate::shards::row::PairRow;
use std::collections::{BTreeMap, BTreeSet};

/// Commits the shards of this run through the dataset's commit protocol (temp file, fsync, rename,
/// manifest entry). Rows are written in unit order, so a shard's content does not depend on the order
/// units finished in. Shards left incomplete by an interruption are not committed; a resume redoes them.
pub struct ShardSink<'a> {
    pub dataset: &'a Dataset,
    pub shard_size: u64,
    pub total_units: u64,
    /// The shards this run processes.
    pub shards: BTreeSet<u64>,
    buffers: BTreeMap<u64, Vec<PairRow>>,
    /// Shards committed by this run, and their rows by status.
    pub committed: Vec<u64>,
    pub rows_by_status: BTreeMap<String, u64>,
}

impl<'a> ShardSink<'a> {
    pub fn new(dataset: &'a Dataset, shard_size: u64, total_units: u64, shards: BTreeSet<u64>) -> Self {
        ShardSink { dataset, shard_size, total_units, shards, buffers: BTreeMap::new(), committed: Vec::new(), rows_by_status: BTreeMap::new() }
    }

    fn expected(&self, shard: u64) -> u64 {
        let (a, b) = crate::shards::plan::shard_units(shard, self.shard_size, self.total_units);
        b - a
    }
}

impl Sink<PairUnit> for ShardSink<'_> {
    fn consume(&mut self, mut unit: PairUnit) -> Result<()> {
        let mut row = unit.row.take().ok_or_else(|| Error::Internal(format!("unit {} reached the sink without a row", unit.unit_index)))?;
        row.timings = std::mem::take(&mut unit.timings);
        let shard = row.unit_index / self.shard_size;
        if !self.shards.contains(&shard) {
            return Err(Error::Internal(format!("unit {} belongs to shard {shard}, which this run does not own", row.unit_index)));
        }
        let buf = self.buffers.entry(shard).or_default();
        buf.push(row);
        if buf.len() as u64 == self.expected(shard) {
            let mut rows = self.buffers.remove(&shard).expect("buffer exists");
            rows.sort_by_key(|r| r.unit_index);
            let (first, end) = crate::shards::plan::shard_units(shard, self.shard_size, self.total_units);
            self.dataset.commit_pairs(shard, first, end - first, &rows)?;
            for r in &rows {
                *self.rows_by_status.entry(r.status.as_str().to_string()).or_default() += 1;
            }
            self.committed.push(shard);
        }
        Ok(())
    }

    fn finish(&mut self, cancelled: bool) -> Result<()> {
        if !cancelled && !self.buffers.is_empty() {
            let open: Vec<u64> = self.buffers.keys().copied().collect();
            return Err(Error::Internal(format!("shards {open:?} did not receive all their units")));
        }
        self.buffers.clear();
        Ok(())
    }
}
