//! Data-parallel training: a step shared over devices gives the batch's mean gradient, frozen
//! parameters stay frozen on every device, a GPU share agrees with a CPU share, and a run over
//! two devices learns.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor};
use formats::Split;
use model::{DenseDepth, DenseDepthConfig, DenseNetConfig, DepthLossConfig};
use train::data::{DepthBatcher, DepthDataset, DepthItem};
use train::parallel::{DataParallel, share_sizes};
use train::{FitConfig, Start, fit_on};

use crate::common;
use common::tiny_dataset;

/// Every gradient the module has in `grads`, parameter by parameter, in visiting order.
struct Collect<'a> {
    grads: &'a GradientsParams,
    out: Vec<Option<Vec<f32>>>,
}

impl ModuleVisitor for Collect<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let g = self.grads.get::<D>(param.id).map(|t| t.into_data().try_to_vec::<f32>().unwrap());
        self.out.push(g);
    }
}

fn gradients(net: &DenseDepth, grads: &GradientsParams) -> Vec<Option<Vec<f32>>> {
    let mut c = Collect { grads, out: Vec::new() };
    net.visit(&mut c);
    c.out
}

struct Setup {
    items: Vec<DepthItem>,
    batcher: DepthBatcher,
    loss: DepthLossConfig,
    _tmp: tempfile::TempDir,
}

fn setup(n: usize) -> Setup {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let set = DepthDataset::open(&data, Some(Split::Train), [64, 64]).unwrap();
    let items = (0..n).map(|i| set.load(i, None).unwrap()).collect();
    let batcher = DepthBatcher::for_data(&set);
    let loss = DepthLossConfig::new().with_dynamic_range(set.scale.range() as f64);
    Setup { items, batcher, loss, _tmp: tmp }
}

/// A fresh tiny network on `device` (plain) and an independent copy of it: the same weights and
/// parameter ids, its own batch-norm running statistics.
fn twins(device: &Device) -> (DenseDepth, DenseDepth) {
    device.seed(11);
    let net = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device.clone().autodiff());
    let copy = net.valid().train();
    (net, copy)
}

/// Within `rel` of the larger magnitude of the two, that magnitude taken as at least 1e-5: a
/// parameter whose gradient all but vanishes (4e-7 and 2e-6 on this batch for two of them) is
/// the difference of much larger terms, and two devices' summation orders differ there by
/// float rounding alone.
fn close(a: &[f32], b: &[f32], rel: f32) -> bool {
    let scale = a.iter().chain(b).fold(0f32, |m, v| m.max(v.abs())).max(1e-5);
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= rel * scale)
}

#[test]
fn shares_are_as_even_as_can_be() {
    assert_eq!(share_sizes(5, 2), vec![3, 2]);
    assert_eq!(share_sizes(4, 4), vec![1, 1, 1, 1]);
    assert_eq!(share_sizes(2, 3), vec![1, 1], "no device gets an empty share");
    assert_eq!(share_sizes(7, 1), vec![7]);
}

#[test]
fn two_shares_give_the_mean_of_their_gradients_and_the_first_keeps_its_statistics() {
    let s = setup(4);
    let cpu = model::backend::default_device();
    let (net, copy) = twins(&cpu);
    let one = DataParallel::new(std::slice::from_ref(&cpu), s.batcher.clone(), s.loss.clone()).unwrap();
    let a = one.step(&net, s.items[..2].to_vec()).unwrap();
    let after_a = net.valid();
    let b = one.step(&copy.valid().train(), s.items[2..].to_vec()).unwrap();

    let two = DataParallel::new_allowing_repeats(&[cpu.clone(), cpu.clone()], s.batcher.clone(), s.loss.clone());
    let both = two.unwrap().step(&copy, s.items.clone()).unwrap();
    assert!(
        (both.loss - (a.loss + b.loss) / 2.0).abs() <= 1e-6 * both.loss.abs(),
        "{} vs {} {}",
        both.loss,
        a.loss,
        b.loss
    );
    let (ga, gb, g) = (gradients(&net, &a.grads), gradients(&net, &b.grads), gradients(&net, &both.grads));
    // Batch-norm running statistics are visited too, without gradients.
    let has = |g: &Vec<Option<Vec<f32>>>| g.iter().map(Option::is_some).collect::<Vec<_>>();
    assert_eq!(has(&g), has(&ga), "the same parameters have gradients");
    assert!(g.iter().flatten().count() > 50);
    for ((ga, gb), g) in ga.iter().zip(&gb).zip(&g) {
        let (Some(ga), Some(gb), Some(g)) = (ga, gb, g) else { continue };
        let mean: Vec<f32> = ga.iter().zip(gb).map(|(x, y)| (x + y) / 2.0).collect();
        assert!(close(g, &mean, 1e-5), "the shared step's gradient is the mean of the shares'");
    }
    // Running statistics come from the first device's share, as a step on it alone gives them.
    let x = Tensor::<4>::ones([1, 3, 64, 64], &cpu);
    let v = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(v(copy.valid().forward(x.clone())), v(after_a.forward(x)));
}

