//! Convolutions that run as large matrix products on flex, forward and backward.
//!
//! On flex (f32) outside autodiff, `conv2d_act` calls `conv_forward` directly, with the layer's
//! bias and activation applied while the output is in cache. Under autodiff on flex, layers go
//! through a Burn backend extension whose forward and gradients are the same matrix products
//! (`gemm_conv`), with a handwritten backward; strided ones too (the stem: taking it off
//! Burn's lowering of the weight gradient took a fifth off the quickstart's training step).
//! Every other case (other backends, dtypes, dilation, groups) is Burn's own
//! `Conv2d::forward`, so results agree everywhere within float rounding.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Flex, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::tensor::activation::{leaky_relu, relu};
use burn::tensor::{DType, Tensor};
use burn_flex::FlexTensor;

use super::conv_forward;
use super::flex::{contiguous, flex_f32, flex_kind, flex_tensor, from_flex, slice};
use super::gemm_conv;
use super::shared::{Activation, ConvShape, Epilogue};

/// A square-kernel convolution with the same padding on every side and the same stride along
/// both axes.
#[backend_extension(Flex, Autodiff: cfg(feature = "autodiff"))]
pub trait GemmConvBackend: Backend {
    /// `x` [batch, in, h, w] with `weight` [out, in, k, k].
    fn gemm_conv2d(x: FloatTensor<Self>, weight: FloatTensor<Self>, padding: usize, stride: usize)
    -> FloatTensor<Self>;
    /// The same plus `bias` [out] (the extension takes no optional tensors).
    fn gemm_conv2d_bias(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        padding: usize,
        stride: usize,
    ) -> FloatTensor<Self>;
}

/// The gradients a backend computes for `GemmConvBackend`'s autodiff form.
pub trait GemmConvGrads: GemmConvBackend {
    /// The input's gradient, for an input of `size` ([height, width]: a strided convolution's
    /// output does not tell the rows and columns its last step left out).
    fn gemm_conv2d_input_grad(
        grad: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        size: [usize; 2],
        padding_stride: [usize; 2],
    ) -> FloatTensor<Self>;
    fn gemm_conv2d_weight_grad(
        x: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        kernel: usize,
        padding_stride: [usize; 2],
    ) -> FloatTensor<Self>;
}

fn shape_of(x: &FlexTensor, weight_dims: [usize; 2], kernel: usize, padding: usize, stride: usize) -> ConvShape {
    let dims = x.layout().shape();
    ConvShape {
        batch: dims[0],
        channels_in: weight_dims[1],
        channels_out: weight_dims[0],
        height: dims[2],
        width: dims[3],
        kernel,
        padding,
        stride,
    }
}

/// The convolution on flex tensors, with the bias and activation as its epilogue; `keep`: the
/// weight's Winograd transform kept between calls (inference; a training step's weights change
/// every step).
fn flex_conv(
    x: FlexTensor,
    weight: FlexTensor,
    bias: Option<FlexTensor>,
    [padding, stride]: [usize; 2],
    activation: Activation,
    keep: bool,
) -> FlexTensor {
    let (x, weight, bias) = (contiguous(x), contiguous(weight), bias.map(contiguous));
    let w = weight.layout().shape();
    let s = shape_of(&x, [w[0], w[1]], w[2], padding, stride);
    let epilogue = Epilogue::bias(bias.as_ref().map(slice), activation);
    let out = conv_forward::forward_with(slice(&x), slice(&weight), &s, None, &epilogue, keep);
    flex_tensor(out, &[s.batch, s.channels_out, s.out_height(), s.out_width()])
}

impl GemmConvBackend for Flex {
    fn gemm_conv2d(x: FlexTensor, weight: FlexTensor, padding: usize, stride: usize) -> FlexTensor {
        flex_conv(x, weight, None, [padding, stride], Activation::Identity, false)
    }

    fn gemm_conv2d_bias(
        x: FlexTensor,
        weight: FlexTensor,
        bias: FlexTensor,
        padding: usize,
        stride: usize,
    ) -> FlexTensor {
        flex_conv(x, weight, Some(bias), [padding, stride], Activation::Identity, false)
    }
}

