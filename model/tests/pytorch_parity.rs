//! The imported PyTorch DenseDepth gives PyTorch's eval-mode output.

use crate::common;

use common::{SafeFile, errors, fixtures, to_vec};
use model::import::load_pytorch;
use model::{DenseNetConfig, Upsample};

#[test]
#[ignore = "needs ../shared"]
fn tiny_densedepth_matches_pytorch_in_eval_mode() {
    let dir = fixtures();
    let device = model::backend::default_device();
    let imported = load_pytorch(&dir.join("densedepth_tiny.pth"), &device).unwrap();
    assert_eq!(imported.config.encoder, DenseNetConfig::tiny());
    assert_eq!(imported.config.decoder_width, 0.5);
    assert!(!imported.encoder_only);
    let io = SafeFile::open(&dir.join("densedepth_tiny_io.safetensors"));
    let input = io.tensor::<4>("input", &device);
    let (want, shape) = io.get("output");
    for mode in [Upsample::Native, Upsample::Matmul] {
        let out = imported.model.forward_with(input.clone(), mode).depth;
        assert_eq!(out.dims().to_vec(), shape);
        let (abs, rel) = errors(&to_vec(out), &want);
        assert!(rel <= 1e-4, "{mode:?}: max_abs_err={abs} max_rel_err={rel}");
    }
    // Folding BatchNorms into convolutions keeps the eval-mode result.
    let folded = imported.model.folded();
    assert!(folded.encoder.norm0.is_none() && folded.encoder.denseblock2.layers[1].norm2.is_none());
    let (abs, rel) = errors(&to_vec(folded.forward(input)), &want);
    assert!(rel <= 1e-4, "folded: max_abs_err={abs} max_rel_err={rel}");
}
