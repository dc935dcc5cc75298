//! Plain flex tensors behind Burn's `Tensor`: where this crate's kernels take over from Burn's
//! generic operations (f32 on flex outside autodiff), and back.

use burn::backend::{BackendTensor, DispatchAutodiffContext, DispatchTensor, DispatchTensorKind};
use burn::tensor::{DType, Device, Tensor, TensorData};
use burn_flex::FlexTensor;

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
