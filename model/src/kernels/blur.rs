//! The loss's separable window (SSIM's 11x11 Gaussian, the masked SSIM's window count) on flex:
//! a pass along the rows and a pass down the columns as plain loops, forward and backward.
//!
//! Through Burn, each pass is a one-channel convolution lowered to a thin matrix product, and
//! its gradient a transposed convolution: together about half of the quickstart's loss and a
//! twentieth of its training step (BENCHMARKS.md). Here the gradient is the same two passes
//! run backwards (each output spreads back over the inputs its window read), through a backend
//! extension with a handwritten backward, as `conv` does for the convolutions.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Flex, backend_extension};
use burn::tensor::{DType, Tensor, TensorData};
use burn_flex::FlexTensor;
use rayon::prelude::*;

use super::flex::{contiguous, flex_kind, flex_tensor, slice};

/// `x` [n, 1, h, w] convolved without padding with the outer product of a window's column taps
/// (down the rows) and row taps (along them), given as one tensor `[column, row]` of 2k values:
/// [n, 1, h - k + 1, w - k + 1].
#[backend_extension(Flex, Autodiff: cfg(feature = "autodiff"))]
pub trait BlurBackend: Backend {
    fn separable_blur(x: FloatTensor<Self>, taps: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// The gradient `BlurBackend`'s autodiff form needs: the input's, for an input of [h, w].
pub trait BlurGrads: BlurBackend {
    fn separable_blur_grad(grad: FloatTensor<Self>, taps: FloatTensor<Self>, size: [usize; 2]) -> FloatTensor<Self>;
}

/// One window's taps, split from the `[column, row]` tensor.
fn split(taps: &FlexTensor) -> (&[f32], &[f32]) {
    let taps = slice(taps);
    taps.split_at(taps.len() / 2)
}

/// `dst += tap * src` over their common length: each pass's step, one tap of one row.
fn add_scaled(dst: &mut [f32], src: &[f32], tap: f32) {
    dst.iter_mut().zip(src).for_each(|(d, v)| *d += tap * v);
}

/// The forward on plain slices: `x` is `maps` planes of [h, w]; each plane's output is
/// [h - k + 1, w - k + 1]. The row pass runs first, as Burn's pair of convolutions does.
fn forward(x: &[f32], [h, w]: [usize; 2], column: &[f32], row: &[f32]) -> Vec<f32> {
    let k = row.len();
    let (ho, wo) = (h + 1 - k, w + 1 - k);
    let mut out = vec![0.0f32; x.len() / (h * w) * ho * wo];
    out.par_chunks_mut(ho * wo).zip(x.par_chunks(h * w)).for_each(|(out, plane)| {
        let mut along = vec![0.0f32; h * wo];
        for (dst, src) in along.chunks_exact_mut(wo).zip(plane.chunks_exact(w)) {
            for (b, tap) in row.iter().enumerate() {
                add_scaled(dst, &src[b..], *tap);
            }
        }
        for (i, dst) in out.chunks_exact_mut(wo).enumerate() {
            for (a, tap) in column.iter().enumerate() {
                add_scaled(dst, &along[(i + a) * wo..][..wo], *tap);
            }
        }
    });
    out
}

/// The forward's adjoint: `grad` is `maps` planes of [h - k + 1, w - k + 1], the result [h, w]
/// planes, each output's gradient spread over the inputs its window read with the same taps.
fn backward(grad: &[f32], [h, w]: [usize; 2], column: &[f32], row: &[f32]) -> Vec<f32> {
    let k = row.len();
    let (ho, wo) = (h + 1 - k, w + 1 - k);
    let mut dx = vec![0.0f32; grad.len() / (ho * wo) * h * w];
    dx.par_chunks_mut(h * w).zip(grad.par_chunks(ho * wo)).for_each(|(dx, g)| {
        let mut along = vec![0.0f32; h * wo];
        for (i, src) in g.chunks_exact(wo).enumerate() {
            for (a, tap) in column.iter().enumerate() {
                add_scaled(&mut along[(i + a) * wo..][..wo], src, *tap);
            }
        }
        for (dst, src) in dx.chunks_exact_mut(w).zip(along.chunks_exact(wo)) {
            for (b, tap) in row.iter().enumerate() {
                add_scaled(&mut dst[b..][..wo], src, *tap);
            }
        }
    });
    dx
}

impl BlurBackend for Flex {
    fn separable_blur(x: FlexTensor, taps: FlexTensor) -> FlexTensor {
        let (x, taps) = (contiguous(x), contiguous(taps));
        let [n, c, h, w] = <[usize; 4]>::try_from(x.layout().shape().to_vec()).expect("a 4-d input");
        let (column, row) = split(&taps);
        let k = row.len();
        flex_tensor(forward(slice(&x), [h, w], column, row), &[n, c, h + 1 - k, w + 1 - k])
    }
}

impl BlurGrads for Flex {
    fn separable_blur_grad(grad: FlexTensor, taps: FlexTensor, [h, w]: [usize; 2]) -> FlexTensor {
        let (grad, taps) = (contiguous(grad), contiguous(taps));
        let dims = grad.layout().shape().to_vec();
        let (column, row) = split(&taps);
        flex_tensor(backward(slice(&grad), [h, w], column, row), &[dims[0], dims[1], h, w])
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
    use burn::backend::tensor::FloatTensor;

    use super::{BlurBackend, BlurGrads};

    #[derive(Debug)]
    struct BlurBackward;

    impl<B: BlurGrads> Backward<B, 1> for BlurBackward {
        /// The checkpointed taps and the input's [h, w].
        type State = (NodeId, [usize; 2]);

        fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, checkpointer: &mut Checkpointer) {
            let [node_x] = ops.parents;
            let grad = grads.consume::<B>(&ops.node);
            let (taps_state, size) = ops.state;
            let taps = checkpointer.retrieve_node_output::<B::FloatTensorPrimitive>(taps_state);
            if let Some(node) = node_x {
                grads.register::<B>(node.id, B::separable_blur_grad(grad, taps, size));
            }
        }
    }

    impl<B: BlurGrads, C: CheckpointStrategy> BlurBackend for Autodiff<B, C> {
        fn separable_blur(x: FloatTensor<Self>, taps: FloatTensor<Self>) -> FloatTensor<Self> {
            let [_, _, h, w] = x.shape().dims::<4>();
            match BlurBackward.prepare::<C>([x.node()]).compute_bound().stateful() {
                OpsKind::Tracked(mut prep) => {
                    let taps_state = prep.checkpoint(&taps);
                    let out = B::separable_blur(x.into_primitive(), taps.into_primitive());
                    prep.finish((taps_state, [h, w]), out)
                }
                OpsKind::UnTracked(prep) => prep.finish(B::separable_blur(x.into_primitive(), taps.into_primitive())),
            }
        }
    }
}

/// `x` ([n, 1, h, w], f32 on flex, plain or under autodiff) convolved without padding with the
/// outer product of `column` and `row` (equal lengths); `None` elsewhere, where the caller runs
/// Burn's convolutions.
pub(crate) fn separable(x: &Tensor<4>, column: &[f32], row: &[f32]) -> Option<Tensor<4>> {
    let [_, c, h, w] = x.dims();
    let k = row.len();
    let fits = c == 1 && column.len() == k && k >= 1 && h >= k && w >= k;
    if !fits || flex_kind(&x.device()).is_none() || x.dtype() != DType::F32 {
        return None;
    }
    let taps = [column, row].concat();
    let taps = Tensor::<1>::from_data(TensorData::new(taps, [2 * k]), &x.device());
    type D = burn::backend::Dispatch;
    Some(Tensor::from_dispatch(<D as BlurBackend>::separable_blur(x.clone().into_dispatch(), taps.into_dispatch())))
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Distribution, Tolerance};

    use super::*;

    const COLUMN: [f32; 3] = [0.2, 0.5, 0.3];
    const ROW: [f32; 3] = [1.0, -0.5, 0.25];

    fn random(n: usize, seed: u64) -> Vec<f32> {
        let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
            })
            .collect()
    }

    /// The window by its definition, in f64: each output is the sum over the k x k window of
    /// column tap x row tap x input.
    #[test]
    fn the_window_is_the_outer_product_of_its_taps() {
        let ([h, w], k, maps) = ([9, 13], ROW.len(), 2);
        let x = random(maps * h * w, 1);
        let out = forward(&x, [h, w], &COLUMN, &ROW);
        let (ho, wo) = (h + 1 - k, w + 1 - k);
        assert_eq!(out.len(), maps * ho * wo);
        for m in 0..maps {
            for i in 0..ho {
                for j in 0..wo {
                    let mut want = 0.0f64;
                    for a in 0..k {
                        for b in 0..k {
                            want += (COLUMN[a] * ROW[b]) as f64 * x[(m * h + i + a) * w + j + b] as f64;
                        }
                    }
                    let got = out[(m * ho + i) * wo + j] as f64;
                    assert!((got - want).abs() < 1e-6, "map {m} ({i}, {j}): {got} against {want}");
                }
            }
        }
    }

    /// The backward is the forward's adjoint: <forward(x), g> = <x, backward(g)>.
    #[test]
    fn the_gradient_is_the_forwards_adjoint() {
        let ([h, w], k, maps) = ([11, 7], ROW.len(), 3);
        let x = random(maps * h * w, 2);
        let g = random(maps * (h + 1 - k) * (w + 1 - k), 3);
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(a, b)| (a * b) as f64).sum::<f64>();
        let (left, right) =
            (dot(&forward(&x, [h, w], &COLUMN, &ROW), &g), dot(&x, &backward(&g, [h, w], &COLUMN, &ROW)));
        assert!((left - right).abs() < 1e-5 * left.abs().max(1.0), "{left} against {right}");
    }

    /// Burn's two one-channel convolutions: the loss's path everywhere else.
    fn burns(x: Tensor<4>) -> Tensor<4> {
        crate::loss::separable_by_convs(x, &COLUMN, &ROW)
    }

    #[test]
    fn flex_takes_one_channel_and_equals_burns_convolutions() {
        let device = crate::backend::default_device();
        let x = Tensor::<4>::random([3, 1, 10, 12], Distribution::Normal(0.0, 1.0), &device);
        let mine = separable(&x, &COLUMN, &ROW).expect("flex f32 takes the kernel");
        mine.into_data().assert_approx_eq::<f32>(&burns(x).into_data(), Tolerance::rel_abs(1e-5, 1e-6));
        let two = Tensor::<4>::zeros([1, 2, 10, 12], &device);
        assert!(separable(&two, &COLUMN, &ROW).is_none(), "one channel only");
        let small = Tensor::<4>::zeros([1, 1, 2, 12], &device);
        assert!(separable(&small, &COLUMN, &ROW).is_none(), "no window fits");
    }

    #[cfg(feature = "autodiff")]
    #[test]
    fn the_gradient_equals_burns_autodiff() {
        let device = crate::backend::default_device().autodiff();
        let x = Tensor::<4>::random([2, 1, 9, 14], Distribution::Normal(0.0, 1.0), &device).require_grad();
        let probe = Tensor::<4>::random([2, 1, 7, 12], Distribution::Normal(0.0, 1.0), &device);
        let mine = (separable(&x, &COLUMN, &ROW).expect("autodiff on flex takes the kernel") * probe.clone()).sum();
        let theirs = (burns(x.clone()) * probe).sum();
        let tol = Tolerance::rel_abs(1e-5, 1e-6);
        mine.clone().into_data().assert_approx_eq::<f32>(&theirs.clone().into_data(), tol);
        let (mine, theirs) = (mine.backward(), theirs.backward());
        x.grad(&mine).unwrap().into_data().assert_approx_eq::<f32>(&x.grad(&theirs).unwrap().into_data(), tol);
    }
}
