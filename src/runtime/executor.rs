//! Runs a source, a chain of stages and a sink on threads joined by bounded channels.

use super::metrics::{RunSummary, StageMetrics};
use super::progress::Progress;
use super::{CancelToken, Item, Sink, Stage};
use crate::error::{Error, Result};
use crossbeam_channel::{bounded, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Capacity of every channel between two stages. Each item carries a frame and its clouds (a few MB at
/// most), so 8 per channel keeps every worker fed while the whole pipeline holds well under 100 MB.
pub const CHANNEL_CAPACITY: usize = 8;

/// One stage of a pipeline: one boxed instance per worker thread.
pub struct StageSpec<T: Item> {
    pub workers: Vec<Box<dyn Stage<T>>>,
}

impl<T: Item> StageSpec<T> {
    /// A stage run by a single worker thread.
    pub fn single(stage: impl Stage<T> + 'static) -> Self {
        StageSpec { workers: vec![Box::new(stage)] }
    }
    /// A stage run by `n` worker threads, each with its own instance from `make`.
    pub fn replicated<S: Stage<T> + 'static>(n: usize, mut make: impl FnMut() -> S) -> Self {
        StageSpec { workers: (0..n.max(1)).map(|_| Box::new(make()) as Box<dyn Stage<T>>).collect() }
    }
    fn name(&self) -> &'static str {
        self.workers.first().map(|w| w.name()).unwrap_or("empty")
    }
}

/// The first fatal error of a run, with the work unit it happened on.
#[derive(Default)]
struct FirstError(Mutex<Option<Error>>);

impl FirstError {
    fn set(&self, e: Error, cancel: &CancelToken) {
        let mut slot = self.0.lock().expect("error slot");
        if slot.is_none() {
            *slot = Some(e);
        }
        cancel.cancel();
    }
    fn is_set(&self) -> bool {
        self.0.lock().expect("error slot").is_some()
    }
    fn take(&self) -> Option<Error> {
        self.0.lock().expect("error slot").take()
    }
}

