//! Training-mode `relu(batch_norm(x))` on flex under autodiff, as one operation.
//!
//! Burn's training batch norm computes the batch statistics and the normalisation out of
//! generic tensor operations (about eight passes over the input forward, ten backward), and the
//! ReLU after it is two more. DenseNet normalises its whole growing feature stack in every layer,
//! so these passes are a large share of a train step's memory traffic. Here the statistics are
//! one pass, the normalisation with its ReLU one more, and the backward two (per-channel sums,
//! then the input gradient), with the standard batch-norm gradient:
//! `dx = gamma * rstd * (g - mean(g) - xhat * mean(g * xhat))` where `g` is the output gradient
//! masked by the ReLU. Running statistics are updated as Burn's `BatchNorm` does.

use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Flex, backend_extension};
use burn::nn::BatchNorm;
use burn::tensor::{DType, Tensor};
use burn_flex::FlexTensor;
use rayon::prelude::*;

use super::flex::{contiguous, flex_kind, flex_tensor, slice};

#[backend_extension(Flex, Autodiff: cfg(feature = "autodiff"))]
pub trait BatchNormReluBackend: Backend {
    /// The batch's per-channel mean and biased variance of `x` [batch, channels, ...], as
    /// [2, channels]. Not differentiated (the next operation's backward accounts for them).
    fn batch_stats(x: FloatTensor<Self>) -> FloatTensor<Self>;
    /// `max(0, gamma * (x - mean) / sqrt(var + epsilon) + beta)` with `stats` from `batch_stats`.
    fn batch_norm_relu(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        epsilon: f64,
    ) -> FloatTensor<Self>;
}

/// The gradients of `batch_norm_relu` for `x`, `gamma` and `beta`, given the output's.
pub trait BatchNormReluGrads: BatchNormReluBackend {
    fn batch_norm_relu_backward(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        epsilon: f64,
        grad: FloatTensor<Self>,
    ) -> [FloatTensor<Self>; 3];
}

/// Channels and elements per plane of `x` [batch, channels, ...].
fn layout(x: &FlexTensor) -> (Vec<usize>, usize, usize) {
    let dims = x.layout().shape().to_vec();
    let plane = dims[2..].iter().product();
    let channels = dims[1];
    (dims, channels, plane)
}

/// Per channel: the planes of that channel, image after image.
fn channel_planes(x: &[f32], channels: usize, plane: usize, c: usize) -> impl Iterator<Item = &[f32]> {
    x.chunks_exact(plane.max(1)).skip(c).step_by(channels.max(1))
}

/// Independent f32 accumulators in `lane_sums`, which the compiler keeps in vector registers.
const LANES: usize = 16;
/// Elements per lane summed in f32 before the partial sums move to f64: few enough that f32
/// rounding stays near 1e-6 relative, the total then as exact as a plain f64 sum.
const BLOCK: usize = LANES * 64;

/// `sum f(a[i], b[i])` for both of `f`'s outputs, in f64. A plain f64 sum is one serial chain of
/// dependent additions (a few cycles per element, unvectorised); this keeps the per-element work
/// in f32 lanes and gathers each block into f64.
#[inline(always)]
fn lane_sums(a: &[f32], b: &[f32], f: impl Fn(f32, f32) -> [f32; 2]) -> [f64; 2] {
    let mut total = [0.0f64; 2];
    for (a, b) in a.chunks(BLOCK).zip(b.chunks(BLOCK)) {
        let mut acc = [[0.0f32; LANES]; 2];
        let (a_lanes, b_lanes) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
        let (a_rest, b_rest) = (a_lanes.remainder(), b_lanes.remainder());
        for (a, b) in a_lanes.zip(b_lanes) {
            for l in 0..LANES {
                let [p, q] = f(a[l], b[l]);
                acc[0][l] += p;
                acc[1][l] += q;
            }
        }
        for (l, (a, b)) in a_rest.iter().zip(b_rest).enumerate() {
            let [p, q] = f(*a, *b);
            acc[0][l] += p;
            acc[1][l] += q;
        }
        for (t, lanes) in total.iter_mut().zip(&acc) {
            *t += lanes.iter().map(|v| *v as f64).sum::<f64>();
        }
    }
    total
}

