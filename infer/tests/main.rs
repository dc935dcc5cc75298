//! The crate's integration tests, one module a file, built as one test binary: one link and
//! one copy of the generic code they share, instead of one a file (`Cargo.toml`: `autotests`).

mod common;
mod force;
mod icp;
mod onnx_whole;
mod predict;
mod ros2;
mod stream;
mod view;