/// Runs `source` through `stages` into `sink` and returns the summary, or the first fatal error.
///
/// `total` sizes the progress bars. Cancelling `cancel` (Ctrl-C) stops the source; items already in
/// flight are finished and handed to the sink, then `sink.finish(true)` runs. After a fatal error, items
/// still in flight are dropped (never handed to the sink half-processed) and the error is returned,
/// prefixed with the unit it happened on.
pub fn run_pipeline<T: Item>(
    source: impl Iterator<Item = T> + Send,
    stages: Vec<StageSpec<T>>,
    sink: &mut dyn Sink<T>,
    total: u64,
    show_progress: bool,
    cancel: &CancelToken,
) -> Result<RunSummary> {
    let start = Instant::now();
    let names: Vec<&'static str> = stages.iter().map(|s| s.name()).collect();
    let metrics: Vec<Arc<StageMetrics>> = names.iter().map(|_| Arc::new(StageMetrics::default())).collect();
    let progress = Progress::new(&names, &metrics, total, show_progress);
    let error = FirstError::default();
    let mut sunk = 0u64;
    let done = CancelToken::new();

    std::thread::scope(|scope| {
        let (first_tx, mut rx): (Sender<T>, Receiver<T>) = bounded(CHANNEL_CAPACITY);
        scope.spawn(|| {
            let tx = first_tx;
            for item in source {
                if cancel.is_cancelled() || tx.send(item).is_err() {
                    break;
                }
            }
        });
        for (idx, (spec, m)) in stages.into_iter().zip(&metrics).enumerate() {
            let (tx, next_rx) = bounded::<T>(CHANNEL_CAPACITY);
            for mut stage in spec.workers {
                let (rx, tx, m, error) = (rx.clone(), tx.clone(), m.clone(), &error);
                // Each worker runs on its own one-thread rayon pool: rayon calls inside a stage then run
                // inline on the worker instead of queueing behind every other stage in the global pool.
                // Parallelism comes from the workers (units side by side).
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .thread_name(move |_| format!("stage-{idx}"))
                    .build()
                    .map_err(|e| Error::Internal(format!("cannot start a worker thread: {e}")));
                scope.spawn(move || {
                    let pool = match pool {
                        Ok(p) => p,
                        Err(e) => return error.set(e, cancel),
                    };
                    pool.install(|| {
                        for mut item in rx.iter() {
                            if error.is_set() {
                                continue; // drain without processing: nothing half-done reaches the sink
                            }
                            if item.is_rejected() && !stage.handles_rejected() {
                                m.add(Duration::ZERO, false);
                            } else {
                                let was_rejected = item.is_rejected();
                                let t0 = Instant::now();
                                let result = stage.process(&mut item);
                                let elapsed = t0.elapsed();
                                if let Err(e) = result {
                                    let unit = item.describe();
                                    error.set(Error::Unit { stage: stage.name().into(), unit, source: Box::new(e) }, cancel);
                                    continue;
                                }
                                item.record_timing(stage.name(), elapsed);
                                m.add(elapsed, item.is_rejected() && !was_rejected);
                            }
                            if tx.send(item).is_err() {
                                break;
                            }
                        }
                    })
                });
            }
            rx = next_rx;
        }
        // The progress ticker.
        scope.spawn(|| {
            while !done.is_cancelled() {
                progress.refresh();
                std::thread::sleep(Progress::TICK);
            }
        });
        // The sink, on this thread.
        for item in rx.iter() {
            if error.is_set() {
                continue;
            }
            if let Err(e) = sink.consume(item) {
                error.set(e, cancel);
                continue;
            }
            sunk += 1;
        }
        done.cancel();
    });
    progress.finish();
    if let Some(e) = error.take() {
        return Err(e);
    }
    sink.finish(cancel.is_cancelled())?;
    Ok(RunSummary::from_metrics(&names, &metrics, sunk, start.elapsed(), cancel.is_cancelled()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug)]
    struct Num {
        v: u64,
        rejected: bool,
        trail: Vec<&'static str>,
    }
    impl Item for Num {
        fn is_rejected(&self) -> bool {
            self.rejected
        }
        fn record_timing(&mut self, stage: &'static str, _: Duration) {
            self.trail.push(stage);
        }
        fn describe(&self) -> String {
            format!("unit {}", self.v)
        }
    }
    struct Double;
    impl Stage<Num> for Double {
        fn name(&self) -> &'static str {
            "double"
        }
        fn process(&mut self, item: &mut Num) -> Result<()> {
            item.v *= 2;
            Ok(())
        }
    }
    struct RejectMultiplesOf(u64);
    impl Stage<Num> for RejectMultiplesOf {
        fn name(&self) -> &'static str {
            "reject"
        }
        fn process(&mut self, item: &mut Num) -> Result<()> {
            item.rejected = item.v % self.0 == 0;
            Ok(())
        }
    }
    struct FailAt(u64);
    impl Stage<Num> for FailAt {
        fn name(&self) -> &'static str {
            "fail"
        }
        fn process(&mut self, item: &mut Num) -> Result<()> {
            if item.v == self.0 {
                Err(Error::Internal("boom".into()))
            } else {
                Ok(())
            }
        }
    }
    #[derive(Default)]
    struct Collect(Vec<Num>, Option<bool>);
    impl Sink<Num> for Collect {
        fn consume(&mut self, item: Num) -> Result<()> {
            self.0.push(item);
            Ok(())
        }
        fn finish(&mut self, cancelled: bool) -> Result<()> {
            self.1 = Some(cancelled);
            Ok(())
        }
    }
    fn nums(n: u64) -> impl Iterator<Item = Num> + Send {
        (0..n).map(|v| Num { v, rejected: false, trail: vec![] })
    }

    #[test]
    fn every_item_passes_every_stage_once_and_rejected_items_skip_later_stages() {
        let mut sink = Collect::default();
        let stages = vec![
            StageSpec { workers: vec![Box::new(Double) as Box<dyn Stage<Num>>, Box::new(Double)] },
            StageSpec::single(RejectMultiplesOf(3)),
            StageSpec::single(Double),
        ];
        let s = run_pipeline(nums(1000), stages, &mut sink, 1000, false, &CancelToken::new()).unwrap();
        assert_eq!(s.items, 1000);
        assert_eq!(sink.1, Some(false));
        let mut got: Vec<u64> = sink.0.iter().map(|n| n.v).collect();
        got.sort();
        // v -> 2v; rejected when 2v % 3 == 0 (v % 3 == 0), otherwise doubled again.
        let mut expect: Vec<u64> = (0..1000).map(|v| if v % 3 == 0 { 2 * v } else { 4 * v }).collect();
        expect.sort();
        assert_eq!(got, expect);
        let rejected = sink.0.iter().filter(|n| n.rejected).count() as u64;
        assert_eq!(s.stages[1].rejected, rejected);
        assert_eq!(s.stages[2].items, 1000);
        assert!(sink.0.iter().filter(|n| n.rejected).all(|n| n.trail == ["double", "reject"]));
    }

    #[test]
    fn a_fatal_error_names_the_unit_and_nothing_after_it_is_half_processed() {
        let mut sink = Collect::default();
        let stages = vec![StageSpec::single(FailAt(500)), StageSpec::single(Double)];
        let err = run_pipeline(nums(10_000), stages, &mut sink, 10_000, false, &CancelToken::new()).unwrap_err();
        assert!(err.to_string().contains("fail failed on unit 500"), "{err}");
        assert!(sink.0.len() < 10_000);
        assert!(sink.0.iter().all(|n| n.trail == ["fail", "double"]), "every sunk item went through every stage");
        assert_eq!(sink.1, None, "finish is not called after a fatal error");
    }

    #[test]
    fn cancellation_stops_the_source_and_finishes_items_in_flight() {
        let cancel = CancelToken::new();
        let c2 = cancel.clone();
        let source = (0..u64::MAX).map(move |v| {
            if v == 100 {
                c2.cancel();
            }
            Num { v, rejected: false, trail: vec![] }
        });
        let mut sink = Collect::default();
        let s = run_pipeline(source, vec![StageSpec::single(Double)], &mut sink, 0, false, &cancel).unwrap();
        assert!(s.cancelled);
        assert_eq!(sink.1, Some(true));
        assert!(sink.0.len() <= 101 && sink.0.len() >= 1);
        assert!(sink.0.iter().all(|n| n.trail == ["double"]));
    }
}
