//! The stage runtime: a source of items, a chain of stages each on its own worker threads, and a sink,
//! connected by bounded crossbeam channels.
//!
//! Stages never see channels: they implement [`Stage`] (take an item, change it in place) and the
//! [`executor`] does receive → process → send. A slow stage fills its input channel and so slows its
//! producers; memory stays flat however long the run. Rayon parallelises inside a stage.

pub mod cancel;
pub mod executor;
pub mod metrics;
pub mod progress;

pub use cancel::CancelToken;
pub use executor::{run_pipeline, StageSpec, CHANNEL_CAPACITY};
pub use metrics::{RunSummary, StageMetrics};

use std::time::Duration;

/// An item flowing through a pipeline.
pub trait Item: Send + 'static {
    /// Whether an earlier stage rejected the item; later stages pass it through untouched.
    fn is_rejected(&self) -> bool;
    /// Records the wall time `stage` spent on the item (kept in the item's provenance).
    fn record_timing(&mut self, stage: &'static str, elapsed: Duration);
    /// A short label for errors: which work unit this is.
    fn describe(&self) -> String;
}

/// One operator of a pipeline.
pub trait Stage<T: Item>: Send {
    /// Name in progress bars, metrics and provenance.
    fn name(&self) -> &'static str;
    /// Processes one item in place. Rejecting the item is done by marking it (see [`Item::is_rejected`]);
    /// an `Err` is fatal for the whole run (a bug, a full disk, `--strict` on bad input).
    fn process(&mut self, item: &mut T) -> crate::Result<()>;
    /// How many items the stage takes at once at most (1: one at a time). A worker hands it the items that
    /// are already waiting, up to this many, and never waits for more.
    fn batch(&self) -> usize {
        1
    }
    /// Processes several items together (see [`Stage::batch`]); by default one after another.
    fn process_batch(&mut self, items: &mut [T]) -> crate::Result<()> {
        items.iter_mut().try_for_each(|item| self.process(item))
    }
    /// Whether the stage also processes rejected items (the stage that turns items into rows does).
    fn handles_rejected(&self) -> bool {
        false
    }
}

/// The end of a pipeline: consumes items on the calling thread.
pub trait Sink<T: Item> {
    /// Takes one finished item.
    fn consume(&mut self, item: T) -> crate::Result<()>;
    /// Called once after the last item; `cancelled` says whether the run was interrupted.
    fn finish(&mut self, cancelled: bool) -> crate::Result<()>;
}
