//! What the training tests share.

use std::path::Path;

use dataset::Kit;
use dataset::generate::generate_with_unit;
use formats::dataset::GeneratorParams;

/// 24 samples of simulated unit 3, a quarter of them test samples.
pub fn tiny_dataset(dir: &Path) {
    unit_dataset(dir, 3, 24);
}

/// `count` samples of simulated unit `unit`, a quarter of them test samples.
pub fn unit_dataset(dir: &Path, unit: u64, count: u32) {
    generated(dir, unit, count, 25.0, 0.25);
}

/// `count` samples of simulated unit `unit` of a sensor of `radius_mm`, `test_fraction` of them
/// test samples.
pub fn generated(dir: &Path, unit: u64, count: u32, radius_mm: f64, test_fraction: f32) {
    let kit = Kit::procedural(radius_mm as f32);
    let params = GeneratorParams { test_fraction, ..GeneratorParams::new(2, count, &kit.source) };
    generate_with_unit(dir, &kit, unit, radius_mm, params).unwrap();
}
