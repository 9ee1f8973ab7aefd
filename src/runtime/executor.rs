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
                        let batch = stage.batch().max(1);
                        while let Ok(first) = rx.recv() {
                            let mut items = vec![first];
                            while items.len() < batch {
                                match rx.try_recv() {
                                    Ok(item) => items.push(item),
                                    Err(_) => break,
                                }
                            }
                            if error.is_set() {
                                continue; // drain without processing: nothing half-done reaches the sink
                            }
                            let (mut todo, skip): (Vec<T>, Vec<T>) =
                                items.into_iter().partition(|i| !i.is_rejected() || stage.handles_rejected());
                            for _ in &skip {
                                m.add(Duration::ZERO, false);
                            }
                            if !todo.is_empty() {
                                let was_rejected: Vec<bool> = todo.iter().map(|i| i.is_rejected()).collect();
                                let t0 = Instant::now();
                                let result = stage.process_batch(&mut todo);
                                // A batch's wall time is shared equally by its items.
                                let elapsed = t0.elapsed() / todo.len() as u32;
                                if let Err(e) = result {
                                    let unit = todo.iter().map(|i| i.describe()).collect::<Vec<_>>().join(", ");
                                    error.set(Error::Unit { stage: stage.name().into(), unit, source: Box::new(e) }, cancel);
                                    continue;
                                }
                                for (item, was) in todo.iter_mut().zip(was_rejected) {
                                    item.record_timing(stage.name(), elapsed);
                                    m.add(elapsed, item.is_rejected() && !was);
                                }
                            }
                            for item in todo.into_iter().chain(skip) {
                                if tx.send(item).is_err() {
                                    return;
                                }
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
    /// Adds the size of the batch it was handed to each item (so a sunk item shows its batch).
    struct Batched(usize, std::sync::Arc<Mutex<Vec<usize>>>);
    impl Stage<Num> for Batched {
        fn name(&self) -> &'static str {
            "batched"
        }
        fn process(&mut self, item: &mut Num) -> Result<()> {
            self.process_batch(std::slice::from_mut(item))
        }
        fn batch(&self) -> usize {
            self.0
        }
        fn process_batch(&mut self, items: &mut [Num]) -> Result<()> {
            let n = items.len();
            self.1.lock().unwrap().push(n);
            std::thread::sleep(Duration::from_micros(300)); // slower than its producers: items pile up
            for item in items.iter_mut() {
                item.v = item.v * 10 + n as u64;
            }
            Ok(())
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
    fn a_batching_stage_gets_waiting_items_together_and_each_item_exactly_once() {
        // The batching stage is slower than the one in front, so items wait for it; rejected items bypass it.
        struct Mark;
        impl Stage<Num> for Mark {
            fn name(&self) -> &'static str {
                "mark"
            }
            fn process(&mut self, item: &mut Num) -> Result<()> {
                item.rejected = item.v % 7 == 0;
                Ok(())
            }
        }
        let sizes = std::sync::Arc::new(Mutex::new(Vec::new()));
        let mut sink = Collect::default();
        let stages = vec![
            StageSpec { workers: vec![Box::new(Mark) as Box<dyn Stage<Num>>, Box::new(Mark)] },
            StageSpec::single(Batched(4, sizes.clone())),
        ];
        run_pipeline(nums(400), stages, &mut sink, 400, false, &CancelToken::new()).unwrap();
        let sizes = sizes.lock().unwrap().clone();
        assert!(sizes.iter().all(|&b| (1..=4).contains(&b)), "{sizes:?}");
        // (A batch of 4 waiting items holds fewer when some of them were rejected.)
        assert!(sizes.iter().filter(|&&b| b >= 2).count() > sizes.len() / 2, "waiting items were not batched: {sizes:?}");
        assert_eq!(sizes.iter().sum::<usize>(), (0..400).filter(|v| v % 7 != 0).count());
        let mut got: Vec<u64> = sink.0.iter().map(|n| if n.rejected { n.v } else { n.v / 10 }).collect();
        got.sort();
        assert_eq!(got, (0..400).collect::<Vec<_>>());
        for n in &sink.0 {
            assert_eq!(n.trail, if n.rejected { vec!["mark"] } else { vec!["mark", "batched"] });
        }
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
