//! Eval-mode max pooling, and a transition's batch norm, ReLU and average pooling, on flex.
//!
//! Burn's generic pooling kernel took 67 ms for DenseNet's stem pool (3x3, stride 2, padding 1,
//! 96 channels at 240x320), as much as a tenth of the encoder. Here each output row is the
//! element-wise maximum of its `kernel` input rows (one vectorisable pass) followed by the
//! strided maximum along that row. Anywhere else (autodiff, other backends or dtypes, dilation,
//! ceil mode) it is Burn's `MaxPool2d::forward`.

use burn::nn::BatchNorm;
use burn::nn::pool::{AvgPool2d, MaxPool2d};
use burn::tensor::Tensor;
use rayon::prelude::*;

use super::conv::symmetric_padding;
use super::flex::{flex_f32, flex_tensor, from_flex, slice};
use super::norm_relu::inference_affine;

/// A square pooling window.
#[derive(Clone, Copy, Debug)]
struct Window {
    kernel: usize,
    stride: usize,
    padding: usize,
}

impl Window {
    fn out_len(&self, len: usize) -> usize {
        (len + 2 * self.padding - self.kernel) / self.stride + 1
    }

    /// The input indices under output index `i`, clipped to `0..len`.
    fn span(&self, i: usize, len: usize) -> std::ops::Range<usize> {
        let start = (i * self.stride).saturating_sub(self.padding);
        let end = (i * self.stride + self.kernel - self.padding).min(len);
        start..end
    }
}

/// Planes of `plane_len` values a pooling task takes: about 16k input values, so that a small
/// pool is a few tasks rather than one per channel.
fn planes_per_task(plane_len: usize) -> usize {
    (16384 / plane_len.max(1)).max(1)
}

/// `x` holds planes of `h * w` values; every plane is pooled on its own.
fn max_pool_planes(x: &[f32], [h, w]: [usize; 2], window: Window) -> Vec<f32> {
    let (ho, wo) = (window.out_len(h), window.out_len(w));
    let mut out = vec![0.0f32; x.len() / (h * w).max(1) * ho * wo];
    if out.is_empty() {
        return out;
    }
    // Each output column's input columns, once for every row.
    let columns: Vec<std::ops::Range<usize>> = (0..wo).map(|ox| window.span(ox, w)).collect();
    let group = planes_per_task(h * w);
    out.par_chunks_mut(group * ho * wo).zip(x.par_chunks(group * h * w)).for_each(|(dst, planes)| {
        let mut rows_max = vec![f32::NEG_INFINITY; w];
        for (dst, plane) in dst.chunks_exact_mut(ho * wo).zip(planes.chunks_exact(h * w)) {
            for (oy, dst_row) in dst.chunks_exact_mut(wo).enumerate() {
                let mut rows = window.span(oy, h);
                let first = rows.next().expect("a window overlaps the image");
                rows_max.copy_from_slice(&plane[first * w..][..w]);
                for y in rows {
                    rows_max.iter_mut().zip(&plane[y * w..][..w]).for_each(|(m, v)| *m = m.max(*v));
                }
                for (d, span) in dst_row.iter_mut().zip(&columns) {
                    *d = rows_max[span.clone()].iter().fold(f32::NEG_INFINITY, |m, v| m.max(*v));
                }
            }
        }
    });
    out
}

/// `pool.forward(x)`, with the kernel above where it applies.
pub(crate) fn max_pool2d(pool: &MaxPool2d, x: Tensor<4>) -> Tensor<4> {
    let ([k, k2], [s, s2]) = (pool.kernel_size, pool.stride);
    let [n, c, h, w] = x.dims();
    let plain = k == k2 && s == s2 && s > 0 && pool.dilation == [1, 1] && !pool.ceil_mode;
    match (symmetric_padding(&pool.padding), flex_f32(&x)) {
        (Some(padding), Some(input)) if plain && padding < k && h + 2 * padding >= k && w + 2 * padding >= k => {
            let window = Window { kernel: k, stride: s, padding };
            let out = max_pool_planes(slice(&input), [h, w], window);
            from_flex(flex_tensor(out, &[n, c, window.out_len(h), window.out_len(w)]))
        }
        _ => pool.forward(x),
    }
}

