//! DenseDepth's loss: SSIM + image-gradient L1 + L1, weighted (1.0, 1.0, 0.1) by default.
//!
//! Definitions follow `shared/fixtures/README.md`: forward differences with a zero last row
//! and column; SSIM with an 11x11 Gaussian window (sigma 1.5), no padding, `C1 = (0.01 L)^2`,
//! `C2 = (0.03 L)^2`, `ssim_term = clamp((1 - mean ssim) / 2, 0, 1)`. SSIM statistics are computed
//! on values divided by `L`, which changes nothing mathematically but keeps squares of depth
//! units (up to 1e6) out of half-precision range; sums over whole maps are taken in f32.

use burn::config::Config;
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{DType, Tensor, TensorData};

/// Loss weights and SSIM's dynamic range.
#[derive(Config, Debug)]
pub struct DepthLossConfig {
    #[config(default = 1.0)]
    pub ssim_weight: f64,
    #[config(default = 1.0)]
    pub gradient_weight: f64,
    #[config(default = 0.1)]
    pub l1_weight: f64,
    /// SSIM's `L`: the width of the target's value range (990 for 10..1000).
    #[config(default = 990.0)]
    pub dynamic_range: f64,
    /// Weight of an extra L1 term over contact pixels only (target above `contact_above`), in
    /// the L1 term's units: where the sensor is pressed is a small part of each map, and the
    /// part a user needs. Default 0: DenseDepth's loss.
    #[config(default = 0.0)]
    pub contact_weight: f64,
    /// Target value (network units) above which a pixel counts as contact.
    #[config(default = 0.0)]
    pub contact_above: f64,
    /// Weight of the pressure channel's term ([`DepthLossConfig::forward_heads`]): the masked
    /// L1 of the pressure in its network units (`PRESSURE_KPA_PER_UNIT`). Default 0.
    #[config(default = 0.0)]
    pub pressure_weight: f64,
}

/// The loss and its terms (each a scalar tensor).
pub struct DepthLoss {
    pub total: Tensor<1>,
    pub ssim: Tensor<1>,
    pub gradient: Tensor<1>,
    pub l1: Tensor<1>,
    /// Mean absolute error over contact pixels (zero where a batch has none); computed only
    /// when `contact_weight` is above zero.
    pub contact_l1: Option<Tensor<1>>,
    /// Mean absolute pressure error over the labelled useful pixels (network units), where the
    /// network and the batch both have pressure ([`DepthLossConfig::forward_heads`]).
    pub pressure_l1: Option<Tensor<1>>,
    /// Mean over the images with a force target of |F_pred - F|, summed over x, y, z (N): the
    /// pressure output's resultant against the sample's wrench.
    pub force_l1_n: Option<Tensor<1>>,
    /// The same for the force head's output, where the network has one.
    pub head_force_l1_n: Option<Tensor<1>>,
}

/// Mean over the images with a force target of |F_pred - F| summed over x, y, z (N);
/// `force_n`: `[N, 3]`, N.
fn mean_force_error_n(force_n: Tensor<2>, f: &ForceTargets) -> Tensor<1> {
    let err = (force_n - f.force_n.clone()).abs().sum_dim(1) * f.has.clone();
    err.sum() / f.has.clone().sum().clamp_min(1.0)
}

/// The force (N) that counts as one unit of loss in [`DepthLossConfig::forward_heads`]'s force
/// term, beside the pressure's per-pixel term: the kit's contacts push 1 to 60 N.
pub const FORCE_N_PER_LOSS_UNIT: f32 = 20.0;

/// Force targets of a batch: per image, the force (N) that 1 pressure unit on each output pixel
/// applies (`[N, 3, H * W]`, x, y, z), the target force (`[N, 3]`, N) and whether the image has
/// one (`[N, 1]`, 0 or 1).
#[derive(Clone, Debug)]
pub struct ForceTargets {
    pub per_unit: Tensor<3>,
    pub force_n: Tensor<2>,
    pub has: Tensor<2>,
}