impl GemmConvGrads for Flex {
    fn gemm_conv2d_input_grad(
        grad: FlexTensor,
        weight: FlexTensor,
        [height, width]: [usize; 2],
        [padding, stride]: [usize; 2],
    ) -> FlexTensor {
        let (grad, weight) = (contiguous(grad), contiguous(weight));
        let (w, g) = (weight.layout().shape(), grad.layout().shape());
        let s = ConvShape {
            batch: g[0],
            channels_in: w[1],
            channels_out: w[0],
            height,
            width,
            kernel: w[2],
            padding,
            stride,
        };
        assert_eq!([g[2], g[3]], [s.out_height(), s.out_width()], "conv output gradient's size");
        let dx = gemm_conv::input_grad(slice(&grad), slice(&weight), &s);
        flex_tensor(dx, &[s.batch, s.channels_in, s.height, s.width])
    }

    fn gemm_conv2d_weight_grad(
        x: FlexTensor,
        grad: FlexTensor,
        kernel: usize,
        [padding, stride]: [usize; 2],
    ) -> FlexTensor {
        let (x, grad) = (contiguous(x), contiguous(grad));
        let channels = [grad.layout().shape()[1], x.layout().shape()[1]];
        let s = shape_of(&x, channels, kernel, padding, stride);
        let dw = gemm_conv::weight_grad(slice(&x), slice(&grad), &s);
        flex_tensor(dw, &[s.channels_out, s.channels_in, kernel, kernel])
    }
}

#[cfg(feature = "autodiff")]
mod autodiff {
    use burn::backend::TensorMetadata;
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::autodiff::{Autodiff, NodeId};
    use burn::backend::ops::FloatTensorOps;
    use burn::backend::tensor::FloatTensor;

    use super::{GemmConvBackend, GemmConvGrads};

    #[derive(Debug)]
    struct GemmConvBackward;

    impl<B: GemmConvGrads> Backward<B, 2> for GemmConvBackward {
        /// Checkpointed input and weight, and the padding and stride.
        type State = (NodeId, NodeId, [usize; 2]);

        fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, checkpointer: &mut Checkpointer) {
            let [node_x, node_weight] = ops.parents;
            let grad = grads.consume::<B>(&ops.node);
            let (x_state, weight_state, padding_stride) = ops.state;
            let x = checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(x_state);
            let weight = checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(weight_state);
            let kernel = weight.shape().dims::<4>()[2];
            let [_, _, height, width] = x.shape().dims::<4>();
            if let Some(node) = node_weight {
                grads.register::<B>(node.id, B::gemm_conv2d_weight_grad(x, grad.clone(), kernel, padding_stride));
            }
            if let Some(node) = node_x {
                grads.register::<B>(node.id, B::gemm_conv2d_input_grad(grad, weight, [height, width], padding_stride));
            }
        }
    }

    impl<B: GemmConvGrads, C: CheckpointStrategy> GemmConvBackend for Autodiff<B, C> {
        fn gemm_conv2d(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            padding: usize,
            stride: usize,
        ) -> FloatTensor<Self> {
            match GemmConvBackward.prepare::<C>([x.node(), weight.node()]).compute_bound().stateful() {
                OpsKind::Tracked(mut prep) => {
                    let x_state = prep.checkpoint(&x);
                    let weight_state = prep.checkpoint(&weight);
                    let out = B::gemm_conv2d(x.into_primitive(), weight.into_primitive(), padding, stride);
                    prep.finish((x_state, weight_state, [padding, stride]), out)
                }
                OpsKind::UnTracked(prep) => {
                    prep.finish(B::gemm_conv2d(x.into_primitive(), weight.into_primitive(), padding, stride))
                }
            }
        }

        /// The bias through autodiff's own broadcast add: its gradient is a plain sum.
        fn gemm_conv2d_bias(
            x: FloatTensor<Self>,
            weight: FloatTensor<Self>,
            bias: FloatTensor<Self>,
            padding: usize,
            stride: usize,
        ) -> FloatTensor<Self> {
            let channels = bias.shape().num_elements();
            let out = Self::gemm_conv2d(x, weight, padding, stride);
            Self::float_add(out, Self::float_reshape(bias, [1, channels, 1, 1].into()))
        }
    }
}

