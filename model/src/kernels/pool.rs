//! Eval-mode max pooling on flex.
//!
//! Burn's generic pooling kernel took 67 ms for DenseNet's stem pool (3x3, stride 2, padding 1,
//! 96 channels at 240x320), as much as a tenth of the encoder. Here each output row is the
//! element-wise maximum of its `kernel` input rows (one vectorisable pass) followed by the
//! strided maximum along that row. Anywhere else (autodiff, other backends or dtypes, dilation,
//! ceil mode) it is Burn's `MaxPool2d::forward`.

use burn::nn::pool::MaxPool2d;
use burn::tensor::Tensor;
use rayon::prelude::*;

use super::conv::symmetric_padding;
use super::flex::{flex_f32, flex_tensor, from_flex, slice};

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

/// `x` holds planes of `h * w` values; every plane is pooled on its own.
fn max_pool_planes(x: &[f32], [h, w]: [usize; 2], window: Window) -> Vec<f32> {
    let (ho, wo) = (window.out_len(h), window.out_len(w));
    let mut out = vec![0.0f32; x.len() / (h * w).max(1) * ho * wo];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(ho * wo).zip(x.par_chunks(h * w)).for_each(|(dst, plane)| {
        let mut rows_max = vec![f32::NEG_INFINITY; w];
        for (oy, dst_row) in dst.chunks_exact_mut(wo).enumerate() {
            rows_max.fill(f32::NEG_INFINITY);
            for y in window.span(oy, h) {
                rows_max.iter_mut().zip(&plane[y * w..][..w]).for_each(|(m, v)| *m = m.max(*v));
            }
            for (ox, d) in dst_row.iter_mut().enumerate() {
                *d = rows_max[window.span(ox, w)].iter().fold(f32::NEG_INFINITY, |m, v| m.max(*v));
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

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::PaddingConfig2d;
    use burn::nn::pool::MaxPool2dConfig;
    use burn::tensor::Distribution;

    /// Against Burn's pooling: DenseNet's stem pool on odd and even sides, a valid 2x2 pool, and
    /// an all-negative input (where zero padding would wrongly win).
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
            for [h, w] in [[7, 9], [8, 10], [3, 3]] {
                let x = Tensor::<4>::random([2, 3, h, w], Distribution::Normal(0.0, 1.0), &device);
                for x in [x.clone(), x.abs().neg().sub_scalar(1.0)] {
                    let expected = pool.forward(x.clone()).into_data();
                    max_pool2d(pool, x).into_data().assert_eq(&expected, true);
                }
            }
        }
    }
}
