//! Bundles from a training run or from a PyTorch DenseDepth `state_dict`.

use std::path::Path;

use anyhow::{Context, Result};
use burn::module::Module;
use formats::dataset::Split;
use formats::training::{Imported, TestError, Trained, TrainingRecord};
use model::bundle::{BundleFile, SafetensorsKeys, write_bundle};
use model::{DenseDepth, DepthScale};
use sensor::Sensor;

use crate::checkpoint::{self, RunState};
use crate::data::DepthDataset;

/// Writes the bundle of a run: its best epoch on the held-out validation samples if it keeps
/// one, else its latest checkpoint; its force head's map refitted as `fit` refits it.
/// `keys` names the tensors of `weights.safetensors` (PyTorch's with `--torch-names`).
pub fn export_run(run: &Path, out: &Path, device: &burn::tensor::Device, keys: SafetensorsKeys) -> Result<()> {
    let latest =
        checkpoint::latest(run).with_context(|| format!("{}: no checkpoint in this run folder", run.display()))?;
    // Held while exporting: a run whose training still goes on is refused, not exported at
    // whatever step it last saved.
    let _held = formats::output::claim_dir(run, formats::output::OutputKind::Run, &[])?;
    let state = checkpoint::read_state(&latest)?;
    let weights = checkpoint::best(run).unwrap_or(latest);
    let net = checkpoint::restore_model(&weights, &state.model, device)?;
    // As `fit` returned it: the force head's map refitted the same way on the same data.
    let (net, _) = crate::fit::refit_run_force_head(net, &state, device)?;
    export_net_with(&net, &state, out, &[run], keys)
}

/// Writes the bundle of a trained network and its run's state (never over the dataset, nor
/// over `inputs`, the run's folder say).
/// The bundle records the network's error on the dataset's whole test split with its image
/// count, so that every speed figure taken from it can stand beside an error figure; where the
/// split is empty or an image of it cannot be read (`--on-bad-data skip`), it records why there
/// is no test error instead of a figure over part of it.
pub fn export_net(net: &DenseDepth, state: &RunState, out: &Path, inputs: &[&Path]) -> Result<()> {
    export_net_with(net, state, out, inputs, SafetensorsKeys::Burn)
}

/// [`export_net`] with the key names of `weights.safetensors` chosen; PyTorch's names on a
/// model whose architecture differs from the reference DenseDepth's say what differs.
pub fn export_net_with(
    net: &DenseDepth,
    state: &RunState,
    out: &Path,
    inputs: &[&Path],
    keys: SafetensorsKeys,
) -> Result<()> {
    if keys == SafetensorsKeys::Pytorch {
        warn_differences(&state.model);
    }
    // The test error is the bundle's unit's (`data`); other units' folders are inputs too.
    let folders = state.config.folders();
    let mut all_inputs: Vec<&Path> = folders.iter().map(|p| p.as_path()).collect();
    all_inputs.extend(inputs);
    formats::output::check_dir(out, formats::output::OutputKind::Bundle, &all_inputs)?;
    let mut test = DepthDataset::open(&state.config.data, Some(Split::Test), state.config.input_hw)?;
    test.scale = state.config.scale(test.sensor.max_depth_mm);
    test.set_model(&state.model)?;
    let batcher = crate::data::DepthBatcher::for_data(&test);
    let device = net.devices().into_iter().next().context("the network has no device")?;
    let (test_error, test_missing) = if test.is_empty() {
        (None, Some("the dataset has no test split".to_string()))
    } else {
        let eval =
            crate::fit::validate(net, &test, &batcher, state.config.batch, &device, state.config.on_bad_data, "test")?;
        if let Some(f) = &eval.head_force {
            if let Some(c) = eval.contact_l1_mm {
                println!("test split: contact L1 {c:.4} mm, L1 {:.4} mm (the network's, untared)", eval.l1_mm);
            }
            println!(
                "test split: force head's total force error {:.3} N ({:.2} % of the mean {:.2} N), vector error {:.3} N, \
                 {} images",
                f.total_n,
                f.total_percent(),
                f.mean_n,
                f.vector_n,
                f.images
            );
        }
        if eval.bad.is_empty() {
            (Some(TestError { l1_mm: eval.l1_mm, images: eval.images }), None)
        } else {
            eprintln!(
                "warning: {} of {} test samples could not be read; the bundle records no test error",
                eval.bad.len(),
                test.len()
            );
            (
                None,
                Some(format!(
                    "{} of {} test samples could not be read: {}",
                    eval.bad.len(),
                    test.len(),
                    eval.bad.join("; ")
                )),
            )
        }
    };
    let skip_bad = state.config.on_bad_data == crate::OnBadData::Skip;
    let contact_gate = crate::gate::fit_gate(&state.config.data, skip_bad)?;
    match &contact_gate {
        Some(record) => crate::gate::report_lines(record).iter().for_each(|l| println!("{l}")),
        None => println!("no contact gate: the dataset has no reference frame or no train frame with contact"),
    }
    let elastomer = crate::elastomer::fit_elastomer(&state.config.data, skip_bad)?;
    match &elastomer {
        Some(record) => println!("{}", crate::elastomer::report_line(record)),
        None => println!("no elastomer fitted: the dataset's train split has no force labels with contact"),
    }
    let file = BundleFile {
        safetensors_keys: keys,
        contact_gate,
        elastomer,
        input_encoding: test.encoding().text(),
        training: Some(TrainingRecord::Trained(Trained {
            data: state.config.data.clone(),
            epochs: state.epoch,
            batch: state.config.batch,
            lr: state.config.lr,
            seed: state.config.seed,
            steps: state.global_step,
            skipped_steps: state.skipped_steps,
            bad_samples: state.bad_samples.clone(),
            history: state.history.clone(),
            test: test_error,
            test_missing,
            test_l1_mm: None,
            selected_epoch: state.selected().map_or(state.epoch, |m| m.epoch),
        })),
        ..BundleFile::new(state.model.clone(), state.config.input_hw, test.sensor.clone(), test.scale)
    };
    write_bundle(out, net, &file, test.reference_png().as_deref(), &all_inputs)?;
    Ok(())
}