/// The padding when it is the same on every side (`Same` is left to Burn).
pub(crate) fn symmetric_padding(padding: &PaddingConfig2d) -> Option<usize> {
    match padding {
        PaddingConfig2d::Valid => Some(0),
        PaddingConfig2d::Explicit(top, left, bottom, right) if [left, bottom, right].iter().all(|p| *p == top) => {
            Some(*top)
        }
        _ => None,
    }
}

/// The padding and stride of `conv` when the matrix-product path can run it on `x`: flex
/// (directly or under autodiff), f32, dilation 1, one group, a square kernel, equal padding on
/// every side no larger than `kernel - 1`, the same stride along both axes.
pub(crate) fn gemm_padding(conv: &Conv2d, x: &Tensor<4>) -> Option<(usize, usize)> {
    let on_flex = flex_kind(&x.device()).is_some();
    let [k, k2] = conv.kernel_size;
    let padding = symmetric_padding(&conv.padding)?;
    let [stride, stride2] = conv.stride;
    let strided_ok = stride == stride2 && stride >= 1;
    let plain = strided_ok && conv.dilation == [1, 1] && conv.groups == 1 && k == k2 && padding < k;
    let f32s = x.dtype() == DType::F32 && conv.weight.val().dtype() == DType::F32;
    let [_, _, h, w] = x.dims();
    (on_flex && plain && f32s && h + 2 * padding >= k && w + 2 * padding >= k).then_some((padding, stride))
}

/// `activation(conv.forward(x))`; on plain flex the activation rides in the convolution.
pub(crate) fn conv2d_act(conv: &Conv2d, x: Tensor<4>, activation: Activation) -> Tensor<4> {
    let Some((padding, stride)) = gemm_padding(conv, &x) else {
        return activate(conv.forward(x), activation);
    };
    // A bias that is not plain f32 flex sends the layer to the autodiff path, never drops out.
    if let (Some(input), Some(weight), Some(bias)) = (flex_f32(&x), flex_f32(&conv.weight.val()), flex_bias(conv)) {
        return from_flex(flex_conv(input, weight, bias, [padding, stride], activation, true));
    }
    type D = burn::backend::Dispatch;
    let (x, weight) = (x.into_dispatch(), conv.weight.val().into_dispatch());
    activate(
        Tensor::from_dispatch(match &conv.bias {
            Some(bias) => {
                <D as GemmConvBackend>::gemm_conv2d_bias(x, weight, bias.val().into_dispatch(), padding, stride)
            }
            None => <D as GemmConvBackend>::gemm_conv2d(x, weight, padding, stride),
        }),
        activation,
    )
}

/// `conv`'s bias as a plain f32 flex tensor: `Some(None)` when it has none, `None` when it is
/// not plain f32 flex.
pub(crate) fn flex_bias(conv: &Conv2d) -> Option<Option<FlexTensor>> {
    match &conv.bias {
        Some(b) => flex_f32(&b.val()).map(Some),
        None => Some(None),
    }
}

