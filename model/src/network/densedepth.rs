//! The whole network.

use burn::module::Module;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use super::config::DenseDepthConfig;
use super::decoder::{Decoder, Heads};
use super::densenet::DenseNetEncoder;
use super::upsample::{Upsample, upsample_mode_for};

/// DenseDepth: an encoded crop ([N, C, H, W], C = 3 for RGB in [0, 1], 6 with the reference
/// difference; H and W at least 29, any size) to depth in network units at half resolution
/// ([N, 1, ceil(H/2), ceil(W/2)]), or at the input's with `DenseDepthConfig::full_resolution`.
#[derive(Module, Debug)]
pub struct DenseDepth {
    pub encoder: DenseNetEncoder,
    pub decoder: Decoder,
}

impl DenseDepthConfig {
    pub fn init(&self, device: &Device) -> DenseDepth {
        let (skips, bottleneck) = self.encoder.skip_channels();
        DenseDepth {
            encoder: self.encoder.init_for(self.input.count(), device),
            decoder: Decoder::new(
                skips,
                bottleneck,
                self.decoder_channels(),
                self.full_resolution.then_some(self.input.count()),
                self.pressure,
                self.force_head.map(|hidden| (hidden, self.force_head_reads_transition2())),
                device,
            ),
        }
    }
}

impl DenseDepth {
    /// Forward pass. Upsampling uses Burn's native bilinear kernel unless gradients are being
    /// recorded on a backend whose `interpolate` has no backward pass.
    pub fn forward(&self, images: Tensor<4>) -> Tensor<4> {
        self.forward_heads(images).depth
    }

    /// Depth and, where the network has its channel, pressure (both `[N, 1, OH, OW]`, network
    /// units; see `PressureScale`).
    pub fn forward_heads(&self, images: Tensor<4>) -> Heads {
        let mode = upsample_mode_for(&images.device());
        self.forward_with(images, mode)
    }

    /// Whether this network has the pressure output.
    pub fn has_pressure(&self) -> bool {
        self.decoder.pressure.is_some()
    }

    /// This network with a pressure output, freshly initialised from `device`'s generator where
    /// it has none: a depth-only network fine-tuned into one that also reports force.
    pub fn with_pressure_output(mut self, device: &Device) -> Self {
        if self.decoder.pressure.is_none() {
            let features = self.decoder.conv3.weight.dims()[1];
            self.decoder.pressure = Some(super::decoder::conv3([features, 1], device));
        }
        self
    }

    /// Whether this network has the force head.
    pub fn has_force_head(&self) -> bool {
        self.decoder.force.is_some()
    }

    /// This network with a force head of `hidden` width (reading transition2 too where `skip`),
    /// freshly initialised from `device`'s generator where it has none: a network trained
    /// without one fine-tuned into one with it.
    pub fn with_force_head(mut self, hidden: usize, skip: bool, device: &Device) -> Self {
        if self.decoder.force.is_none() {
            let features = self.decoder.conv2.weight.dims()[1];
            let transition2 = self.encoder.transition2.conv.weight.dims()[0];
            self.decoder.force = Some(super::ForceHead::new(features, skip.then_some(transition2), hidden, device));
        }
        self
    }

    /// The force head's pooled features (`[N, hidden]`, [`ForceHead::pooled`]) on `images`, as
    /// the forward computes them, where the network has the head: what a map fitted in closed
    /// form reads. Panics on an input [`check_input`](Self::check_input) refuses.
    pub fn force_features(&self, images: Tensor<4>) -> Option<Tensor<2>> {
        let head = self.decoder.force.as_ref()?;
        if let Err(e) = self.check_input(images.dims()) {
            panic!("{e}");
        }
        let plain_flex = crate::kernels::plain_flex(&images.device());
        let run = || {
            let s = self.encoder.forward(images);
            head.pooled(relu(s.norm5), s.transition2)
        };
        Some(if plain_flex { crate::backend::in_pool(run) } else { run() })
    }

    /// Panics on an input [`check_input`](Self::check_input) refuses.
    pub fn forward_with(&self, images: Tensor<4>, mode: Upsample) -> Heads {
        self.run_marked(images, mode, &mut |_| {})
    }

    /// Milliseconds of each stage of one inference forward (the encoder's stem, blocks and
    /// transitions, the decoder's blocks and heads), in order, run as
    /// [`forward_with`](Self::forward_with) runs it: where a small network's time goes.
    pub fn stage_ms(&self, images: Tensor<4>) -> Vec<(&'static str, f64)> {
        let mode = upsample_mode_for(&images.device());
        let mut stages = Vec::new();
        let mut last = std::time::Instant::now();
        let heads = self.run_marked(images, mode, &mut |name| {
            let now = std::time::Instant::now();
            stages.push((name, (now - last).as_secs_f64() * 1e3));
            last = now;
        });
        let _ = heads.depth.into_data();
        stages.push(("output", last.elapsed().as_secs_f64() * 1e3));
        stages
    }

