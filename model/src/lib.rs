//! DenseDepth for DenseTact on Burn: a torchvision-compatible DenseNet encoder with
//! DenseDepth's skip-connection decoder, its loss, the depth scale, the exported bundle (the
//! contract with deployment) and PyTorch weight import.
//!
//! - `network`: the Burn modules, readable on their own; their layers call
//! - `kernels`: the flex CPU kernels (matrix-product convolutions, fused dense blocks, batch
//!   norms, pooling, upsampling), through one small interface; private to this crate;
//! - `input`: crops to the network's input (RGB, optionally the reference difference);
//! - `bundle`, `import`, `torch`, `onnx`, `tensor_file`: files in and out (PyTorch's names both
//!   ways, ONNX out);
//! - `loss`, `scale`: the training loss and the mm <-> network depth scale;
//! - `backend`: devices by name.

#![deny(unsafe_code)]

pub mod backend;
pub mod bundle;
pub mod import;
pub mod input;
mod kernels;
pub mod loss;
mod network;
pub mod onnx;
pub mod scale;
pub mod tensor_file;
pub mod torch;

pub use input::{InputChannels, InputEncoder, InputEncoding};
pub use loss::{DepthLoss, DepthLossConfig, FORCE_N_PER_LOSS_UNIT, ForceTargets};
pub use network::{
    Activation, ConfigError, Decoder, DenseBlock, DenseDepth, DenseDepthConfig, DenseLayer, DenseNetConfig,
    DenseNetEncoder, ForceHead, Heads, Preset, Skips, Transition, UpBlock, Upsample, fold_batch_norm,
    interpolation_matrix, upsample_bilinear, upsample_mode_for,
};
pub use scale::{DepthScale, PAPER_NET_RANGE, PRESSURE_KPA_PER_UNIT, ScaleError, UNIT_NET_RANGE};
