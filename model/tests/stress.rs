//! Numerical stress: the loss and its gradient stay finite on degenerate and extreme inputs,
//! in f32 and f16; the trainable upsample equals `interpolate` and trains.

use crate::common;

use burn::tensor::{DType, Device, Distribution, Tensor};
use common::to_vec;
use model::{DenseDepthConfig, DenseNetConfig, DepthLossConfig, DepthScale};
use model::{Upsample, upsample_bilinear};
use proptest::prelude::*;

fn device() -> Device {
    model::backend::default_device().autodiff()
}

fn full(value: f32, dims: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::<4>::ones(dims, device).mul_scalar(value)
}

/// Loss terms and gradient of `pred` against `target`; asserts all are finite.
fn check_finite(pred: Tensor<4>, target: Tensor<4>, mask: Option<Tensor<4>>, what: &str) -> f32 {
    let pred = pred.require_grad();
    let out = DepthLossConfig::new().forward_masked(pred.clone(), target, mask);
    let values = [out.total.clone(), out.ssim, out.gradient, out.l1].map(|t| to_vec(t.cast(DType::F32))[0]);
    assert!(values.iter().all(|v| v.is_finite()), "{what}: loss terms {values:?}");
    let grads = out.total.backward();
    let g = to_vec(pred.grad(&grads).expect("gradient").cast(DType::F32));
    assert!(g.iter().all(|v| v.is_finite()), "{what}: non-finite gradient");
    values[0]
}

#[test]
fn loss_is_finite_on_degenerate_and_extreme_inputs() {
    let d = device();
    let dims = [2, 1, 24, 32];
    let scale = DepthScale::paper(9.4);
    let zero = scale.to_net(0.0);
    let max = scale.to_net(9.4);
    let random = Tensor::<4>::random(dims, Distribution::Uniform(10.0, 1000.0), &d);
    let cases: Vec<(&str, Tensor<4>, Tensor<4>)> = vec![
        ("constant images", full(500.0, dims, &d), full(500.0, dims, &d)),
        ("all-zero depth", full(zero, dims, &d), full(zero, dims, &d)),
        ("all-maximal depth", full(max, dims, &d), full(max, dims, &d)),
        ("zero vs maximal", full(zero, dims, &d), full(max, dims, &d)),
        ("constant vs random", full(zero, dims, &d), random.clone()),
        ("tiny values", full(1e-6, dims, &d), random.clone().mul_scalar(1e-6)),
        ("huge values", random.clone().mul_scalar(1e3), random.clone().mul_scalar(1e3).add_scalar(5.0)),
        ("exact zeros", full(0.0, dims, &d), full(0.0, dims, &d)),
    ];
    for (what, pred, target) in cases {
        let total = check_finite(pred.clone(), target.clone(), None, what);
        if what == "constant images" || what.starts_with("all-") || what == "exact zeros" {
            assert!(total.abs() < 1e-5, "{what}: identical maps must cost nothing, got {total}");
        }
        let mask = Tensor::<4>::random(dims, Distribution::Bernoulli(0.7), &d);
        check_finite(pred.clone(), target.clone(), Some(mask), &format!("{what}, masked"));
        check_finite(pred, target, Some(full(0.0, dims, &d)), &format!("{what}, empty mask"));
    }
}

#[test]
fn loss_is_finite_in_half_precision() {
    let d = device();
    let dims = [1, 1, 24, 32];
    let random = Tensor::<4>::random(dims, Distribution::Uniform(10.0, 1000.0), &d);
    let cases = [
        ("random", random.clone(), random.clone().flip([3])),
        ("constant", full(500.0, dims, &d), full(500.0, dims, &d)),
        ("extremes", full(1000.0, dims, &d), full(10.0, dims, &d)),
    ];
    for (what, pred, target) in cases {
        let (p16, t16) = (pred.clone().cast(DType::F16), target.clone().cast(DType::F16));
        let half = check_finite(p16, t16, None, &format!("f16 {what}"));
        let single = check_finite(pred, target, None, what);
        // Depth units squared (up to 1e6) would overflow f16; normalised statistics do not.
        assert!((half - single).abs() <= 0.02 * single.abs().max(1.0), "{what}: f16 {half} vs f32 {single}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn random_stress_cases_never_give_nan(
        base in 0.0f32..1100.0,
        spread in 0.0f32..1000.0,
        noise in 0.0f32..100.0,
        masked in proptest::bool::ANY,
    ) {
        let d = device();
        let dims = [1, 1, 16, 20];
        let target = Tensor::<4>::random(dims, Distribution::Uniform(0.0, 1.0), &d).mul_scalar(spread).add_scalar(base);
        let pred = target.clone() + Tensor::<4>::random(dims, Distribution::Normal(0.0, 1.0), &d).mul_scalar(noise);
        let mask = masked.then(|| Tensor::<4>::random(dims, Distribution::Bernoulli(0.5), &d));
        check_finite(pred, target, mask, "proptest case");
    }
}

#[test]
fn trainable_upsample_equals_interpolate_and_has_gradients() {
    let d = device();
    for (from, to) in [([3, 4], [6, 8]), ([5, 7], [10, 14]), ([2, 3], [5, 9]), ([1, 1], [4, 4]), ([8, 6], [8, 6])] {
        let x = Tensor::<4>::random([2, 3, from[0], from[1]], Distribution::Uniform(-1.0, 1.0), &d).require_grad();
        let native = to_vec(upsample_bilinear(x.clone(), to, Upsample::Native));
        let y = upsample_bilinear(x.clone(), to, Upsample::Matmul);
        let (abs, _) = common::errors(&to_vec(y.clone()), &native);
        assert!(abs <= 1e-5, "{from:?} -> {to:?}: max abs diff {abs}");
        let grads = y.sum().backward();
        if from != to {
            let g = to_vec(x.grad(&grads).expect("gradient"));
            // Each input sample's weights over the output sum to H*W/(h*w) on average.
            assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0));
            let total: f32 = g.iter().sum();
            assert!((total - (2 * 3 * to[0] * to[1]) as f32).abs() < 1e-2 * total, "gradient mass {total}");
        }
    }
}