/// `avg_pool_2x2(relu(x * scale[c] + shift[c]))` for planes of `h * w` values, channel after
/// channel (`scale.len()` of them), image after image: a transition's normalisation and pooling
/// in one pass that writes only the pooled quarter. An odd last row or column is dropped, as
/// the pool's floor does.
fn norm_relu_avg_pool2_planes(x: &[f32], [h, w]: [usize; 2], scale: &[f32], shift: &[f32]) -> Vec<f32> {
    let (ho, wo) = (h / 2, w / 2);
    let mut out = vec![0.0f32; x.len() / (h * w).max(1) * ho * wo];
    if out.is_empty() {
        return out;
    }
    let group = planes_per_task(h * w);
    out.par_chunks_mut(group * ho * wo).zip(x.par_chunks(group * h * w)).enumerate().for_each(|(g, (dst, src))| {
        for (k, (dst, plane)) in dst.chunks_exact_mut(ho * wo).zip(src.chunks_exact(h * w)).enumerate() {
            let c = (g * group + k) % scale.len();
            let (s, t) = (scale[c], shift[c]);
            let f = |v: f32| (v * s + t).max(0.0);
            for (oy, row) in dst.chunks_exact_mut(wo).enumerate() {
                let (a, b) = (&plane[2 * oy * w..][..2 * wo], &plane[(2 * oy + 1) * w..][..2 * wo]);
                for (ox, d) in row.iter_mut().enumerate() {
                    *d = 0.25 * ((f(a[2 * ox]) + f(a[2 * ox + 1])) + (f(b[2 * ox]) + f(b[2 * ox + 1])));
                }
            }
        }
    });
    out
}

/// `pool.forward(relu(norm(x)))` for a DenseNet transition, in one pass where `pool` is a 2x2,
/// stride-2 average without padding and `x` f32 on flex outside autodiff; Burn's operations
/// (through [`super::norm_relu`]) anywhere else.
pub(crate) fn norm_relu_avg_pool2(norm: &BatchNorm, pool: &AvgPool2d, x: Tensor<4>) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let plain = pool.kernel_size == [2, 2]
        && pool.stride == [2, 2]
        && symmetric_padding(&pool.padding) == Some(0)
        && !pool.ceil_mode
        && h >= 2
        && w >= 2;
    if let (true, Some(input)) = (plain, flex_f32(&x)) {
        let (scale, shift) = inference_affine(norm);
        if let (Some(scale), Some(shift)) = (flex_f32(&scale), flex_f32(&shift)) {
            let out = norm_relu_avg_pool2_planes(slice(&input), [h, w], slice(&scale), slice(&shift));
            return from_flex(flex_tensor(out, &[n, c, h / 2, w / 2]));
        }
    }
    pool.forward(super::norm_relu(norm, x))
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::PaddingConfig2d;
    use burn::nn::pool::MaxPool2dConfig;
    use burn::tensor::Distribution;

    /// Against Burn's batch norm, ReLU and average pool, on even and odd sides (the odd row
    /// and column dropped) and a batch of two, with statistics away from their defaults.
    #[test]
    fn the_transitions_pass_equals_burns_norm_relu_and_average_pool() {
        use burn::nn::pool::AvgPool2dConfig;
        use burn::tensor::Tolerance;
        let device = crate::backend::default_device();
        let norm = super::super::norm_relu::tests::random_norm(3, &device);
        let pool = AvgPool2dConfig::new([2, 2]).with_strides([2, 2]).init();
        for [h, w] in [[8, 10], [7, 9], [2, 3], [130, 129]] {
            let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 2.0), &device);
            let expected = pool.forward(burn::tensor::activation::relu(norm.forward(x.clone()))).into_data();
            let got = norm_relu_avg_pool2(&norm, &pool, x);
            assert_eq!(got.dims(), [2, 3, h / 2, w / 2]);
            got.into_data().assert_approx_eq::<f32>(&expected, Tolerance::rel_abs(1e-5, 1e-6));
        }
    }

    /// Against Burn's pooling: DenseNet's stem pool on odd and even sides, a valid 2x2 pool, and
    /// an all-negative input (where zero padding would wrongly win); small planes share a task,
    /// a large one (130x129) has its own.
    #[test]
    fn equals_burns_max_pool() {
        let device = crate::backend::default_device();
        let explicit = |p| PaddingConfig2d::Explicit(p, p, p, p);
        let pools = [
            MaxPool2dConfig::new([3, 3]).with_strides([2, 2]).with_padding(explicit(1)).init(),
            MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
            MaxPool2dConfig::new([3, 3]).with_strides([1, 1]).with_padding(explicit(1)).init(),
        ];
        for pool in &pools {
            for [h, w] in [[7, 9], [8, 10], [3, 3], [130, 129]] {
                let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
                for x in [x.clone(), x.abs().neg().sub_scalar(1.0)] {
                    let expected = pool.forward(x.clone()).into_data();
                    max_pool2d(pool, x).into_data().assert_eq(&expected, true);
                }
            }
        }
    }
}