/// Per channel `(scale, shift)` with `y = x * scale + shift`, and `rstd`.
fn affine(gamma: &[f32], beta: &[f32], stats: &[f32], epsilon: f64) -> Vec<(f32, f32, f32)> {
    let channels = gamma.len();
    (0..channels)
        .map(|c| {
            let (mean, var) = (stats[c], stats[channels + c]);
            let rstd = (1.0 / (var as f64 + epsilon).sqrt()) as f32;
            let scale = gamma[c] * rstd;
            (scale, beta[c] - mean * scale, rstd)
        })
        .collect()
}

impl BatchNormReluBackend for Flex {
    fn batch_stats(x: FlexTensor) -> FlexTensor {
        let x = contiguous(x);
        let (_, channels, plane) = layout(&x);
        let values = slice(&x);
        let count = (values.len() / channels.max(1)).max(1) as f64;
        let per_channel: Vec<(f32, f32)> = (0..channels)
            .into_par_iter()
            .map(|c| {
                let planes = || channel_planes(values, channels, plane, c);
                let sum: f64 = planes().map(|p| lane_sums(p, p, |v, _| [v, 0.0])[0]).sum();
                let mean = (sum / count) as f32;
                // Centred second pass: no cancellation for large means.
                let squares: f64 = planes().map(|p| lane_sums(p, p, |v, _| [(v - mean) * (v - mean), 0.0])[0]).sum();
                (mean, (squares / count) as f32)
            })
            .collect();
        let (means, vars): (Vec<f32>, Vec<f32>) = per_channel.into_iter().unzip();
        flex_tensor([means, vars].concat(), &[2, channels])
    }

    fn batch_norm_relu(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        stats: FlexTensor,
        epsilon: f64,
    ) -> FlexTensor {
        let (x, gamma, beta, stats) = (contiguous(x), contiguous(gamma), contiguous(beta), contiguous(stats));
        let coefficients = affine(slice(&gamma), slice(&beta), slice(&stats), epsilon);
        let (scale, shift): (Vec<f32>, Vec<f32>) = coefficients.iter().map(|&(s, t, _)| (s, t)).unzip();
        super::norm_relu::scale_shift_relu_flex(&x, &scale, &shift)
    }
}