/// 1 where the whole 11x11 window around a pixel lies in `mask` ([N, 1, H - 10, W - 10]), so that
/// pixels outside the mask cannot influence the masked SSIM. The window's count of mask pixels is
/// a row sum then a column sum (exact: integers up to 121).
fn windows_inside(mask: Tensor<4>) -> Tensor<4> {
    let ones = vec![1.0f32; WINDOW];
    let covered = separable(mask, &ones, &ones);
    covered.greater_equal_elem((WINDOW * WINDOW) as f32 - 0.5).float().cast(DType::F32)
}

/// `x` ([N, 1, H, W]) convolved, without padding, with the outer product of `column` (down the
/// rows) and `row` (along them): two 11-tap passes instead of one 121-tap window, the same
/// values up to rounding and, forward and backward, a fraction of the work.
fn separable(x: Tensor<4>, column: &[f32], row: &[f32]) -> Tensor<4> {
    crate::kernels::separable_blur(&x, column, row).unwrap_or_else(|| separable_by_convs(x, column, row))
}

/// `separable` through Burn's two one-channel convolutions: every backend and dtype the kernel
/// does not take, and the kernel's reference in its tests.
pub(crate) fn separable_by_convs(x: Tensor<4>, column: &[f32], row: &[f32]) -> Tensor<4> {
    let (device, dtype) = (x.device(), x.dtype());
    let kernel = |taps: &[f32], shape: [usize; 4]| {
        Tensor::<4>::from_data(TensorData::new(taps.to_vec(), shape), &device).cast(dtype)
    };
    let options = || ConvOptions::new([1, 1], [0, 0], [1, 1], 1);
    let along_rows = conv2d(x, kernel(row, [1, 1, 1, row.len()]), None, options());
    conv2d(along_rows, kernel(column, [1, 1, column.len(), 1]), None, options())
}

/// Sums in f32 whatever the input's precision: a half-precision sum of a whole depth map
/// overflows (65,504 is f16's largest value).
fn sum32(x: Tensor<4>) -> Tensor<1> {
    x.cast(DType::F32).sum()
}

const WINDOW: usize = 11;
const SIGMA: f64 = 1.5;

/// The 1-D Gaussian (sigma 1.5, 11 taps, summing to 1) whose outer product with itself is
/// SSIM's window.
fn gaussian_taps() -> Vec<f32> {
    let g: Vec<f64> = (0..WINDOW).map(|i| (-((i as f64 - 5.0).powi(2)) / (2.0 * SIGMA * SIGMA)).exp()).collect();
    let sum: f64 = g.iter().sum();
    g.iter().map(|v| (v / sum) as f32).collect()
}

impl DepthLossConfig {
    /// Loss over every pixel. `pred` and `target` are [N, 1, H, W] in network units.
    pub fn forward(&self, pred: Tensor<4>, target: Tensor<4>) -> DepthLoss {
        self.forward_masked(pred, target, None)
    }