    /// The checked forward, calling `mark` with each stage's name as it ends. Panics on an
    /// input [`check_input`](Self::check_input) refuses.
    fn run_marked(&self, images: Tensor<4>, mode: Upsample, mark: &mut (dyn FnMut(&'static str) + Send)) -> Heads {
        if let Err(e) = self.check_input(images.dims()) {
            panic!("{e}");
        }
        let plain_flex = crate::kernels::plain_flex(&images.device());
        let run = || {
            let skips = self.encoder.forward_marked(images.clone(), mark);
            self.decoder.forward_marked(skips, images, mode, mark)
        };
        // Inference on the CPU from inside rayon's pool (`backend::in_pool`). A training forward
        // is not hopped call by call: Burn keeps batch norm's running statistics per thread and
        // averages them when read, so forwards on whichever worker takes each would make them
        // follow the schedule (a run and its killed-and-resumed twin then differ; BENCHMARKS.md).
        // `train`'s fit runs its whole epoch loop on one worker instead.
        if plain_flex { crate::backend::in_pool(run) } else { run() }
    }

    /// Whether this network takes an input of shape `[N, C, H, W]`: its channel count, both
    /// sides at least 29 px. Callers with inputs from outside check here and report the error.
    pub fn check_input(&self, [_, c, h, w]: [usize; 4]) -> Result<(), crate::ConfigError> {
        let want = self.encoder.conv0.weight.dims()[1];
        if c != want {
            return Err(crate::ConfigError::InputChannels { want, got: c });
        }
        DenseDepthConfig::check_input_hw([h, w])
    }

    /// The same network for inference only: BatchNorms that follow a convolution are folded
    /// into it (see `DenseNetEncoder::folded`). Do not train the result.
    pub fn folded(self) -> Self {
        DenseDepth { encoder: self.encoder.folded(), decoder: self.decoder }
    }

    /// Number of trainable parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[should_panic(expected = "at least 29 px")]
    fn input_sides_below_29_are_refused() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny()).init(&device);
        model.forward(Tensor::zeros([1, 3, 28, 64], &device));
    }

