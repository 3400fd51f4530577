//! NOCS evaluation metrics (in progress).
