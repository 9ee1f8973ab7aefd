//! Per-stage counters and timings, and the run summary built from them.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Counters one stage updates from its workers (shared with the progress display).
#[derive(Debug, Default)]
pub struct StageMetrics {
    /// Items processed (rejected ones passed through included).
    pub items: AtomicU64,
    /// Items this stage rejected.
    pub rejected: AtomicU64,
    /// Nanoseconds spent inside `process`, summed over workers.
    pub busy_ns: AtomicU64,
}

impl StageMetrics {
    pub fn add(&self, elapsed: Duration, rejected: bool) {
        self.items.fetch_add(1, Ordering::Relaxed);
        self.busy_ns.fetch_add(elapsed.as_nanos() as u64, Ordering::Relaxed);
        if rejected {
            self.rejected.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// One stage's line of the summary.
#[derive(Clone, Debug, PartialEq)]
pub struct StageSummary {
    pub name: String,
    pub items: u64,
    pub rejected: u64,
    pub busy: Duration,
}

/// What a finished (or interrupted) run did.
#[derive(Clone, Debug, PartialEq)]
pub struct RunSummary {
    pub items: u64,
    pub wall: Duration,
    pub stages: Vec<StageSummary>,
    pub cancelled: bool,
}

impl RunSummary {
    pub(crate) fn from_metrics(names: &[&'static str], metrics: &[Arc<StageMetrics>], items: u64, wall: Duration, cancelled: bool) -> Self {
        let stages = names
            .iter()
            .zip(metrics)
            .map(|(n, m)| StageSummary {
                name: n.to_string(),
                items: m.items.load(Ordering::Relaxed),
                rejected: m.rejected.load(Ordering::Relaxed),
                busy: Duration::from_nanos(m.busy_ns.load(Ordering::Relaxed)),
            })
            .collect();
        RunSummary { items, wall, stages, cancelled }
    }

    /// Items per second of wall time.
    pub fn rate(&self) -> f64 {
        self.items as f64 / self.wall.as_secs_f64().max(1e-9)
    }

    /// A table: stage, items, rejected, busy seconds and share of the total busy time.
    pub fn stage_table(&self) -> String {
        let total: f64 = self.stages.iter().map(|s| s.busy.as_secs_f64()).sum::<f64>().max(1e-12);
        let mut out = format!("{:<22} {:>8} {:>9} {:>9} {:>7}\n", "stage", "items", "rejected", "busy s", "share");
        for s in &self.stages {
            out += &format!(
                "{:<22} {:>8} {:>9} {:>9.2} {:>6.1}%\n",
                s.name,
                s.items,
                s.rejected,
                s.busy.as_secs_f64(),
                100.0 * s.busy.as_secs_f64() / total
            );
        }
        out
    }
}
