//! The frames ingest prepared last, shared by its workers: a frame's samples are consecutive units, so
//! with `samples_per_frame` > 1 its depth map is decoded, resized and back-projected once, not once per
//! sample. Bounded: at most `capacity` frames are kept (the oldest asked for goes first). What a unit
//! gets is the same either way: preparing a frame is deterministic. The scene stage keeps its fused scenes
//! in one too (by block of source frames: [`super::scene`]).

use crate::error::Result;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// One frame's slot: filled once by the first worker that asks; `None` when that worker's attempt failed.
type Slot<T> = Arc<OnceLock<Option<Arc<T>>>>;

/// The last `capacity` frames asked for, by frame index (0: nothing is kept).
pub struct FrameCache<T> {
    capacity: usize,
    slots: Mutex<VecDeque<(usize, Slot<T>)>>,
    made: AtomicU64,
}

impl<T> FrameCache<T> {
    pub fn new(capacity: usize) -> Self {
        FrameCache { capacity, slots: Mutex::new(VecDeque::new()), made: AtomicU64::new(0) }
    }

    /// How many times a frame was made (prepared) so far.
    pub fn made(&self) -> u64 {
        self.made.load(Ordering::Relaxed)
    }

    /// Frame `index`, made by `make` unless it is among the last `capacity` frames asked for. Two
    /// workers asking for the same frame at once wait for one `make`. An error is never kept: each unit
    /// that asks for a frame that failed runs `make` itself and gets its own error.
    pub fn get(&self, index: usize, make: impl Fn() -> Result<T>) -> Result<Arc<T>> {
        let make = || {
            self.made.fetch_add(1, Ordering::Relaxed);
            make()
        };
        if self.capacity == 0 {
            return make().map(Arc::new);
        }
        let slot = {
            let mut slots = self.slots.lock().expect("frame cache");
            match slots.iter().find(|(i, _)| *i == index) {
                Some((_, s)) => s.clone(),
                None => {
                    let s: Slot<T> = Arc::default();
                    slots.push_back((index, s.clone()));
                    while slots.len() > self.capacity {
                        slots.pop_front();
                    }
                    s
                }
            }
        };
        let mut failed = None;
        let kept = slot.get_or_init(|| match make() {
            Ok(t) => Some(Arc::new(t)),
            Err(e) => {
                failed = Some(e);
                None
            }
        });
        match (kept, failed) {
            (Some(t), _) => Ok(t.clone()),
            (None, Some(e)) => Err(e),
            (None, None) => make().map(Arc::new),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn each_frame_is_made_once_while_kept_and_again_after_it_left() {
        let made = AtomicUsize::new(0);
        let cache = FrameCache::new(2);
        let make = |i: usize| {
            let made = &made;
            move || {
                made.fetch_add(1, Ordering::SeqCst);
                Ok(i * 10)
            }
        };
        for i in [0, 0, 0, 1, 1, 0] {
            assert_eq!(*cache.get(i, make(i)).unwrap(), i * 10);
        }
        assert_eq!(made.load(Ordering::SeqCst), 2, "frames 0 and 1, once each");
        cache.get(2, make(2)).unwrap(); // frame 0 leaves (the oldest asked for first)
        cache.get(0, make(0)).unwrap();
        assert_eq!(made.load(Ordering::SeqCst), 4);
        let off = FrameCache::new(0);
        for _ in 0..3 {
            off.get(5, make(5)).unwrap();
        }
        assert_eq!(made.load(Ordering::SeqCst), 7, "capacity 0 keeps nothing");
        assert_eq!((cache.made(), off.made()), (4, 3));
    }

    #[test]
    fn errors_are_not_kept_and_concurrent_askers_share_one_make() {
        let cache: FrameCache<u32> = FrameCache::new(4);
        let tries = AtomicUsize::new(0);
        let failing = || {
            tries.fetch_add(1, Ordering::SeqCst);
            Err(Error::InvalidArgument("bad frame".into()))
        };
        assert!(cache.get(3, failing).is_err());
        assert!(cache.get(3, failing).is_err());
        assert_eq!(tries.load(Ordering::SeqCst), 2, "each unit gets its own error");

        let made = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    let v = cache.get(7, || {
                        made.fetch_add(1, Ordering::SeqCst);
                        std::thread::sleep(std::time::Duration::from_millis(20));
                        Ok(70)
                    });
                    assert_eq!(*v.unwrap(), 70);
                });
            }
        });
        assert_eq!(made.load(Ordering::SeqCst), 1);
    }
}
