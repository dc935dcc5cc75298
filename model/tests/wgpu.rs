//! The GPU code path, run on wgpu (Mesa's lavapipe in CI): the trainable upsample and a
//! training step work where Burn's `interpolate` has no backward pass, and the whole network
//! agrees with flex.

#![cfg(feature = "wgpu")]

mod common;

use burn::tensor::{Distribution, Tensor, TensorData};
use common::{SafeFile, errors, fixtures, to_vec};
use model::import::load_pytorch;
use model::upsample_mode_for;
use model::{DenseDepthConfig, DenseNetConfig, DepthLossConfig};
use model::{Upsample, upsample_bilinear};

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
    let model = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&train);
    let images = Tensor::<4>::random([1, 3, 64, 64], Distribution::Uniform(0.0, 1.0), &train);
    let target = Tensor::<4>::random([1, 1, 32, 32], Distribution::Uniform(10.0, 1000.0), &train);
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
    train.seed(3);
    let mut net = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&train);
    let image: Vec<f32> = (0..2 * 3 * 64 * 64).map(|i| ((i * 131) % 997) as f32 / 997.0).collect();
    let depth: Vec<f32> = (0..2 * 32 * 32).map(|i| 10.0 + ((i * 17) % 300) as f32).collect();
    let images = Tensor::<4>::from_data(TensorData::new(image, [2, 3, 64, 64]), &train);
    let target = Tensor::<4>::from_data(TensorData::new(depth, [2, 1, 32, 32]), &train);
    let mut optim = AdamConfig::new().init();
    let mut losses = Vec::new();
    for _ in 0..6 {
        let loss = DepthLossConfig::new().forward(net.forward(images.clone()), target.clone()).total;
        losses.push(to_vec(loss.clone())[0]);
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        net = optim.step(1e-2, net, grads);
    }
    assert!(losses.iter().all(|l| l.is_finite()), "{losses:?}");
    assert!(losses[5] < losses[0], "the loss must fall on a fixed batch: {losses:?}");
}