#[test]
fn a_frozen_encoder_gets_no_gradient_from_any_device() {
    let s = setup(3);
    let cpu = model::backend::default_device();
    let (mut net, _) = twins(&cpu);
    net.encoder = net.encoder.no_grad();
    let two = DataParallel::new_allowing_repeats(&[cpu.clone(), cpu.clone()], s.batcher, s.loss).unwrap();
    let step = two.step(&net, s.items.clone()).unwrap();
    let mut c = Collect { grads: &step.grads, out: Vec::new() };
    net.encoder.visit(&mut c);
    assert!(c.out.iter().all(Option::is_none), "the encoder is frozen on the second device too");
    let mut c = Collect { grads: &step.grads, out: Vec::new() };
    net.decoder.visit(&mut c);
    assert!(c.out.iter().flatten().count() > 10, "the decoder learns");
}

#[test]
fn a_device_named_twice_is_refused() {
    let s = setup(1);
    let cpu = model::backend::default_device();
    let e = DataParallel::new(&[cpu.clone(), cpu], s.batcher, s.loss).err().unwrap();
    assert!(e.to_string().contains("twice"), "{e}");
}

/// A share on the GPU (Mesa's lavapipe in CI) gives what the same share gives on the CPU, and a
/// run over both devices learns. Skipped, saying so, in builds or on machines without wgpu.
#[test]
fn a_gpu_share_agrees_with_a_cpu_share_and_a_run_over_both_learns() {
    let Ok(gpu) = model::backend::working_device("wgpu") else {
        eprintln!("no wgpu device: skipped");
        return;
    };
    let s = setup(4);
    let cpu = model::backend::default_device();
    let (net, copy) = twins(&cpu);
    let mixed = DataParallel::new(&[cpu.clone(), gpu.clone()], s.batcher.clone(), s.loss.clone()).unwrap();
    let on_gpu = mixed.step(&net, s.items.clone()).unwrap();
    let on_cpu = DataParallel::new_allowing_repeats(&[cpu.clone(), cpu.clone()], s.batcher, s.loss).unwrap();
    let on_cpu = on_cpu.step(&copy, s.items.clone()).unwrap();
    assert!((on_gpu.loss - on_cpu.loss).abs() <= 1e-4 * on_cpu.loss.abs(), "{} vs {}", on_gpu.loss, on_cpu.loss);
    // A tensor whose gradient is zero in exact arithmetic (a convolution's bias ahead of a batch
    // norm) holds only rounding noise, whose size follows the gradients it was summed from, not its
    // own: so each tensor is held to 1e-3 of its own scale, or 1e-5 of the largest gradient's.
    let (g_all, c_all) = (gradients(&net, &on_gpu.grads), gradients(&net, &on_cpu.grads));
    let largest = c_all.iter().flatten().flatten().fold(0f32, |m, v| m.max(v.abs()));
    assert!(largest > 0.0, "the step has gradients");
    for (g, c) in g_all.iter().zip(&c_all) {
        assert_eq!(g.is_some(), c.is_some());
        if let (Some(g), Some(c)) = (g, c) {
            let scale = g.iter().chain(c).fold(0f32, |m, v| m.max(v.abs()));
            let worst = g.iter().zip(c).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
            let allowed = (1e-3 * scale).max(1e-5 * largest);
            assert!(
                g.len() == c.len() && worst <= allowed,
                "GPU and CPU shares agree: worst difference {worst} at scale {scale} (largest gradient {largest})"
            );
        }
    }

    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    tiny_dataset(&data);
    let config = FitConfig { epochs: 2, batch: 4, lr: 3e-3, seed: 5, ..FitConfig::new(data, [64, 64]) };
    let start = Start { model_config: DenseDepthConfig::new(DenseNetConfig::tiny()), weights: None };
    let fitted = fit_on(&tmp.path().join("run"), &config, start, &[cpu, gpu], false).unwrap();
    let h = &fitted.state.history;
    assert!(h.iter().all(|m| m.train_loss.is_finite() && m.val_l1_mm.is_finite()), "{h:?}");
    assert!(h[1].val_loss < h[0].val_loss, "validation loss must drop: {h:?}");
}

#[test]
fn a_failing_share_names_its_device_and_the_next_step_is_clean() {
    let s = setup(4);
    let cpu = model::backend::default_device();
    let (net, _) = twins(&cpu);
    let two = DataParallel::new_allowing_repeats(&[cpu.clone(), cpu], s.batcher, s.loss).unwrap();
    let mut bad = s.items.clone();
    bad[3].image.truncate(10);
    let e = two.step(&net, bad).err().expect("a malformed sample in the second share fails the step");
    assert!(e.to_string().contains("training on"), "{e}");
    let good = two.step(&net, s.items.clone()).unwrap();
    assert!(good.loss.is_finite() && !good.grads.is_empty());
}
