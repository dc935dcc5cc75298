//! The loss and its gradient against PyTorch's (float64) reference values.

use crate::common;

use burn::tensor::Tensor;
use common::{SafeFile, errors, fixtures, to_vec};
use model::DepthLossConfig;

const CASES: [&str; 5] = ["random", "identical", "constant_both", "constant_vs_random", "extremes"];

#[test]
#[ignore = "needs ../shared"]
fn loss_values_and_gradients_match_pytorch() {
    let dir = fixtures();
    let device = model::backend::default_device().autodiff();
    let file = SafeFile::open(&dir.join("loss_cases.safetensors"));
    let loss = DepthLossConfig::new();
    for case in CASES {
        let pred: Tensor<4> = file.tensor::<4>(&format!("{case}.pred"), &device).require_grad();
        let target = file.tensor::<4>(&format!("{case}.target"), &device);
        let out = loss.forward(pred.clone(), target);
        let got = [out.total.clone(), out.ssim, out.gradient, out.l1].map(|t| to_vec(t)[0]);
        let (want, _) = file.get(&format!("{case}.values"));
        for (k, name) in ["total", "ssim", "gradient", "l1"].iter().enumerate() {
            let tol = 1e-4 * want[k].abs().max(1e-3);
            assert!((got[k] - want[k]).abs() <= tol, "{case} {name}: {} vs {}", got[k], want[k]);
        }
        let grads = out.total.backward();
        let grad = pred.grad(&grads).expect("gradient recorded");
        let (want_grad, _) = file.get(&format!("{case}.dloss_dpred"));
        let got_grad = to_vec(grad);
        let (abs, rel) = errors(&got_grad, &want_grad);
        assert!(got_grad.iter().all(|g| g.is_finite()), "{case}: non-finite gradient");
        assert!(rel <= 1e-3 || abs <= 1e-9, "{case}: gradient max_abs_err={abs} max_rel_err={rel}");
    }
}
