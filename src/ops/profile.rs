//! Wall-time accounting of the custom operators, for `tricons bench`.
//!
//! Off by default: [`TypedWrapper`](super::tract_glue::TypedWrapper) then pays one
//! relaxed atomic load per call. [`enable`] turns it on process-wide; [`snapshot`]
//! reads the totals per node type and [`reset`] clears them.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use super::PROFILED_NODE_TYPES as NODE_TYPES;

static ENABLED: AtomicBool = AtomicBool::new(false);
static NANOS: [AtomicU64; NODE_TYPES.len()] = [const { AtomicU64::new(0) }; NODE_TYPES.len()];
static CALLS: [AtomicU64; NODE_TYPES.len()] = [const { AtomicU64::new(0) }; NODE_TYPES.len()];

/// Totals of one node type since the last [`reset`].
#[derive(Clone, Debug, PartialEq)]
pub struct OpTime {
    /// ONNX node type (`ai.tricons`, or RoiAlign / NonMaxSuppression).
    pub node_type: &'static str,
    /// Evaluations.
    pub calls: u64,
    /// Total wall time of those evaluations.
    pub total: Duration,
}

/// Turn the accounting on or off (process-wide).
pub fn enable(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

/// Clear the totals.
pub fn reset() {
    for (n, c) in NANOS.iter().zip(&CALLS) {
        n.store(0, Ordering::Relaxed);
        c.store(0, Ordering::Relaxed);
    }
}

/// The totals per node type, in [`NODE_TYPES`] order.
pub fn snapshot() -> Vec<OpTime> {
    NODE_TYPES
        .iter()
        .zip(NANOS.iter().zip(&CALLS))
        .map(|(&node_type, (n, c))| OpTime {
            node_type,
            calls: c.load(Ordering::Relaxed),
            total: Duration::from_nanos(n.load(Ordering::Relaxed)),
        })
        .collect()
}

/// Run `f`, adding its wall time to `node_type`'s total when accounting is on.
pub(crate) fn timed<R>(node_type: &str, f: impl FnOnce() -> R) -> R {
    if !ENABLED.load(Ordering::Relaxed) {
        return f();
    }
    let start = Instant::now();
    let out = f();
    let nanos = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
    if let Some(i) = NODE_TYPES.iter().position(|&t| t == node_type) {
        NANOS[i].fetch_add(nanos, Ordering::Relaxed);
        CALLS[i].fetch_add(1, Ordering::Relaxed);
    }
    out
}
