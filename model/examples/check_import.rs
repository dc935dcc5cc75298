//! Checks a PyTorch DenseDepth (or torchvision DenseNet) import against PyTorch's own output.
//!
//! usage: cargo run --release -p model --example check_import -- WEIGHTS.pth IO.safetensors
//!
//! IO.safetensors holds `input` ([N, 3, H, W] in [0, 1]) and `output`: the model's eval-mode
//! result (for a bare DenseNet checkpoint, `norm5`: its `features` output). Prints
//! `max_abs_err=<x> max_rel_err=<y>` last and exits non-zero when max_rel_err > 1e-4
//! (relative to the largest output magnitude).

use std::path::PathBuf;
use std::process::ExitCode;

use model::import::load_pytorch;
use model::tensor_file::{TensorFile, max_errors};

const TOLERANCE: f32 = 1e-4;

fn run(weights: PathBuf, io: PathBuf) -> Result<(f32, f32), String> {
    let device = model::backend::default_device();
    let imported = load_pytorch(&weights, &device).map_err(|e| e.to_string())?;
    println!(
        "loaded {}: DenseNet growth {} blocks {:?} init {} bn_size {}{}",
        weights.display(),
        imported.config.encoder.growth_rate,
        imported.config.encoder.block_config,
        imported.config.encoder.num_init_features,
        imported.config.encoder.bn_size,
        if imported.encoder_only {
            " (encoder only)".to_string()
        } else {
            format!(", decoder width {}", imported.config.decoder_width)
        }
    );
    let file = TensorFile::open(&io).map_err(|e| e.to_string())?;
    let input = file.tensor::<4>("input", &device).map_err(|e| e.to_string())?;
    imported.model.check_input(input.dims()).map_err(|e| format!("{}: `input`: {e}", io.display()))?;
    let (got, want_name) = if imported.encoder_only {
        (imported.model.encoder.forward(input).norm5, "norm5")
    } else {
        (imported.model.forward(input), "output")
    };
    let (want, shape) = file.get(want_name).map_err(|e| e.to_string())?;
    if got.dims().to_vec() != shape {
        return Err(format!("{}: {want_name} has shape {shape:?} but the model gives {:?}", io.display(), got.dims()));
    }
    let got: Vec<f32> = got.into_data().convert::<f32>().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
    Ok(max_errors(&got, &want))
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [weights, io] = args.as_slice() else {
        eprintln!("usage: check_import WEIGHTS.pth IO.safetensors");
        return ExitCode::from(2);
    };
    match run(weights.into(), io.into()) {
        Ok((abs, rel)) => {
            println!("max_abs_err={abs:e} max_rel_err={rel:e}");
            if rel > TOLERANCE { ExitCode::FAILURE } else { ExitCode::SUCCESS }
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