impl BatchNormReluGrads for Flex {
    fn batch_norm_relu_backward(
        x: FlexTensor,
        gamma: FlexTensor,
        beta: FlexTensor,
        stats: FlexTensor,
        epsilon: f64,
        grad: FlexTensor,
    ) -> [FlexTensor; 3] {
        let (x, grad) = (contiguous(x), contiguous(grad));
        let (gamma, beta, stats) = (contiguous(gamma), contiguous(beta), contiguous(stats));
        let (dims, channels, plane) = layout(&x);
        let (values, dy) = (slice(&x), slice(&grad));
        let coefficients = affine(slice(&gamma), slice(&beta), slice(&stats), epsilon);
        let means = &slice(&stats)[..channels];
        let count = (values.len() / channels.max(1)).max(1) as f64;
        // Pass 1, per channel: sum(g) and sum(g * xhat), g the output gradient where y > 0.
        let sums: Vec<(f64, f64)> = (0..channels)
            .into_par_iter()
            .map(|c| {
                let (scale, shift, rstd) = coefficients[c];
                let mean = means[c];
                let [sg, sgx] = channel_planes(values, channels, plane, c)
                    .zip(channel_planes(dy, channels, plane, c))
                    .map(|(xs, gs)| {
                        lane_sums(xs, gs, |v, g| {
                            let g = if v * scale + shift > 0.0 { g } else { 0.0 };
                            [g, g * (v - mean)]
                        })
                    })
                    .fold([0.0f64; 2], |a, b| [a[0] + b[0], a[1] + b[1]]);
                (sg, sgx * rstd as f64)
            })
            .collect();
        // Pass 2: the input gradient, plane by plane.
        let mut dx = vec![0.0f32; values.len()];
        if plane > 0 && channels > 0 {
            dx.par_chunks_mut(plane).zip(values.par_chunks(plane).zip(dy.par_chunks(plane))).enumerate().for_each(
                |(i, (out, (xs, gs)))| {
                    let c = i % channels;
                    let (scale, shift, rstd) = coefficients[c];
                    let (mean_g, mean_gx) = ((sums[c].0 / count) as f32, (sums[c].1 / count) as f32);
                    let (factor, mean, slope) = (slice(&gamma)[c] * rstd, means[c], rstd * mean_gx);
                    for ((d, &v), &g) in out.iter_mut().zip(xs).zip(gs) {
                        // A select between two loaded values, not a branch: the ReLU's mask is
                        // unpredictable, and a branch (or a load inside one) keeps this scalar.
                        let g = if v * scale + shift > 0.0 { g } else { 0.0 };
                        *d = factor * (g - mean_g - (v - mean) * slope);
                    }
                },
            );
        }
        let dgamma = sums.iter().map(|s| s.1 as f32).collect();
        let dbeta = sums.iter().map(|s| s.0 as f32).collect();
        [flex_tensor(dx, &dims), flex_tensor(dgamma, &[channels]), flex_tensor(dbeta, &[channels])]
    }
}

#[cfg(feature = "autodiff")]
mod autodiff {
    use burn::backend::autodiff::Autodiff;
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::tensor::FloatTensor;

    use super::{BatchNormReluBackend, BatchNormReluGrads};

    #[derive(Debug)]
    struct BatchNormReluBackward;

    impl<B: BatchNormReluGrads> Backward<B, 3> for BatchNormReluBackward {
        /// The input, gamma, beta, the batch statistics and epsilon.
        type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, f64);

        fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
            let grad = grads.consume::<B>(&ops.node);
            let (x, gamma, beta, stats, epsilon) = ops.state;
            let [dx, dgamma, dbeta] = B::batch_norm_relu_backward(x, gamma, beta, stats, epsilon, grad);
            for (node, g) in ops.parents.into_iter().zip([dx, dgamma, dbeta]) {
                if let Some(node) = node {
                    grads.register::<B>(node.id, g);
                }
            }
        }
    }

    impl<B: BatchNormReluGrads, C: CheckpointStrategy> BatchNormReluBackend for Autodiff<B, C> {
        fn batch_stats(x: FloatTensor<Self>) -> FloatTensor<Self> {
            FloatTensor::<Self>::new(B::batch_stats(x.into_primitive()))
        }

        fn batch_norm_relu(
            x: FloatTensor<Self>,
            gamma: FloatTensor<Self>,
            beta: FloatTensor<Self>,
            stats: FloatTensor<Self>,
            epsilon: f64,
        ) -> FloatTensor<Self> {
            let stats = stats.into_primitive();
            match BatchNormReluBackward.prepare::<C>([x.node(), gamma.node(), beta.node()]).compute_bound().stateful() {
                OpsKind::Tracked(prep) => {
                    let (x, gamma, beta) = (x.into_primitive(), gamma.into_primitive(), beta.into_primitive());
                    let out = B::batch_norm_relu(x.clone(), gamma.clone(), beta.clone(), stats.clone(), epsilon);
                    prep.finish((x, gamma, beta, stats, epsilon), out)
                }
                OpsKind::UnTracked(prep) => prep.finish(B::batch_norm_relu(
                    x.into_primitive(),
                    gamma.into_primitive(),
                    beta.into_primitive(),
                    stats,
                    epsilon,
                )),
            }
        }
    }
}