    #[test]
    fn input_shapes_are_checked_without_a_panic() {
        let device = crate::backend::default_device();
        let config = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny());
        let model = config.clone().with_input(crate::InputChannels::RgbDifference).init(&device);
        assert_eq!(model.check_input([1, 6, 570, 570]), Ok(()));
        let e = model.check_input([1, 3, 570, 570]).unwrap_err().to_string();
        assert!(e.contains("takes 6 input channels") && e.contains("got 3"), "{e}");
        let e = config.init(&device).check_input([2, 3, 570, 20]).unwrap_err().to_string();
        assert!(e.contains("570x20") && e.contains("at least 29"), "{e}");
    }

    /// Sides that are not multiples of 32 (odd ones included) give the output size
    /// `output_hw` promises, at half and at full resolution, and the folded inference network
    /// agrees with the training graph on them.
    #[test]
    fn any_input_size_from_29_gives_the_promised_output() {
        use burn::tensor::{Distribution, Tolerance};
        let device = crate::backend::default_device();
        for full_resolution in [false, true] {
            let config =
                DenseDepthConfig::new(crate::network::DenseNetConfig::tiny()).with_full_resolution(full_resolution);
            let model = config.init(&device);
            // 29: the smallest side, a 1x1 bottleneck that the first block upsamples.
            for [h, w] in [[29, 29], [29, 40], [32, 32], [33, 47], [75, 100], [97, 64]] {
                let x = Tensor::<4>::random([2, 3, h, w], Distribution::Uniform(0.0, 1.0), &device);
                let out = model.forward(x.clone());
                let [n, c, oh, ow] = out.dims();
                assert!(out.to_data().iter::<f32>().all(f32::is_finite), "{h}x{w}: not finite");
                assert_eq!([n, c, oh, ow], [2, 1, config.output_hw([h, w])[0], config.output_hw([h, w])[1]]);
                let folded = model.clone().folded().forward(x);
                folded.into_data().assert_approx_eq::<f32>(&out.into_data(), Tolerance::rel_abs(1e-4, 1e-5));
            }
        }
    }

    /// `bench table`'s family draws a curve only if its presets are spaced: each at least twice
    /// the parameters of the one before, from compact to DenseNet-121.
    #[test]
    fn the_preset_family_grows_in_steps() {
        use crate::network::DenseNetConfig;
        let device = crate::backend::default_device();
        let family = [
            DenseNetConfig::compact(),
            DenseNetConfig::small(),
            DenseNetConfig::medium(),
            DenseNetConfig::densenet121(),
        ];
        let params: Vec<usize> =
            family.into_iter().map(|e| DenseDepthConfig::new(e).init(&device).parameters()).collect();
        // compact, small, medium, DenseNet-121: 0.19, 0.87, 3.26, 10.7 M.
        for pair in params.windows(2) {
            assert!(pair[1] >= 2 * pair[0], "{params:?}");
        }
    }

    #[test]
    fn channels_and_output_size_follow_the_config() {
        let device = crate::backend::default_device();
        let base = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny());
        for (input, full, want) in [
            (crate::InputChannels::Rgb, false, [2, 1, 32, 48]),
            (crate::InputChannels::RgbDifference, false, [2, 1, 32, 48]),
            (crate::InputChannels::RgbDifference, true, [2, 1, 64, 96]),
        ] {
            let config = base.clone().with_input(input).with_full_resolution(full);
            let model = config.init(&device);
            let out = model.forward(Tensor::zeros([2, input.count(), 64, 96], &device));
            assert_eq!(out.dims(), want, "{input:?} full {full}");
            assert_eq!(config.output_hw([64, 96]), [want[2], want[3]]);
        }
    }

    /// The pressure's gradient reaches the pressure convolution alone, never the decoder's
    /// features that depth shares; depth's reaches those features.
    #[test]
    fn the_pressure_trains_its_convolution_alone() {
        let device = crate::backend::default_device().autodiff();
        let net = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny()).with_pressure(true).init(&device);
        let x = Tensor::<4>::random([1, 3, 40, 40], burn::tensor::Distribution::Uniform(0.0, 1.0), &device);
        let heads = net.forward_heads(x.clone());
        let pressure = heads.pressure.unwrap();
        let conv = net.decoder.pressure.as_ref().unwrap();
        let shared = &net.decoder.up4.conv_b;
        let grads = pressure.clone().sum().backward();
        assert!(conv.weight.grad(&grads).is_some() && shared.weight.grad(&grads).is_none());
        let grads = heads.depth.sum().backward();
        assert!(conv.weight.grad(&grads).is_none() && shared.weight.grad(&grads).is_some());
        // Without autodiff there is nothing to cut: the same output on the depth's grid.
        let plain = net.valid().forward_heads(x.inner());
        assert_eq!(plain.pressure.unwrap().dims(), plain.depth.dims());
    }

    /// The head's output is its linear map of [`DenseDepth::force_features`], and a map given
    /// by [`ForceHead::with_map`] is the one the forward then applies.
    #[test]
    fn the_force_head_is_a_linear_map_of_its_features() {
        let device = crate::backend::default_device();
        let config = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny())
            .with_force_head(Some(8))
            .with_force_head_skip(Some(true));
        let net = config.init(&device);
        let x = Tensor::<4>::random([2, 3, 48, 48], burn::tensor::Distribution::Uniform(0.0, 1.0), &device);
        let values = |t: Tensor<2>| t.into_data().try_to_vec::<f32>().unwrap();
        let apply = |h: &[f32], (w, b): &(Vec<f32>, [f32; 3])| -> Vec<f32> {
            let hidden = w.len() / 3;
            (0..h.len() / hidden)
                .flat_map(|n| (0..3).map(move |k| (n, k)))
                .map(|(n, k)| b[k] + (0..hidden).map(|j| h[n * hidden + j] * w[j * 3 + k]).sum::<f32>())
                .collect()
        };
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(p, q)| (p - q).abs() <= 1e-4 * (1.0 + q.abs()));
        let features = values(net.force_features(x.clone()).unwrap());
        assert_eq!(features.len(), 2 * 8);
        let head = net.decoder.force.as_ref().unwrap();
        let out = values(net.forward_heads(x.clone()).force.unwrap());
        assert!(close(&out, &apply(&features, &head.map())), "{out:?}");
        // A new map: a distinct number in each place, and the bias.
        let map = ((0..24).map(|i| 0.1 * i as f32 - 1.0).collect::<Vec<_>>(), [0.5, -2.0, 3.0]);
        let mut net = net;
        net.decoder.force = net.decoder.force.map(|h| h.with_map(&map.0, map.1));
        assert_eq!(net.decoder.force.as_ref().unwrap().map(), map);
        let out = values(net.forward_heads(x.clone()).force.unwrap());
        assert!(close(&out, &apply(&features, &map)), "{out:?}");
        assert_eq!(values(net.force_features(x).unwrap()), features, "the features do not read the map");
        assert!(
            DenseDepthConfig::new(crate::network::DenseNetConfig::tiny())
                .init(&device)
                .force_features(Tensor::<4>::zeros([1, 3, 48, 48], &device))
                .is_none()
        );
    }

    #[test]
    fn a_widened_stem_computes_what_the_rgb_one_did() {
        let device = crate::backend::default_device();
        let model = DenseDepthConfig::new(crate::network::DenseNetConfig::tiny()).init(&device);
        let x = Tensor::<4>::random([1, 3, 64, 64], burn::tensor::Distribution::Uniform(0.0, 1.0), &device);
        let extra = Tensor::<4>::random([1, 3, 64, 64], burn::tensor::Distribution::Uniform(-1.0, 1.0), &device);
        let a = model.forward(x.clone()).into_data().try_to_vec::<f32>().unwrap();
        let wide = DenseDepth { encoder: model.encoder.with_input_channels(6), decoder: model.decoder };
        let b = wide.forward(Tensor::cat(vec![x, extra], 1)).into_data().try_to_vec::<f32>().unwrap();
        let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{worst}");
    }
}