/// A training step through either upsample, at a multiple of 32 and at odd sides that are not.
#[test]
fn a_training_step_at_any_input_size_gives_finite_gradients() {
    let d = device();
    let config = DenseDepthConfig::new(DenseNetConfig::tiny());
    let model = config.init(&d);
    for (hw, mode) in [([64, 64], Upsample::Matmul), ([45, 71], Upsample::Matmul), ([45, 71], Upsample::Native)] {
        let [oh, ow] = config.output_hw(hw);
        let images = Tensor::<4>::random([1, 3, hw[0], hw[1]], Distribution::Uniform(0.0, 1.0), &d);
        let target = Tensor::<4>::random([1, 1, oh, ow], Distribution::Uniform(10.0, 1000.0), &d);
        let pred = model.forward_with(images, mode).depth;
        assert_eq!(pred.dims(), [1, 1, oh, ow]);
        let loss = DepthLossConfig::new().forward(pred, target).total;
        let grads = loss.backward();
        let w = model.decoder.up1.conv_a.weight.val();
        let g = to_vec(w.grad(&grads).expect("decoder weights receive a gradient"));
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0), "{hw:?} {mode:?}");
        let g = to_vec(model.encoder.conv0.weight.val().grad(&grads).expect("encoder weights receive a gradient"));
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0), "{hw:?} {mode:?}");
    }
}

#[test]
fn masked_loss_counts_only_the_mask() {
    let d = model::backend::default_device();
    let dims = [2, 1, 40, 48];
    let target = Tensor::<4>::random(dims, Distribution::Uniform(10.0, 1000.0), &d);
    let pred = target.clone() + Tensor::<4>::random(dims, Distribution::Normal(0.0, 30.0), &d);
    let loss = DepthLossConfig::new();
    let terms = |l: model::DepthLoss| [l.total, l.ssim, l.gradient, l.l1].map(|t| to_vec(t)[0]);

    // An all-ones mask is no mask at all.
    let plain = terms(loss.forward(pred.clone(), target.clone()));
    let ones = terms(loss.forward_masked(pred.clone(), target.clone(), Some(Tensor::ones(dims, &d))));
    for (a, b) in plain.iter().zip(&ones) {
        assert!((a - b).abs() <= 1e-5 * a.abs().max(1.0), "{plain:?} vs {ones:?}");
    }

    // A disk mask: changing the prediction outside it changes nothing.
    let mut disk = vec![0f32; 2 * 40 * 48];
    for (i, v) in disk.iter_mut().enumerate() {
        let (y, x) = (((i / 48) % 40) as f32 - 19.5, (i % 48) as f32 - 23.5);
        *v = (x * x + y * y <= 18.0 * 18.0) as u8 as f32;
    }
    let mask = Tensor::<4>::from_data(burn::tensor::TensorData::new(disk, dims), &d);
    let outside = mask.clone().neg().add_scalar(1.0);
    let scrambled =
        pred.clone() + outside.clone() * Tensor::<4>::random(dims, Distribution::Uniform(-500.0, 500.0), &d);
    let a = terms(loss.forward_masked(pred.clone(), target.clone(), Some(mask.clone())));
    let b = terms(loss.forward_masked(scrambled, target.clone(), Some(mask)));
    assert_eq!(a, b, "pixels outside the mask influenced the masked loss");
    assert!(a.iter().all(|v| v.is_finite() && *v > 0.0));
}
