//! `ScatterElements` (ONNX standard op, `reduction = "none"`): tract's own evaluates
//! every element through a dynamic-rank coordinate (`indexed_iter`), which made the
//! Mask R-CNN's multi-scale RoI pooling (one scatter of `(R, 256, 7, 7)` per FPN level)
//! a third of a frame. This one walks the updates row by row with precomputed strides.
//! Same results as tract's (later updates win on duplicate indices; negative indices
//! count from the end); an index out of range is an error, not a panic. Other reductions
//! and element types stay with tract ([`onnx`]).
//!
//! `ScatterRows` (domain `ai.tricons`) is the same scatter along axis 0 when every
//! element of an update row has one index (torchvision's level merge: `Expand` of a
//! `(R, 1, 1, 1)` row index): the Mask R-CNN loader's rewrite puts it in, and it copies
//! whole rows without the broadcast index tensor (8 bytes per scattered value).

pub mod kernel;
pub mod onnx;
pub mod tract_op;

pub use kernel::{scatter_elements, scatter_elements_reference, scatter_rows};
pub use onnx::{ScatterElements, ScatterRows};
