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

/// A bundle with an untrained tiny network for simulated unit 3, with its reference image.
pub fn bundle(dir: &Path) -> Renderer {
    let unit = SensorUnit::from_seed(3, 25.0);
    let renderer = Renderer::for_crop(&unit);
    let device = model::backend::default_device();
    device.seed(1);
    let net = DenseDepthConfig::new(DenseNetConfig::tiny()).init(&device);
    let file = bundle_file(DenseDepthConfig::new(DenseNetConfig::tiny()), &unit);
    let reference = sensor::frame::encode_png_rgb(&renderer.reference_image(1));
    write_bundle(dir, &net, &file, Some(&reference), &[]).unwrap();
    renderer
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
