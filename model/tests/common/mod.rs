//! Helpers shared by the model's tests.

#![allow(dead_code, unused_imports)]

use std::path::PathBuf;

use burn::tensor::{Device, Tensor};
pub use model::tensor_file::max_errors as errors;

/// `../shared/fixtures` (or `$DENSETACT_FIXTURES`); the tests that read it are ignored unless
/// asked for (`--include-ignored`).
pub fn fixtures() -> PathBuf {
    sensor::shared::shared_dir("DENSETACT_FIXTURES", "fixtures")
}

/// A safetensors file whose tensors must exist (panics otherwise).
pub struct SafeFile(model::tensor_file::TensorFile);

impl SafeFile {
    pub fn open(path: &std::path::Path) -> Self {
        SafeFile(model::tensor_file::TensorFile::open(path).unwrap())
    }

    pub fn get(&self, name: &str) -> (Vec<f32>, Vec<usize>) {
        self.0.get(name).unwrap()
    }

    pub fn tensor<const D: usize>(&self, name: &str, device: &Device) -> Tensor<D> {
        self.0.tensor(name, device).unwrap()
    }
}

pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}