/// `relu(norm.forward(x))` in training mode on flex under autodiff as the fused operation
/// above, running statistics updated; `None` anywhere else.
pub(crate) fn train_norm_relu<const D: usize>(norm: &BatchNorm, x: &Tensor<D>) -> Option<Tensor<D>> {
    if flex_kind(&x.device()) != Some(true) || !norm.training.is_enabled() || x.dtype() != DType::F32 || D < 2 {
        return None;
    }
    type Dispatch = burn::backend::Dispatch;
    let stats: Tensor<2> =
        Tensor::from_dispatch(<Dispatch as BatchNormReluBackend>::batch_stats(x.clone().into_dispatch()));
    let channels = norm.gamma.val().dims()[0];
    let (mean, var) = (
        stats.clone().slice([0..1, 0..channels]).reshape([channels]),
        stats.clone().slice([1..2, 0..channels]).reshape([channels]),
    );
    let device = x.device();
    let m = norm.momentum;
    let running_mean =
        norm.running_mean.value_sync().to_device(&device).mul_scalar(1.0 - m).add(mean.detach().mul_scalar(m));
    let running_var =
        norm.running_var.value_sync().to_device(&device).mul_scalar(1.0 - m).add(var.detach().mul_scalar(m));
    norm.running_mean.update(running_mean.detach());
    norm.running_var.update(running_var.detach());
    Some(Tensor::from_dispatch(<Dispatch as BatchNormReluBackend>::batch_norm_relu(
        x.clone().into_dispatch(),
        norm.gamma.val().into_dispatch(),
        norm.beta.val().into_dispatch(),
        stats.into_dispatch(),
        norm.epsilon,
    )))
}

/// `relu(norm.forward(x))`: in one pass on flex outside autodiff, as one fused operation in
/// training on flex (here), through Burn's operations elsewhere.
pub(crate) fn norm_relu<const D: usize>(norm: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    use super::flex::{flex_f32, from_flex};
    use super::norm_relu::{inference_affine, scale_shift_relu_flex};
    use burn::tensor::activation::relu;
    if let Some(y) = train_norm_relu(norm, &x) {
        return y;
    }
    let Some(input) = flex_f32(&x) else {
        return relu(norm.forward(x));
    };
    let (scale, shift) = inference_affine(norm);
    match (flex_f32(&scale), flex_f32(&shift)) {
        (Some(scale), Some(shift)) => from_flex(scale_shift_relu_flex(&input, slice(&scale), slice(&shift))),
        _ => relu(norm.forward(x)),
    }
}

#[cfg(all(test, feature = "autodiff"))]
mod tests {
    use burn::module::Param;
    use burn::nn::BatchNormConfig;
    use burn::tensor::activation::relu;
    use burn::tensor::{Distribution, Tolerance};

    use super::*;

    /// Output, gradients (input, gamma, beta) and updated running statistics against Burn's
    /// training batch norm followed by ReLU; one channel is constant (zero variance). Planes
    /// shorter than one lane group, and longer than a block with a ragged end.
    #[test]
    fn fused_equals_burns_training_batch_norm_and_relu() {
        check_against_burn(3, 5);
        check_against_burn(37, 41);
    }

