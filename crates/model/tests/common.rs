//! Helpers shared by the model's tests: the fixture folder and safetensors reading.

#![allow(dead_code)]

use std::path::PathBuf;

use burn::tensor::{Device, Tensor, TensorData};

/// `../shared/fixtures` (or `$DENSETACT_FIXTURES`); `None` (test skipped) when absent outside CI.
pub fn fixtures() -> Option<PathBuf> {
    let dir = std::env::var_os("DENSETACT_FIXTURES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/fixtures")));
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(std::env::var_os("CI").is_none(), "CI must provide the fixtures at {}", dir.display());
    eprintln!("skipped: no fixtures at {}", dir.display());
    None
}

/// Reads named f32 tensors of a safetensors file.
pub struct SafeFile {
    bytes: Vec<u8>,
}

impl SafeFile {
    pub fn open(path: &std::path::Path) -> Self {
        SafeFile { bytes: std::fs::read(path).unwrap() }
    }

    pub fn get(&self, name: &str) -> (Vec<f32>, Vec<usize>) {
        let st = safetensors::SafeTensors::deserialize(&self.bytes).unwrap();
        let t = st.tensor(name).unwrap_or_else(|_| panic!("no tensor {name}"));
        assert_eq!(t.dtype(), safetensors::Dtype::F32);
        let v = t.data().chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        (v, t.shape().to_vec())
    }

    pub fn tensor<const D: usize>(&self, name: &str, device: &Device) -> Tensor<D> {
        let (v, shape) = self.get(name);
        Tensor::from_data(TensorData::new(v, shape), device)
    }
}

pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// Largest absolute difference, and that relative to the largest reference magnitude.
pub fn errors(got: &[f32], want: &[f32]) -> (f32, f32) {
    assert_eq!(got.len(), want.len());
    let abs = got.iter().zip(want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    let scale = want.iter().map(|v| v.abs()).fold(0.0, f32::max).max(1e-12);
    (abs, abs / scale)
}
