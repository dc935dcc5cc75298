//! Which Burn backend runs where.
//!
//! On the CPU the default is burn-flex, built with its `x86-v4` feature (AVX-512 matrix kernels
//! chosen at run time, with a fallback on older CPUs): DenseDepth-161 forward at 480x640 took
//! 1.63 s with it, 3.5 s without, and 20.4 s on the deprecated burn-ndarray (field notes).

use burn::backend::{BackendTensor, DispatchAutodiffContext, DispatchTensor, DispatchTensorKind};
use burn::tensor::{DType, Device, Tensor, TensorData};
use burn_flex::FlexTensor;

/// The default device: flex on the CPU.
pub fn default_device() -> Device {
    Device::flex()
}

/// The flex tensor behind `x` when `x` is f32 on flex outside autodiff: where this crate's
/// inference kernels (`conv_forward`, `dense_block`, `norm_relu`, `pool`, `upsample`) replace
/// Burn's generic operations. Cheap: flex tensors share their storage.
pub(crate) fn flex_f32<const D: usize>(x: &Tensor<D>) -> Option<FlexTensor> {
    let tensor = x.clone().into_dispatch();
    match (tensor.kind, tensor.autodiff) {
        (DispatchTensorKind::Flex(BackendTensor::Float(t)), DispatchAutodiffContext::Disabled)
            if t.dtype() == DType::F32 =>
        {
            Some(contiguous(t))
        }
        _ => None,
    }
}

/// `Some(tracked)` when `device` is flex, plain or under autodiff; `None` for other backends.
pub(crate) fn flex_kind(device: &Device) -> Option<bool> {
    #[allow(unreachable_patterns)]
    match device.as_dispatch().clone() {
        burn::backend::DispatchDevice::Flex(_) => Some(false),
        #[cfg(feature = "autodiff")]
        d @ burn::backend::DispatchDevice::Autodiff(_) => {
            matches!(d.inner(), burn::backend::DispatchDevice::Flex(_)).then_some(true)
        }
        _ => None,
    }
}

/// A plain flex tensor back as a `Tensor`.
pub(crate) fn from_flex<const D: usize>(t: FlexTensor) -> Tensor<D> {
    Tensor::from_dispatch(DispatchTensor {
        kind: DispatchTensorKind::Flex(BackendTensor::Float(t)),
        autodiff: DispatchAutodiffContext::Disabled,
    })
}

/// `x` as one readable f32 slice: kept when it already is one, copied otherwise.
pub(crate) fn contiguous(x: FlexTensor) -> FlexTensor {
    if x.as_slice::<f32>().is_some() { x } else { x.to_contiguous() }
}

/// The values of a contiguous f32 flex tensor.
pub(crate) fn slice(x: &FlexTensor) -> &[f32] {
    x.as_slice().expect("a contiguous f32 tensor")
}

pub(crate) fn flex_tensor(values: Vec<f32>, shape: &[usize]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape.to_vec()))
}

/// The default wgpu adapter (a discrete GPU when there is one; Mesa's lavapipe on a CPU-only
/// machine with `mesa-vulkan-drivers`).
#[cfg(feature = "wgpu")]
pub fn wgpu_device() -> Device {
    Device::wgpu(burn::tensor::DeviceKind::DefaultDevice)
}

/// A device by its command-line name: `flex` (or `cpu`), and `wgpu` in builds with the `wgpu`
/// feature.
pub fn device(name: &str) -> Result<Device, String> {
    match name {
        "flex" | "cpu" => Ok(default_device()),
        #[cfg(feature = "wgpu")]
        "wgpu" => Ok(wgpu_device()),
        other => Err(format!(
            "unknown or unavailable device {other:?}: flex{}",
            if cfg!(feature = "wgpu") { ", wgpu" } else { " (wgpu needs a build with --features wgpu)" }
        )),
    }
}

/// burn-ndarray, deprecated in Burn 0.22 and about 12x slower than flex here; built only with
/// the `ndarray` feature, for comparisons.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
pub fn ndarray_device() -> Device {
    Device::ndarray()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flex_computes_a_matrix_product() {
        let device = default_device();
        let a = Tensor::<2>::from_floats([[1.0, 2.0], [3.0, 4.0]], &device);
        let b = Tensor::<2>::from_floats([[5.0, 6.0], [7.0, 8.0]], &device);
        let c: Vec<f32> = a.matmul(b).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(c, vec![19.0, 22.0, 43.0, 50.0]);
    }
}
