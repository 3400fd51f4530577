//! `TriangleDescriptor`: the triangle-based geometric descriptor of PIGA.

pub mod kernel;