    fn check_against_burn(height: usize, width: usize) {
        let device = crate::backend::default_device().autodiff();
        let mut norm = BatchNormConfig::new(4).init(&device);
        norm.gamma = Param::from_tensor(Tensor::from_floats([1.5, -0.7, 0.3, 1.0], &device));
        norm.beta = Param::from_tensor(Tensor::from_floats([0.2, 0.1, -0.4, 0.5], &device));
        let shape = [2, 4, height, width];
        let x = Tensor::<4>::random(shape, Distribution::Normal(1.0, 2.0), &device);
        let constant = Tensor::full([2, 1, height, width], 0.25, &device);
        let x = x.slice_assign([0..2, 3..4, 0..height, 0..width], constant).require_grad();
        let probe = Tensor::<4>::random(shape, Distribution::Normal(0.0, 1.0), &device);
        let (mine, theirs) = (norm.clone(), norm.clone());
        let y_mine = train_norm_relu(&mine, &x).expect("flex autodiff takes the fused path");
        let y_theirs = relu(theirs.forward(x.clone()));
        let tol = Tolerance::rel_abs(1e-4, 1e-5);
        y_mine.clone().into_data().assert_approx_eq::<f32>(&y_theirs.clone().into_data(), tol);
        let g_mine = (y_mine * probe.clone()).sum().backward();
        let g_theirs = (y_theirs * probe).sum().backward();
        let grad = |t: &Tensor<4>, g| t.grad(g).unwrap().into_data();
        grad(&x, &g_mine).assert_approx_eq::<f32>(&grad(&x, &g_theirs), tol);
        // A parameter's gradient is a sum over 2·h·w terms of order one (|probe · x̂| < ~8) that
        // mostly cancel (the constant channel's comes to ~0.2 from rounding alone), so two
        // summation orders differ by up to terms·eps·8 absolute: a relative bound on the small
        // result failed at random (CI: 2.7e-5 on 0.229, where terms·eps·8 is 2.9e-3).
        let terms = (2 * height * width) as f32;
        let summed = Tolerance::rel_abs(1e-4, terms * f32::EPSILON * 8.0);
        for (p_mine, p_theirs) in [(&mine.gamma, &theirs.gamma), (&mine.beta, &theirs.beta)] {
            let (a, b) = (p_mine.grad(&g_mine).unwrap(), p_theirs.grad(&g_theirs).unwrap());
            a.into_data().assert_approx_eq::<f32>(&b.into_data(), summed);
        }
        for (a, b) in [(&mine.running_mean, &theirs.running_mean), (&mine.running_var, &theirs.running_var)] {
            a.value().into_data().assert_approx_eq::<f32>(&b.value().into_data(), tol);
        }
    }

    /// Batch statistics against an f64 reference over the same values, for a channel whose mean
    /// is 2000 standard deviations from zero (where uncentred sums lose every digit), a plain one
    /// and one of alternating signs, over planes with a ragged end.
    #[test]
    fn batch_stats_keep_precision_far_from_zero() {
        let (batch, channels, plane) = (3, 3, 2_000 + 7);
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut values = vec![0.0f32; batch * channels * plane];
        for (i, v) in values.iter_mut().enumerate() {
            let u = uniform() - 0.5;
            *v = match (i / plane) % channels {
                0 => 1000.0 + u,
                1 => 3.0 * u,
                _ => 50.0f32.copysign(if i % 2 == 0 { 1.0 } else { -1.0 }) + u,
            };
        }
        let x = super::flex_tensor(values.clone(), &[batch, channels, 1, plane]);
        let stats = <Flex as BatchNormReluBackend>::batch_stats(x);
        let stats = slice(&stats);
        for c in 0..channels {
            let own: Vec<f64> = values.chunks(plane).skip(c).step_by(channels).flatten().map(|v| *v as f64).collect();
            let mean = own.iter().sum::<f64>() / own.len() as f64;
            let var = own.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / own.len() as f64;
            let (got_mean, got_var) = (stats[c] as f64, stats[channels + c] as f64);
            assert!((got_mean - mean).abs() <= 1e-6 * mean.abs().max(1.0), "channel {c}: mean {got_mean} vs {mean}");
            assert!((got_var - var).abs() <= 1e-5 * var, "channel {c}: variance {got_var} vs {var}");
        }
    }

    #[test]
    fn plain_flex_is_not_fused() {
        let norm = BatchNormConfig::new(3).init(&crate::backend::default_device());
        let x = Tensor::<4>::zeros([1, 3, 2, 2], &crate::backend::default_device());
        assert!(train_norm_relu(&norm, &x).is_none());
    }
}