/// The activation through Burn's operations.
fn activate(x: Tensor<4>, activation: Activation) -> Tensor<4> {
    match activation {
        Activation::Identity => x,
        Activation::Relu => relu(x),
        Activation::Leaky(slope) => leaky_relu(x, slope),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::Conv2dConfig;

    fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
        conv2d_act(conv, x, Activation::Identity)
    }
    use burn::tensor::{Device, Distribution, Tolerance};

    fn layers(device: &Device) -> Vec<Conv2d> {
        let explicit = |p| PaddingConfig2d::Explicit(p, p, p, p);
        vec![
            Conv2dConfig::new([6, 4], [3, 3]).with_padding(explicit(1)).init(device),
            Conv2dConfig::new([6, 5], [1, 1]).with_bias(false).init(device),
            Conv2dConfig::new([3, 2], [3, 3]).with_padding(PaddingConfig2d::Valid).with_bias(false).init(device),
            // DenseNet's stem: 7x7, stride 2, padding 3.
            Conv2dConfig::new([6, 4], [7, 7]).with_stride([2, 2]).with_padding(explicit(3)).init(device),
            // Stride 3 over a width it does not divide: the gather's phases of unequal use.
            Conv2dConfig::new([2, 3], [5, 5]).with_stride([3, 3]).with_padding(explicit(2)).init(device),
            // A stride longer than the kernel, which skips inputs altogether.
            Conv2dConfig::new([3, 4], [1, 1]).with_stride([2, 2]).init(device),
        ]
    }

    #[test]
    fn only_plain_layers_on_flex_take_the_matrix_path() {
        let device = crate::backend::default_device();
        let x = Tensor::<4>::zeros([1, 6, 8, 8], &device);
        let [same, pointwise, valid, strided, _, _] = <[Conv2d; 6]>::try_from(layers(&device)).unwrap();
        assert_eq!(gemm_padding(&same, &x), Some((1, 1)));
        assert_eq!(gemm_padding(&pointwise, &x), Some((0, 1)));
        assert_eq!(gemm_padding(&valid, &x.clone().slice([0..1, 0..3, 0..8, 0..8])), Some((0, 1)));
        // Strided layers too, under autodiff as well: their backward is this crate's.
        assert_eq!(gemm_padding(&strided, &x), Some((3, 2)));
        #[cfg(feature = "autodiff")]
        assert_eq!(gemm_padding(&strided, &Tensor::<4>::zeros([1, 6, 8, 8], &device.clone().autodiff())), Some((3, 2)));
        let uneven = Conv2dConfig::new([6, 4], [3, 3]).with_stride([2, 1]).init(&device);
        assert_eq!(gemm_padding(&uneven, &x), None);
        let lopsided =
            Conv2dConfig::new([6, 4], [3, 3]).with_padding(PaddingConfig2d::Explicit(1, 0, 1, 0)).init(&device);
        assert_eq!(gemm_padding(&lopsided, &x), None);
        assert_eq!(gemm_padding(&same, &x.clone().cast(DType::F16)), None);
    }

    #[test]
    fn forward_equals_burns_convolution() {
        let device = crate::backend::default_device();
        for conv in layers(&device) {
            let [_, c, _, _] = conv.weight.dims();
            for [h, w] in [[7, 9], [16, 14], [5, 6]] {
                let x = Tensor::<4>::random([2, c, h, w], Distribution::Normal(0.0, 1.0), &device);
                conv2d(&conv, x.clone())
                    .into_data()
                    .assert_approx_eq::<f32>(&conv.forward(x).into_data(), Tolerance::rel_abs(1e-4, 1e-5));
            }
        }
    }

    /// The handwritten backward against Burn's autodiff of its own convolution: input, weight
    /// and bias gradients of the same loss, strided layers included (the 7x9 input leaves
    /// rows and columns that a stride's last step does not reach).
    #[cfg(feature = "autodiff")]
    #[test]
    fn gradients_equal_burns_autodiff() {
        let device = crate::backend::default_device().autodiff();
        for conv in layers(&device) {
            let [_, c, _, _] = conv.weight.dims();
            let x = Tensor::<4>::random([2, c, 7, 9], Distribution::Normal(0.0, 1.0), &device).require_grad();
            assert!(gemm_padding(&conv, &x).is_some(), "autodiff on flex takes the matrix path");
            let probe = Tensor::<4>::random(conv.forward(x.clone()).dims(), Distribution::Normal(0.0, 1.0), &device);
            let mine = (conv2d(&conv, x.clone()) * probe.clone()).sum().backward();
            let theirs = (conv.forward(x.clone()) * probe).sum().backward();
            let tol = Tolerance::rel_abs(1e-4, 1e-4);
            x.grad(&mine).unwrap().into_data().assert_approx_eq::<f32>(&x.grad(&theirs).unwrap().into_data(), tol);
            let (w_mine, w_theirs) = (conv.weight.grad(&mine).unwrap(), conv.weight.grad(&theirs).unwrap());
            w_mine.into_data().assert_approx_eq::<f32>(&w_theirs.into_data(), tol);
            if let Some(bias) = &conv.bias {
                bias.grad(&mine)
                    .unwrap()
                    .into_data()
                    .assert_approx_eq::<f32>(&bias.grad(&theirs).unwrap().into_data(), tol);
            }
        }
    }
}