    /// Loss over the useful pixels only (`mask` is [N, 1, H, W] of 0 and 1): L1 over masked
    /// pixels, gradients over pairs of masked neighbours, SSIM over windows lying wholly in the
    /// mask, so that nothing outside it has any influence. Without a mask, every pixel counts,
    /// exactly as the fixture defines it.
    pub fn forward_masked(&self, pred: Tensor<4>, target: Tensor<4>, mask: Option<Tensor<4>>) -> DepthLoss {
        let [n, c, h, w] = pred.dims();
        assert_eq!(c, 1, "depth maps have one channel");
        assert_eq!(target.dims(), [n, c, h, w], "prediction and target shapes differ");
        assert!(h >= WINDOW && w >= WINDOW, "SSIM needs at least {WINDOW}x{WINDOW} pixels, got {h}x{w}");
        let count = (n * h * w) as f32;
        let diff = pred.clone() - target.clone();
        let contact_l1 = (self.contact_weight > 0.0).then(|| {
            let mut contact = target.clone().greater_elem(self.contact_above as f32).float().cast(DType::F32);
            if let Some(m) = &mask {
                contact = contact * m.clone().cast(DType::F32);
            }
            sum32(diff.clone().abs().cast(DType::F32) * contact.clone()) / sum32(contact).clamp_min(1.0)
        });
        let dy = |x: Tensor<4>| x.clone().slice([0..n, 0..1, 1..h, 0..w]) - x.slice([0..n, 0..1, 0..h - 1, 0..w]);
        let dx = |x: Tensor<4>| x.clone().slice([0..n, 0..1, 0..h, 1..w]) - x.slice([0..n, 0..1, 0..h, 0..w - 1]);
        let (ey, ex) = ((dy(pred.clone()) - dy(target.clone())).abs(), (dx(pred.clone()) - dx(target.clone())).abs());

        let (l1, gradient, ssim_mean) = match mask {
            None => {
                let l1 = sum32(diff.abs()).div_scalar(count);
                let gradient = (sum32(ey) + sum32(ex)).div_scalar(count);
                let ssim =
                    sum32(self.ssim_map(pred, target)).div_scalar(((h - WINDOW + 1) * (w - WINDOW + 1) * n) as f32);
                (l1, gradient, ssim)
            }
            Some(mask) => {
                let mask = mask.cast(pred.dtype());
                let m_sum = sum32(mask.clone()).clamp_min(1.0);
                let l1 = sum32(diff.abs() * mask.clone()) / m_sum.clone();
                let my =
                    mask.clone().slice([0..n, 0..1, 1..h, 0..w]) * mask.clone().slice([0..n, 0..1, 0..h - 1, 0..w]);
                let mx =
                    mask.clone().slice([0..n, 0..1, 0..h, 1..w]) * mask.clone().slice([0..n, 0..1, 0..h, 0..w - 1]);
                let gradient = (sum32(ey * my) + sum32(ex * mx)) / m_sum;
                let centres = windows_inside(mask);
                let ssim = sum32(self.ssim_map(pred, target).cast(DType::F32) * centres.clone())
                    / sum32(centres).clamp_min(1.0);
                (l1, gradient, ssim)
            }
        };
        let ssim = ssim_mean.neg().add_scalar(1.0).mul_scalar(0.5).clamp(0.0, 1.0);
        let total = ssim.clone().mul_scalar(self.ssim_weight)
            + gradient.clone().mul_scalar(self.gradient_weight)
            + l1.clone().mul_scalar(self.l1_weight);
        let total = match &contact_l1 {
            Some(c) => total + c.clone().mul_scalar(self.contact_weight * self.l1_weight),
            None => total,
        };
        DepthLoss { total, ssim, gradient, l1, contact_l1, pressure_l1: None, force_l1_n: None, head_force_l1_n: None }
    }

