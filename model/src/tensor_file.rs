//! Named f32 tensors in a safetensors file (fixtures, example inputs and outputs).

use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};

#[derive(Debug, thiserror::Error)]
pub enum TensorFileError {
    #[error("{path}: {message}")]
    Bad { path: PathBuf, message: String },
}

/// A safetensors file held in memory.
pub struct TensorFile {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl TensorFile {
    pub fn open(path: &Path) -> Result<Self, TensorFileError> {
        let bad = |message: String| TensorFileError::Bad { path: path.into(), message };
        let bytes = std::fs::read(path).map_err(|e| bad(e.to_string()))?;
        safetensors::SafeTensors::deserialize(&bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
        Ok(TensorFile { path: path.into(), bytes })
    }

    /// Values and shape of the f32 tensor `name`.
    pub fn get(&self, name: &str) -> Result<(Vec<f32>, Vec<usize>), TensorFileError> {
        let bad = |message: String| TensorFileError::Bad { path: self.path.clone(), message };
        let st = safetensors::SafeTensors::deserialize(&self.bytes).map_err(|e| bad(e.to_string()))?;
        let t = st.tensor(name).map_err(|_| bad(format!("no tensor named {name:?}")))?;
        if t.dtype() != safetensors::Dtype::F32 {
            return Err(bad(format!("tensor {name:?} is {:?}, expected F32", t.dtype())));
        }
        let values = t.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        Ok((values, t.shape().to_vec()))
    }

    /// The tensor `name` on `device`, checking its rank.
    pub fn tensor<const D: usize>(&self, name: &str, device: &Device) -> Result<Tensor<D>, TensorFileError> {
        let (values, shape) = self.get(name)?;
        if shape.len() != D {
            let message = format!("tensor {name:?} has shape {shape:?}, expected rank {D}");
            return Err(TensorFileError::Bad { path: self.path.clone(), message });
        }
        Ok(Tensor::from_data(TensorData::new(values, shape), device))
    }
}

/// Largest absolute difference, and that relative to the largest reference magnitude.
pub fn max_errors(got: &[f32], want: &[f32]) -> (f32, f32) {
    assert_eq!(got.len(), want.len(), "compared tensors differ in size");
    let abs = got.iter().zip(want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    let scale = want.iter().map(|v| v.abs()).fold(0.0, f32::max).max(1e-12);
    (abs, abs / scale)
}
