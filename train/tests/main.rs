//! The crate's integration tests, one module a file, built as one test binary: one link and
//! one copy of the generic code they share, instead of one a file (`Cargo.toml`: `autotests`).

mod common;
mod fit;
mod force;
#[path = "../../dataset/tests/common/kill.rs"]
mod kill;
mod parallel;
mod safety;
mod view;