    /// The loss of a network's outputs: depth's ([`forward_masked`](Self::forward_masked) over
    /// `mask`) plus, where the network has a pressure output and the batch pressure targets
    /// (`[N, 1, H, W]` targets in network units and a mask of the pixels that have one),
    /// `pressure_weight` times their masked L1, and, where the batch has force targets, the same
    /// weight times the mean |F_pred - F| (in [`FORCE_N_PER_LOSS_UNIT`]s) of the pressure's
    /// resultant: the per-pixel term alone left the force 28 % short on the quickstart's scenes
    /// (an L1 fit keeps the peaks low). Both terms reach the pressure convolution alone: the
    /// network cuts the pressure from the features depth shares (`crate::Heads::pressure`;
    /// through them the resultant's term doubled the contact depth error, the map's cost 1.14x).
    /// A network with the force head adds the same weight times its output's mean |F_pred - F|
    /// (in the same units); that term does reach the encoder, through the head alone.
    pub fn forward_heads(
        &self,
        heads: crate::Heads,
        target: Tensor<4>,
        mask: Tensor<4>,
        pressure: Option<(Tensor<4>, Tensor<4>)>,
        force: Option<ForceTargets>,
    ) -> DepthLoss {
        let mut loss = self.forward_masked(heads.depth, target, Some(mask));
        if let (Some(head), Some(f)) = (heads.force.as_ref(), force.as_ref()) {
            let force_n = head.clone().cast(DType::F32).mul_scalar(FORCE_N_PER_LOSS_UNIT);
            let mean = mean_force_error_n(force_n, f);
            loss.total = loss.total + mean.clone().mul_scalar(self.pressure_weight / FORCE_N_PER_LOSS_UNIT as f64);
            loss.head_force_l1_n = Some(mean);
        }
        if let (Some(pred), Some(f)) = (heads.pressure.as_ref(), force) {
            let [n, _, h, w] = pred.dims();
            let pred = pred.clone().cast(DType::F32).reshape([n, 1, h * w]);
            let resultant = (f.per_unit.clone() * pred).sum_dim(2).reshape([n, 3]);
            let mean = mean_force_error_n(resultant, &f);
            loss.total = loss.total + mean.clone().mul_scalar(self.pressure_weight / FORCE_N_PER_LOSS_UNIT as f64);
            loss.force_l1_n = Some(mean);
        }
        if let (Some(pred), Some((target, mask))) = (heads.pressure, pressure) {
            assert_eq!(pred.dims(), target.dims(), "pressure prediction and target shapes differ");
            let mask = mask.cast(DType::F32);
            let l1 = sum32((pred - target).abs().cast(DType::F32) * mask.clone()) / sum32(mask).clamp_min(1.0);
            loss.total = loss.total + l1.clone().mul_scalar(self.pressure_weight);
            loss.pressure_l1 = Some(l1);
        }
        loss
    }

