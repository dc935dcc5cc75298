//! DenseDepth for DenseTact on Burn. This crate so far fixes the backend choice; the network,
//! its loss and the PyTorch import follow.

pub mod backend;
