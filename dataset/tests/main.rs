//! The crate's integration tests, one module a file, built as one test binary: one link and
//! one copy of the generic code they share, instead of one a file (`Cargo.toml`: `autotests`).

mod analytic;
mod calibration;
mod common;
mod generator;
mod kit;
mod register;
mod safety;
mod session;
mod shard;
