//! DenseDepth for DenseTact on Burn: a torchvision-compatible DenseNet encoder with
//! DenseDepth's skip-connection decoder, its loss, the depth scale, and PyTorch weight import.

pub mod backend;
pub mod batch_norm_train;
pub mod bundle;
pub mod config;
pub mod conv;
pub mod conv_forward;
pub mod decoder;
mod dense_block;
pub mod densedepth;
pub mod densenet;
pub mod gemm_conv;
pub mod import;
pub mod loss;
pub mod norm_relu;
pub mod pool;
pub mod scale;
pub mod tensor_file;
pub mod upsample;

pub use config::{DenseDepthConfig, DenseNetConfig};
pub use densedepth::DenseDepth;
pub use loss::{DepthLoss, DepthLossConfig};
pub use scale::{DepthScale, PAPER_NET_RANGE, UNIT_NET_RANGE};
pub use upsample::Upsample;