    /// Per-window SSIM ([N, 1, H - 10, W - 10]), computed on values divided by `L`. The five
    /// local means are one separable blur of the five maps stacked along the batch.
    fn ssim_map(&self, pred: Tensor<4>, target: Tensor<4>) -> Tensor<4> {
        let inv_l = (1.0 / self.dynamic_range) as f32;
        let (p, t) = (pred.mul_scalar(inv_l), target.mul_scalar(inv_l));
        let stack = Tensor::cat(vec![p.clone(), t.clone(), p.clone() * p.clone(), t.clone() * t.clone(), p * t], 0);
        let taps = gaussian_taps();
        let mut blurred = separable(stack, &taps, &taps).chunk(5, 0).into_iter();
        let mut next = || blurred.next().expect("five blurred maps");
        let (mp, mt, pp, tt, pt) = (next(), next(), next(), next(), next());
        let spp = pp - mp.clone() * mp.clone();
        let stt = tt - mt.clone() * mt.clone();
        let spt = pt - mp.clone() * mt.clone();
        let (c1, c2) = (0.01f32 * 0.01, 0.03f32 * 0.03);
        let num = (mp.clone() * mt.clone()).mul_scalar(2.0).add_scalar(c1) * spt.mul_scalar(2.0).add_scalar(c2);
        let den = (mp.clone() * mp + mt.clone() * mt).add_scalar(c1) * (spp + stt).add_scalar(c2);
        num / den
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 12x12 map of zeros with a 4x4 contact patch of depth 5; the prediction is off by 1 on
    /// the patch and by 0.5 on two untouched pixels.
    fn patch_case(device: &burn::tensor::Device) -> (Tensor<4>, Tensor<4>) {
        let (h, w) = (12, 12);
        let mut target = vec![0f32; h * w];
        let mut pred = vec![0f32; h * w];
        for y in 4..8 {
            for x in 4..8 {
                target[y * w + x] = 5.0;
                pred[y * w + x] = 6.0;
            }
        }
        pred[0] = 0.5;
        pred[1] = 0.5;
        let t = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, [1, 1, h, w]), device);
        (t(pred), t(target))
    }

    #[test]
    fn the_contact_term_is_the_mean_error_over_contact_pixels_and_adds_to_the_total() {
        let device = crate::backend::default_device();
        let (pred, target) = patch_case(&device);
        let scalar = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0];
        let plain = DepthLossConfig::new();
        let weighted = DepthLossConfig::new().with_contact_weight(3.0).with_contact_above(0.1);
        let a = plain.forward(pred.clone(), target.clone());
        let b = weighted.forward(pred.clone(), target.clone());
        // Sixteen contact pixels each off by 1; the two untouched misses do not count.
        assert!((scalar(b.contact_l1.clone().unwrap()) - 1.0).abs() < 1e-6);
        let (ta, tb) = (scalar(a.total), scalar(b.total));
        assert!((tb - ta - 3.0 * 0.1 * 1.0).abs() < 1e-5, "{ta} {tb}");
        // A mask that leaves out half the patch leaves the mean over the rest unchanged, and
        // a map without contact gives zero, not a NaN.
        let mut m = vec![1f32; 144];
        (0..12).for_each(|y| (0..6).for_each(|x| m[y * 12 + x] = 0.0));
        let mask = Tensor::<4>::from_data(TensorData::new(m, [1, 1, 12, 12]), &device);
        let c = weighted.forward_masked(pred.clone(), target.clone(), Some(mask));
        assert!((scalar(c.contact_l1.unwrap()) - 1.0).abs() < 1e-6);
        let none = weighted.forward(pred.clone(), Tensor::zeros([1, 1, 12, 12], &device));
        assert_eq!(scalar(none.contact_l1.unwrap()), 0.0);
    }

    /// The pressure term is the mean absolute error over the pixels its mask keeps, weighted
    /// into the total; without a pressure output or targets the loss is depth's alone.
    #[test]
    fn the_pressure_term_is_its_masked_l1_and_adds_to_the_total() {
        let device = crate::backend::default_device();
        let (pred, target) = patch_case(&device);
        let scalar = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0];
        let config = DepthLossConfig::new().with_pressure_weight(2.0);
        let ones = Tensor::<4>::ones([1, 1, 12, 12], &device);
        let depth_only = config.forward_masked(target.clone(), target.clone(), Some(ones.clone()));
        let heads = |p: Option<Tensor<4>>| crate::Heads { depth: target.clone(), pressure: p, force: None };
        // Pressure off by 1 on the 16 patch pixels and 0.5 on two others; the mask keeps the
        // left half of the map (8 patch pixels and both others): (8 + 1) / 72.
        let mut m = vec![0f32; 144];
        (0..12).for_each(|y| (0..6).for_each(|x| m[y * 12 + x] = 1.0));
        let mask = Tensor::<4>::from_data(TensorData::new(m, [1, 1, 12, 12]), &device);
        let with = config.forward_heads(
            heads(Some(pred.clone())),
            target.clone(),
            ones.clone(),
            Some((target.clone(), mask)),
            None,
        );
        let l1 = scalar(with.pressure_l1.unwrap());
        assert!((l1 - 9.0 / 72.0).abs() < 1e-6, "{l1}");
        let (a, b) = (scalar(depth_only.total), scalar(with.total));
        assert!((b - a - 2.0 * 9.0 / 72.0).abs() < 1e-5, "{a} {b}");
        for unused in [
            config.forward_heads(heads(None), target.clone(), ones.clone(), Some((target.clone(), ones.clone())), None),
            config.forward_heads(heads(Some(pred.clone())), target.clone(), ones.clone(), None, None),
        ] {
            assert!(unused.pressure_l1.is_none());
            assert_eq!(scalar(unused.total), a);
        }

        // The force term: two images; 1 unit of pressure on a pixel pushes (0, 0, -2) N there.
        // The prediction's resultant is -2 * (sum of its pixels) along z: 1 * 16 * 6 + 2 * 0.5
        // = 97 units, so -194 N. Targets -190 N (off by 4) and, for an image without one, any.
        let per_unit = Tensor::<3>::from_data(
            TensorData::new([vec![0f32; 288], vec![-2f32; 144]].concat().repeat(2), [2, 3, 144]),
            &device,
        );
        let pred2 = Tensor::cat(vec![pred.clone(), pred.clone()], 0);
        let force_n = Tensor::<2>::from_data(TensorData::new(vec![0f32, 0.0, -190.0, 5.0, 5.0, 5.0], [2, 3]), &device);
        let has = Tensor::<2>::from_data(TensorData::new(vec![1f32, 0.0], [2, 1]), &device);
        let force = ForceTargets { per_unit, force_n, has };
        let depth2 = Tensor::cat(vec![target.clone(), target.clone()], 0);
        let ones2 = Tensor::cat(vec![ones.clone(), ones.clone()], 0);
        let heads2 = crate::Heads { depth: depth2.clone(), pressure: Some(pred2), force: None };
        let with = config.forward_heads(heads2, depth2.clone(), ones2.clone(), None, Some(force));
        assert!((scalar(with.force_l1_n.unwrap()) - 4.0).abs() < 1e-3);
        let base = scalar(config.forward_masked(depth2.clone(), depth2, Some(ones2)).total);
        assert!((scalar(with.total) - base - 2.0 * 4.0 / FORCE_N_PER_LOSS_UNIT).abs() < 1e-4);
    }

    /// The force head's term: the mean over images with a target of |F_head - F| (N, summed over
    /// x, y, z), weighted into the total beside the other terms; its gradient reaches the head's
    /// output.
    #[test]
    fn the_force_heads_term_is_its_mean_error_and_adds_to_the_total() {
        let device = crate::backend::default_device().autodiff();
        let (_, target) = patch_case(&device);
        let scalar = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0];
        let config = DepthLossConfig::new().with_pressure_weight(2.0);
        let ones = Tensor::<4>::ones([2, 1, 12, 12], &device);
        let depth = Tensor::cat(vec![target.clone(), target.clone()], 0);
        // Heads answering (1, 0, -10) N and (0, 0, 0) N; targets (0, 0, -12) N and, for the
        // second image, none: |1| + |2| = 3 N over the one image with a target.
        let head = Tensor::<2>::from_data(
            TensorData::new(
                vec![1.0 / FORCE_N_PER_LOSS_UNIT, 0.0, -10.0 / FORCE_N_PER_LOSS_UNIT, 0.0, 0.0, 0.0],
                [2, 3],
            ),
            &device,
        )
        .require_grad();
        let force = ForceTargets {
            per_unit: Tensor::<3>::zeros([2, 3, 144], &device),
            force_n: Tensor::<2>::from_data(TensorData::new(vec![0f32, 0.0, -12.0, 7.0, 7.0, 7.0], [2, 3]), &device),
            has: Tensor::<2>::from_data(TensorData::new(vec![1f32, 0.0], [2, 1]), &device),
        };
        let heads = crate::Heads { depth: depth.clone(), pressure: None, force: Some(head.clone()) };
        let with = config.forward_heads(heads, depth.clone(), ones.clone(), None, Some(force));
        assert!((scalar(with.head_force_l1_n.clone().unwrap()) - 3.0).abs() < 1e-4);
        assert!(with.force_l1_n.is_none() && with.pressure_l1.is_none());
        let base = scalar(config.forward_masked(depth.clone(), depth, Some(ones)).total);
        assert!((scalar(with.total.clone()) - base - 2.0 * 3.0 / FORCE_N_PER_LOSS_UNIT).abs() < 1e-4);
        // d total / d head: weight * sign(error) for the first image (x and z over, y exact),
        // nothing for the second.
        let grads = with.total.backward();
        let g = head.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
        let w = 2.0f32;
        for (got, want) in g.iter().zip([w, 0.0, w, 0.0, 0.0, 0.0]) {
            assert!((got - want).abs() < 1e-4, "{g:?}");
        }
    }
}
