//! Helpers the integration tests share: a tiny bundle for a simulated unit, pressed frames.

#![allow(dead_code)] // each test file uses its own part

use std::path::Path;

use dataset::{Renderer, SensorUnit};
use model::bundle::{BundleFile, write_bundle};
use model::{DenseDepthConfig, DenseNetConfig, DepthScale};

/// The description of a bundle of `model` at 64x64 for `unit`.
pub fn bundle_file(model: DenseDepthConfig, unit: &SensorUnit) -> BundleFile {
    BundleFile::new(model, [64, 64], unit.sensor.clone(), DepthScale::paper(unit.sensor.max_depth_mm as f32))
}

/// A bundle with an untrained tiny network for simulated unit 3, with its reference image and
/// a contact gate fitted to a few of the unit's frames (untouched, and dented 0.3 mm).
pub fn bundle(dir: &Path) -> Renderer {
    bundle_with(dir, DenseDepthConfig::new(DenseNetConfig::tiny()), |net, _| net)
}

/// [`bundle`] of the network `config` gives, changed by `edit` (given the bundle's depth scale)
/// before it is written.
pub fn bundle_with(
    dir: &Path,
    config: DenseDepthConfig,
    edit: impl FnOnce(model::DenseDepth, &DepthScale) -> model::DenseDepth,
) -> Renderer {
    let unit = SensorUnit::from_seed(3, 25.0);
    let renderer = Renderer::for_crop(&unit);
    let device = model::backend::default_device();
    device.seed(1);
    let mut file = bundle_file(config.clone(), &unit);
    let net = edit(config.init(&device), &file.depth_scale);
    let reference_image = renderer.reference_image(1);
    let mask = unit.sensor.valid_mask();
    let n = renderer.grid().width as usize;
    let frames: Vec<sensor::gate::GateFrame> = (0..8u64)
        .map(|k| {
            let mut depth = vec![0f32; n * n];
            if k % 2 == 1 {
                let (x0, y0) = (150 + 30 * k as usize, 200 + 20 * k as usize);
                for y in y0..y0 + 12 {
                    depth[y * n + x0..y * n + x0 + 12].fill(0.3);
                }
            }
            let frame = renderer.render(&depth, Some(100 + k));
            let contact: Vec<bool> = depth.iter().map(|&d| d > sensor::CONTACT_THRESHOLD_MM).collect();
            sensor::gate::GateFrame::measure(&frame, &reference_image, &mask, &contact)
        })
        .collect();
    let gate = sensor::gate::fit(&frames).unwrap();
    let tally = sensor::gate::Tally::of(&gate, &frames);
    file.contact_gate = Some(model::bundle::GateRecord { gate, train: tally, test: tally });
    let reference = sensor::frame::encode_png_rgb(&reference_image);
    write_bundle(dir, &net, &file, Some(&reference), &[]).unwrap();
    renderer
}

/// `count` samples of `renderer`'s unit (3) from the procedural kit, `test_fraction` of them
/// test samples, with force labels.
pub fn dataset_of(renderer: &Renderer, data: &Path, count: u32, test_fraction: f32) {
    dataset_with(renderer, data, count, |params| formats::dataset::GeneratorParams { test_fraction, ..params });
}

/// `count` samples of `renderer`'s unit (3) from the procedural kit (generator seed 4), with the
/// generator's parameters as `edit` makes them.
pub fn dataset_with(
    renderer: &Renderer,
    data: &Path,
    count: u32,
    edit: impl FnOnce(formats::dataset::GeneratorParams) -> formats::dataset::GeneratorParams,
) {
    let kit = dataset::Kit::procedural(25.0);
    let params = edit(formats::dataset::GeneratorParams {
        unit: Some(3),
        ..formats::dataset::GeneratorParams::new(4, count, &kit.source)
    });
    let unit = renderer.unit().clone();
    dataset::generate::Generator {
        out: data.to_path_buf(),
        sensor: &unit.sensor,
        kit: &kit,
        params,
        skipping: dataset::Skipping::On,
        renderer: Some(renderer),
    }
    .run()
    .unwrap();
}

/// A frame with a 1 mm dent in the middle.
pub fn pressed(renderer: &Renderer) -> (Vec<f32>, image::RgbImage) {
    let n = renderer.grid().width as usize;
    let mut depth = vec![0.0; n * n];
    for y in 260..310 {
        for x in 260..310 {
            depth[y * n + x] = 1.0;
        }
    }
    let img = renderer.render(&depth, Some(9));
    (depth, img)
}

/// The depth (mm) and pressure (kPa) a [`constant`] network reads everywhere.
pub const DEPTH_MM: f32 = 1.0;
pub const PRESSURE_KPA: f32 = 50.0;

/// A network whose outputs are constants: `DEPTH_MM` of depth and `PRESSURE_KPA` of pressure at
/// every pixel, whatever the frame (weights zero, biases set).
pub fn constant(mut net: model::DenseDepth, scale: &DepthScale) -> model::DenseDepth {
    use burn::module::Param;
    use burn::tensor::Tensor;
    let set = |conv: &mut burn::nn::conv::Conv2d, value: f32| {
        conv.weight = Param::from_tensor(conv.weight.val().zeros_like());
        let bias = conv.bias.as_ref().expect("a bias").val();
        conv.bias = Some(Param::from_tensor(Tensor::full(bias.dims(), value, &bias.device())));
    };
    set(&mut net.decoder.conv3, scale.to_net(DEPTH_MM));
    set(net.decoder.pressure.as_mut().expect("the pressure output"), PRESSURE_KPA / model::PRESSURE_KPA_PER_UNIT);
    net
}

/// The tiny network with the pressure output.
pub fn pressure_config() -> DenseDepthConfig {
    DenseDepthConfig::new(DenseNetConfig::tiny()).with_pressure(true)
}