/// A bundle from a PyTorch DenseDepth `state_dict` (pickled or safetensors) and a sensor
/// description; `keys` names the tensors of its `weights.safetensors`.
pub fn import_pth(
    pth: &Path,
    sensor: &Path,
    input_hw: [usize; 2],
    out: &Path,
    device: &burn::tensor::Device,
    keys: SafetensorsKeys,
) -> Result<()> {
    let sensor_path = sensor;
    let sensor = Sensor::load_json(sensor)?;
    let imported = model::import::load_pytorch(pth, device)?;
    if imported.encoder_only {
        anyhow::bail!("{}: holds a DenseNet encoder only; a bundle needs a whole DenseDepth", pth.display());
    }
    let net = imported.model;
    let scale = DepthScale::paper(sensor.max_depth_mm as f32);
    let file = BundleFile {
        training: Some(TrainingRecord::Imported(Imported { imported_from: pth.to_path_buf() })),
        safetensors_keys: keys,
        ..BundleFile::new(imported.config, input_hw, sensor, scale)
    };
    write_bundle(out, &net, &file, None, &[pth, sensor_path])?;
    Ok(())
}

/// Tells on stderr what a PyTorch user must change in the reference DenseDepth before the
/// exported `state_dict` loads into it (nothing for the reference architecture).
fn warn_differences(model: &model::DenseDepthConfig) {
    for d in model::torch::differences_from_reference(model) {
        eprintln!("note: weights.safetensors has PyTorch's names, but {d}");
    }
}

/// Writes `bundle` as ONNX to `out` (never over one of the bundle's files): the whole predictor
/// (`whole`: crop in, depth in mm out, with the bundle's reference frame, gate and tare) or the
/// network alone; returns its size in bytes.
pub fn export_onnx(bundle: &Path, out: &Path, device: &burn::tensor::Device, whole: bool) -> Result<usize> {
    formats::output::check_file(out, &[bundle])?;
    let (net, file) = model::bundle::load_bundle(bundle, device)?;
    if file.elastomer.is_some() && !file.model.pressure && file.model.force_head.is_none() {
        eprintln!(
            "note: {}: the bundle's force is the contact solved on the predicted depth, which is no ONNX graph; \
             the file carries depth alone (train with --force-weight for the force head and pressure output it can carry)",
            bundle.display()
        );
    }
    let bytes = if whole {
        let reference = model::bundle::load_reference(bundle, &file)?;
        model::onnx::export_whole(&model::onnx::WholePredictor {
            net: &net,
            file: &file,
            reference: reference.as_ref(),
        })
    } else {
        model::onnx::export(&net, &file)
    };
    let bytes = bytes.with_context(|| format!("{}", bundle.display()))?;
    formats::fs::write_atomic(out, &bytes)?;
    Ok(bytes.len())
}
