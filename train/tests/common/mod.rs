//! What the training tests share.

use std::path::Path;

use dataset::Kit;
use dataset::generate::generate_with_unit;
use formats::dataset::GeneratorParams;

/// 24 samples of simulated unit 3, a quarter of them test samples.
pub fn tiny_dataset(dir: &Path) {
    let kit = Kit::procedural(25.0);
    let params = GeneratorParams { test_fraction: 0.25, ..GeneratorParams::new(2, 24, &kit.source) };
    generate_with_unit(dir, &kit, 3, 25.0, params).unwrap();
}
