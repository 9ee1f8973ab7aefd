//! Cooperative cancellation: Ctrl-C / SIGTERM stop the source; items in flight finish and are committed.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A shared flag that a signal handler or a failing stage sets.
#[derive(Clone, Debug, Default)]
pub struct CancelToken(Arc<AtomicBool>);

impl CancelToken {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn cancel(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }

    /// Installs a Ctrl-C / SIGTERM handler (once per process) that cancels this token; a second signal
    /// exits at once with status 130. Later calls return without installing anything.
    pub fn cancel_on_signals(&self) {
        static INSTALLED: AtomicBool = AtomicBool::new(false);
        if INSTALLED.swap(true, Ordering::SeqCst) {
            return;
        }
        let token = self.clone();
        let _ = ctrlc::set_handler(move || {
            if token.is_cancelled() {
                eprintln!("\nsecond interrupt: exiting now (committed shards are safe)");
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: finishing the work in flight and committing complete shards (interrupt again to quit now)");
            token.cancel();
        });
    }
}
