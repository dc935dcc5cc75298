//! Bundles from a training run or from a PyTorch DenseDepth `state_dict`.

use std::path::Path;

use anyhow::{Context, Result};
use burn::module::Module;
use formats::dataset::Split;
use formats::training::{Imported, Trained, TrainingRecord};
use model::bundle::{BUNDLE_FORMAT_VERSION, BundleFile, INPUT_ENCODING, write_bundle};
use model::{DenseDepth, DepthScale};
use sensor::Sensor;

use crate::checkpoint::{self, RunState};
use crate::data::DepthDataset;

/// Writes the bundle of a run: its best epoch on the held-out validation samples if it keeps
/// one, else its latest checkpoint.
pub fn export_run(run: &Path, out: &Path, device: &burn::tensor::Device) -> Result<()> {
    let latest =
        checkpoint::latest(run).with_context(|| format!("{}: no checkpoint in this run folder", run.display()))?;
    let state = checkpoint::read_state(&latest)?;
    let weights = checkpoint::best(run).unwrap_or(latest);
    let net = checkpoint::restore_model(&weights, &state.model, device)?;
    export_net(&net, &state, out)
}

/// Writes the bundle of a trained network and its run's state.
/// The bundle records the network's error on the dataset's test split, so that every speed
/// figure taken from it can stand beside an error figure.
pub fn export_net(net: &DenseDepth, state: &RunState, out: &Path) -> Result<()> {
    let mut test = DepthDataset::open(&state.config.data, Some(Split::Test), state.config.input_hw)?;
    test.scale = state.config.scale(test.sensor.max_depth_mm);
    let batcher = crate::data::DepthBatcher { input_hw: state.config.input_hw, mask: test.mask.clone() };
    let device = net.devices().into_iter().next().context("the network has no device")?;
    let (test_l1_mm, _) = crate::fit::validate(net, &test, &batcher, state.config.batch, &device)?;
    let file = BundleFile {
        format_version: BUNDLE_FORMAT_VERSION,
        model: state.model.clone(),
        input_height_px: state.config.input_hw[0],
        input_width_px: state.config.input_hw[1],
        input_encoding: INPUT_ENCODING.into(),
        depth_scale: test.scale,
        sensor: test.sensor.clone(),
        reference_image: None,
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
            test_l1_mm: test_l1_mm.is_finite().then_some(test_l1_mm),
            test_images: test.records.len(),
            selected_epoch: state.selected().map_or(state.epoch, |m| m.epoch),
        })),
    };
    write_bundle(out, net, &file, test.reference_png().as_deref())?;
    Ok(())
}

/// A bundle from a PyTorch DenseDepth `state_dict` and a sensor description.
pub fn import_pth(
    pth: &Path,
    sensor: &Path,
    input_hw: [usize; 2],
    out: &Path,
    device: &burn::tensor::Device,
) -> Result<()> {
    let sensor = Sensor::load_json(sensor)?;
    let imported = model::import::load_pytorch(pth, device)?;
    if imported.encoder_only {
        anyhow::bail!("{}: holds a DenseNet encoder only; a bundle needs a whole DenseDepth", pth.display());
    }
    let net = imported.model;
    let file = BundleFile {
        format_version: BUNDLE_FORMAT_VERSION,
        model: imported.config,
        input_height_px: input_hw[0],
        input_width_px: input_hw[1],
        input_encoding: INPUT_ENCODING.into(),
        depth_scale: DepthScale::paper(sensor.max_depth_mm as f32),
        sensor,
        reference_image: None,
        training: Some(TrainingRecord::Imported(Imported { imported_from: pth.to_path_buf() })),
    };
    write_bundle(out, &net, &file, None)?;
    Ok(())
}
