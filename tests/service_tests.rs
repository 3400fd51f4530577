//! The pose service: the pipeline from the library (order, drops under a slow
//! stage, stop and drain, failing sources, HTTP) and `tricons serve` /
//! `tricons record` as a user runs them (signals, outputs, bad input).

mod common;

#[path = "service/cli.rs"]
mod cli;
#[path = "service/http.rs"]
mod http;
#[path = "service/pipeline.rs"]
mod pipeline;
