//! Progress bars, in one style: one per stage of a pipeline run with its rate ([`Progress`]), and single
//! bars over rows, frames or steps for the commands that read datasets, train and evaluate ([`bar`]).
//! Drawn on stderr only when asked and when it is a terminal.

use super::metrics::StageMetrics;
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

/// The bars of a run; refreshed by a background ticker from the stage metrics.
pub struct Progress {
    multi: MultiProgress,
    bars: Vec<(ProgressBar, Arc<StageMetrics>)>,
}

impl Progress {
    /// Bars for `names`, each out of `total` items. Hidden when `visible` is false or stderr is not a
    /// terminal.
    pub fn new(names: &[&'static str], metrics: &[Arc<StageMetrics>], total: u64, visible: bool) -> Self {
        let multi = MultiProgress::with_draw_target(draw_target(visible));
        let style = style();
        let bars = names
            .iter()
            .zip(metrics)
            .map(|(n, m)| {
                let bar = multi.add(ProgressBar::new(total).with_style(style.clone()).with_prefix(n.to_string()));
                (bar, m.clone())
            })
            .collect();
        Progress { multi, bars }
    }

    /// Updates every bar from its metrics.
    pub fn refresh(&self) {
        for (bar, m) in &self.bars {
            bar.set_position(m.items.load(Ordering::Relaxed));
            let rejected = m.rejected.load(Ordering::Relaxed);
            if rejected > 0 {
                bar.set_message(format!("{rejected} rejected"));
            }
        }
    }

    /// Final refresh, then removes the bars.
    pub fn finish(&self) {
        self.refresh();
        for (bar, _) in &self.bars {
            bar.finish_and_clear();
        }
        let _ = self.multi.clear();
    }

    /// How often the ticker refreshes.
    pub const TICK: Duration = Duration::from_millis(250);
}

/// The one bar style: label, bar, count, rate, message.
fn style() -> ProgressStyle {
    ProgressStyle::with_template("{prefix:>16} {bar:30} {pos:>7}/{len:7} {per_sec:>10} {msg}")
        .expect("valid template")
        .progress_chars("=> ")
}

/// stderr at 4 Hz when `visible` (indicatif draws nothing when stderr is not a terminal), else hidden.
fn draw_target(visible: bool) -> ProgressDrawTarget {
    if visible {
        ProgressDrawTarget::stderr_with_hz(4)
    } else {
        ProgressDrawTarget::hidden()
    }
}

/// A bar over `total` items labelled `label`, drawn only when `visible` and stderr is a terminal.
pub fn bar(total: u64, visible: bool, label: &str) -> ProgressBar {
    ProgressBar::with_draw_target(Some(total), draw_target(visible)).with_style(style()).with_prefix(label.to_string())
}
