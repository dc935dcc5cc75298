//! The GPU code path, run on wgpu (Mesa's lavapipe in CI): the trainable upsample and a
//! training step work where Burn's `interpolate` has no backward pass, and the whole network
//! agrees with flex.

#![cfg(feature = "wgpu")]

use crate::common;

use burn::tensor::{Distribution, Tensor, TensorData};
use common::{SafeFile, errors, fixtures, to_vec};
use model::import::load_pytorch;
use model::upsample_mode_for;
use model::{DenseDepthConfig, DenseNetConfig, DepthLossConfig};
use model::{Upsample, upsample_bilinear};

/// The wgpu device's random generator is one per process: tests that seed it and draw from it
/// take this lock, or a test running beside them moves the draws (and the initial weights).
static RNG: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn upsample_on_wgpu_matches_interpolate_and_trains() {
    let gpu = model::backend::wgpu_device().autodiff();
    assert_eq!(upsample_mode_for(&gpu), Upsample::Matmul, "wgpu training must avoid interpolate's backward");
    let cpu = model::backend::default_device();
    let values: Vec<f32> = (0..2 * 3 * 5 * 7).map(|i| ((i * 37) % 101) as f32 / 50.0 - 1.0).collect();
    let x_cpu = Tensor::<4>::from_data(TensorData::new(values.clone(), [2, 3, 5, 7]), &cpu);
    let reference = to_vec(upsample_bilinear(x_cpu, [10, 14], Upsample::Native));
    let x = Tensor::<4>::from_data(TensorData::new(values, [2, 3, 5, 7]), &gpu).require_grad();
    let y = upsample_bilinear(x.clone(), [10, 14], Upsample::Matmul);
    let (abs, _) = errors(&to_vec(y.clone()), &reference);
    assert!(abs <= 1e-5, "max abs diff {abs}");
    let grads = y.sum().backward();
    let g = to_vec(x.grad(&grads).expect("gradient"));
    assert!(g.iter().all(|v| v.is_finite() && *v >= 0.0));
}

#[test]
#[ignore = "needs ../shared"]
fn network_on_wgpu_agrees_with_flex_and_a_training_step_is_finite() {
    let dir = fixtures();
    let gpu = model::backend::wgpu_device();
    let cpu = model::backend::default_device();
    let path = dir.join("densedepth_tiny.pth");
    let io = SafeFile::open(&dir.join("densedepth_tiny_io.safetensors"));
    let on_cpu = to_vec(load_pytorch(&path, &cpu).unwrap().model.forward(io.tensor::<4>("input", &cpu)));
    let on_gpu = to_vec(load_pytorch(&path, &gpu).unwrap().model.forward(io.tensor::<4>("input", &gpu)));
    let (abs, rel) = errors(&on_gpu, &on_cpu);
    assert!(rel <= 1e-3, "wgpu vs flex: max_abs_err={abs} max_rel_err={rel}");

    let train = gpu.autodiff();
    let (model, images, target) = {
        let _rng = RNG.lock().unwrap_or_else(|e| e.into_inner());
        let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&train);
        let images = Tensor::<4>::random([1, 3, 64, 64], Distribution::Uniform(0.0, 1.0), &train);
        let target = Tensor::<4>::random([1, 1, 32, 32], Distribution::Uniform(10.0, 1000.0), &train);
        (model, images, target)
    };
    let loss = DepthLossConfig::new().forward(model.forward(images), target).total;
    assert!(to_vec(loss.clone())[0].is_finite());
    let grads = loss.backward();
    let g = to_vec(model.decoder.up2.conv_a.weight.val().grad(&grads).expect("gradient"));
    assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|v| *v != 0.0));
}

#[test]
fn a_few_adam_steps_on_wgpu_lower_the_loss() {
    use burn::optim::{AdamConfig, GradientsParams};
    let train = model::backend::wgpu_device().autodiff();
    let mut net = {
        let _rng = RNG.lock().unwrap_or_else(|e| e.into_inner());
        train.seed(3);
        DenseDepthConfig::new(DenseNetConfig::tiny()).init(&train)
    };
    let image: Vec<f32> = (0..2 * 3 * 64 * 64).map(|i| ((i * 131) % 997) as f32 / 997.0).collect();
    // A smooth depth map in the loss' range (10..1000), so that a few steps can reach towards it.
    let depth: Vec<f32> = (0..2 * 32 * 32)
        .map(|i| {
            let (b, y, x) = (i / 1024, (i / 32) % 32, i % 32);
            200.0 + 100.0 * b as f32 + 80.0 * (x as f32 / 6.0).sin() * (y as f32 / 9.0).cos()
        })
        .collect();
    let images = Tensor::<4>::from_data(TensorData::new(image, [2, 3, 64, 64]), &train);
    let target = Tensor::<4>::from_data(TensorData::new(depth, [2, 1, 32, 32]), &train);
    let mut optim = AdamConfig::new().init();
    let mut losses = Vec::new();
    // A small learning rate: Adam's first steps move every weight by about the rate whatever its
    // gradient, and at 1e-2 the tiny network overshot on one initialisation (loss 129.6 -> 155.8).
    for _ in 0..6 {
        let loss = DepthLossConfig::new().forward(net.forward(images.clone()), target.clone()).total;
        losses.push(to_vec(loss.clone())[0]);
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        net = optim.step(1e-3, net, grads);
    }
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
    // Measured here over seven seeds: it fell at every step on each; the assertion asks less.
    assert!(losses[5] < losses[0], "the loss must fall on a fixed batch: {losses:?}");
}
