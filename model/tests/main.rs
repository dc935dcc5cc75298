//! The crate's integration tests, one module a file, built as one test binary: one link and
//! one copy of the generic code they share, instead of one a file (`Cargo.toml`: `autotests`).

mod common;
mod import_cases;
mod loss_parity;
mod onnx;
mod pytorch_parity;
mod stress;
mod torch_names;
mod wgpu;
