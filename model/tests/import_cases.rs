//! PyTorch import: legacy keys, encoder-only torchvision checkpoints, and broken files.

use crate::common;

use std::path::PathBuf;

use common::{SafeFile, errors, fixtures, to_vec};
use model::import::load_pytorch;
use model::{DenseNetConfig, Upsample};

fn data(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data")).join(name)
}

#[test]
#[ignore = "needs ../shared"]
fn legacy_torchvision_keys_load_the_same_model() {
    let dir = fixtures();
    let device = model::backend::default_device();
    let imported = load_pytorch(&data("densedepth_tiny_legacy.pth"), &device).unwrap();
    assert_eq!(imported.config.encoder, DenseNetConfig::tiny());
    let io = SafeFile::open(&dir.join("densedepth_tiny_io.safetensors"));
    let out = imported.model.forward_with(io.tensor::<4>("input", &device), Upsample::Native).depth;
    let (abs, rel) = errors(&to_vec(out), &io.get("output").0);
    assert!(rel <= 1e-4, "max_abs_err={abs} max_rel_err={rel}");
}

#[test]
fn torchvision_densenet_checkpoint_fills_the_encoder() {
    let device = model::backend::default_device();
    let imported = load_pytorch(&data("densenet_micro.pth"), &device).unwrap();
    assert!(imported.encoder_only);
    assert_eq!(imported.config.encoder, DenseNetConfig::new(4, [1, 2, 1, 1], 8, 2));
    let io = SafeFile::open(&data("densenet_micro_io.safetensors"));
    let skips = imported.model.encoder.forward(io.tensor::<4>("input", &device));
    let (abs, rel) = errors(&to_vec(skips.norm5), &io.get("norm5").0);
    assert!(rel <= 1e-4, "max_abs_err={abs} max_rel_err={rel}");
}

#[test]
fn broken_files_name_the_file_and_the_tensor() {
    let device = model::backend::default_device();
    let err = |name: &str| load_pytorch(&data(name), &device).err().expect("must fail").to_string();

    let e = err("micro_missing.pth");
    assert!(
        e.contains("micro_missing.pth")
            && e.contains("missing")
            && e.contains("features.denseblock2.denselayer2.norm1.weight"),
        "{e}"
    );
    let e = err("micro_misshaped.pth");
    assert!(
        e.contains("micro_misshaped.pth") && e.contains("transition1.conv.weight") && e.contains("[3, 3, 1, 1]"),
        "{e}"
    );
    let e = err("micro_extra.pth");
    assert!(e.contains("micro_extra.pth") && e.contains("extra_gate"), "{e}");
    let e = err("not_densenet.pth");
    assert!(
        e.contains("not_densenet.pth") && e.contains("not a DenseNet") && e.contains("features.conv0.weight"),
        "{e}"
    );
    assert_eq!(model::import::torch_name("decoder.up2.conv_a.bias"), "decoder.up2.convA.bias");
    let e = err("no_such_file.pth");
    assert!(e.contains("no_such_file.pth"), "{e}");

    let dir = std::env::temp_dir().join(format!("model-import-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let garbage = dir.join("garbage.pth");
    std::fs::write(&garbage, b"this is not a zip archive").unwrap();
    let e = load_pytorch(&garbage, &device).err().expect("must fail").to_string();
    assert!(e.contains("garbage.pth"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
