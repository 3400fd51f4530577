//! Worker thread pools: a frame's pose instances ([`crate::pose::PoseEstimator::with_threads`])
//! and the segmenter's matrix products ([`crate::segment::Segmenter::with_threads`]).

use std::sync::Arc;

use crate::error::{Error, Result};

/// A rayon pool of `threads` workers named `{what}-N`, or `None` for one thread.
pub fn pool(threads: usize, what: &str) -> Result<Option<Arc<rayon::ThreadPool>>> {
    if threads <= 1 {
        return Ok(None);
    }
    let what = what.to_string();
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(move |i| format!("{what}-{i}"))
        .build()
        .map(|p| Some(Arc::new(p)))
        .map_err(|e| Error::InvalidArgument(format!("cannot start {threads} worker threads: {e}")))
}
