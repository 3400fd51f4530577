//! A bounded queue between two pipeline stages.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};

/// What a full queue does with a new item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WhenFull {
    /// The producer waits for room (backpressure; nothing is lost).
    Block,
    /// The oldest queued item is dropped, counted, and the new one enters
    /// (newest-frame-wins, for live sources).
    DropOldest,
}

struct State<T> {
    items: VecDeque<T>,
    closed: bool,
}

/// A bounded multi-producer, multi-consumer FIFO with a drop counter.
pub struct BoundedQueue<T> {
    capacity: usize,
    when_full: WhenFull,
    state: Mutex<State<T>>,
    not_empty: Condvar,
    not_full: Condvar,
    dropped: AtomicU64,
    max_depth: AtomicUsize,
}

impl<T> BoundedQueue<T> {
    /// A queue holding at most `capacity` (>= 1) items.
    pub fn new(capacity: usize, when_full: WhenFull) -> BoundedQueue<T> {
        BoundedQueue {
            capacity: capacity.max(1),
            when_full,
            state: Mutex::new(State { items: VecDeque::new(), closed: false }),
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
            dropped: AtomicU64::new(0),
            max_depth: AtomicUsize::new(0),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State<T>> {
        // A panicking stage cannot leave the deque half-updated: recover the data.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Adds an item. Returns the item back if the queue is closed. With
    /// [`WhenFull::DropOldest`] the oldest item is returned in `Ok(Some(..))`
    /// when one had to go (already counted).
    pub fn push(&self, item: T) -> Result<Option<T>, T> {
        let mut st = self.lock();
        let mut evicted = None;
        loop {
            if st.closed {
                return Err(item);
            }
            if st.items.len() < self.capacity {
                break;
            }
            match self.when_full {
                WhenFull::Block => st = self.not_full.wait(st).unwrap_or_else(|p| p.into_inner()),
                WhenFull::DropOldest => {
                    evicted = st.items.pop_front();
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
        st.items.push_back(item);
        self.max_depth.fetch_max(st.items.len(), Ordering::Relaxed);
        drop(st);
        self.not_empty.notify_one();
        Ok(evicted)
    }

    /// Takes the oldest item, waiting while the queue is empty and open.
    /// `None` once the queue is closed and drained.
    pub fn pop(&self) -> Option<T> {
        let mut st = self.lock();
        loop {
            if let Some(item) = st.items.pop_front() {
                drop(st);
                self.not_full.notify_one();
                return Some(item);
            }
            if st.closed {
                return None;
            }
            st = self.not_empty.wait(st).unwrap_or_else(|p| p.into_inner());
        }
    }

    /// Closes the queue: producers are refused, consumers drain what is left.
    pub fn close(&self) {
        self.lock().closed = true;
        self.not_empty.notify_all();
        self.not_full.notify_all();
    }

    /// Items queued now.
    pub fn len(&self) -> usize {
        self.lock().items.len()
    }

    /// Whether nothing is queued now.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The capacity.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Items dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// The most items ever queued at once.
    pub fn max_depth(&self) -> usize {
        self.max_depth.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn drop_oldest_keeps_the_newest_and_counts() {
        let q = BoundedQueue::new(2, WhenFull::DropOldest);
        for i in 0..5 {
            q.push(i).ok();
        }
        assert_eq!(q.dropped(), 3);
        assert_eq!(q.max_depth(), 2);
        q.close();
        assert_eq!((q.pop(), q.pop(), q.pop()), (Some(3), Some(4), None));
        assert_eq!(q.push(9), Err(9));
    }

    #[test]
    fn block_waits_for_room_and_loses_nothing() {
        let q = Arc::new(BoundedQueue::new(1, WhenFull::Block));
        let producer = {
            let q = Arc::clone(&q);
            std::thread::spawn(move || {
                for i in 0..100 {
                    q.push(i).ok();
                }
                q.close();
            })
        };
        let mut got = Vec::new();
        while let Some(i) = q.pop() {
            got.push(i);
        }
        producer.join().ok();
        assert_eq!(got, (0..100).collect::<Vec<_>>());
        assert_eq!((q.dropped(), q.max_depth()), (0, 1));
    }
}
