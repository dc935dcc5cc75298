//! `train fit --view` and `train finetune --view` (feature `view`): each step's loss and
//! learning rate, each epoch's validation figures, and the network's reading of a few held-out
//! samples (their camera image, the true depth, the prediction and its error, in mm at the
//! network's output size) in a Rerun viewer or a `.rrd` recording, on the timelines `step`
//! (global step) and `epoch`.

use anyhow::Result;
use burn::tensor::Device;
use formats::training::EpochMetrics;
use model::DenseDepth;

use crate::data::{DepthBatcher, DepthDataset};

/// Held-out samples shown each epoch: the validation split's first, the same every epoch.
#[cfg(feature = "view")]
const HELD_OUT_SHOWN: usize = 3;

/// The largest error the error images' colours span (mm): about a tenth of a 25 mm dome's
/// deepest press; a trained model's errors sit well inside it.
#[cfg(feature = "view")]
const ERROR_SPAN_MM: f32 = 1.0;

/// A run's view.
#[cfg(feature = "view")]
pub struct RunView {
    view: view::View,
}

/// Without the feature there is no view: `ViewArgs::target` refuses to give one.
#[cfg(not(feature = "view"))]
pub enum RunView {}

#[cfg(feature = "view")]
impl RunView {
    /// Opens the view on `target`, laid out for the losses and `val`'s samples shown.
    pub fn open(target: &view::Target, val: &DepthDataset) -> Result<Self> {
        let view = view::View::open("densetact_training", target)?;
        view.lay_out(&view::training_columns(val.len().min(HELD_OUT_SHOWN)))?;
        Ok(RunView { view })
    }

    /// A step's loss (the mean over its batch) and learning rate.
    pub fn step(&self, step: u64, loss: f64, learning_rate: f64) -> Result<()> {
        use view::entity;
        self.view.at(view::timeline::STEP, step as i64);
        self.view.scalar(entity::TRAIN_LOSS, loss)?;
        Ok(self.view.scalar(entity::LEARNING_RATE, learning_rate)?)
    }

    /// An epoch's figures, and the network's reading of the held-out samples shown.
    pub fn epoch(
        &self,
        metrics: &EpochMetrics,
        step: u64,
        net: &DenseDepth,
        val: &DepthDataset,
        batcher: &DepthBatcher,
        device: &Device,
    ) -> Result<()> {
        use burn::data::dataloader::batcher::Batcher;
        use view::entity;
        let v = &self.view;
        v.at(view::timeline::EPOCH, metrics.epoch as i64);
        v.at(view::timeline::STEP, step as i64);
        v.scalar(entity::EPOCH_LOSS, metrics.train_loss)?;
        v.scalar(entity::VAL_L1_MM, metrics.val_l1_mm)?;
        v.scalar(entity::VAL_LOSS, metrics.val_loss)?;
        if let Some(p) = metrics.val_pressure_l1_kpa {
            v.scalar(entity::VAL_PRESSURE_L1_KPA, p)?;
        }
        // A sample that cannot be read is left out of the view; validation has said so already.
        let shown: Vec<usize> = (0..val.len().min(HELD_OUT_SHOWN)).collect();
        let loaded: Vec<_> = shown.iter().filter_map(|&i| Some((i, val.load(i, None).ok()?))).collect();
        if loaded.is_empty() {
            return Ok(());
        }
        let masks: Vec<_> = loaded.iter().map(|(_, item)| item.mask.clone()).collect();
        let batch = batcher.batch(loaded.iter().map(|(_, item)| item.clone()).collect(), device);
        let pred = val.scale.tensor_to_mm(net.forward_heads(batch.images).depth);
        let truth = val.scale.tensor_to_mm(batch.depths);
        let [_, _, h, w] = pred.dims();
        let pred = pred.into_data().try_to_vec::<f32>()?;
        let truth = truth.into_data().try_to_vec::<f32>()?;
        let size = [w as u32, h as u32];
        let max_mm = val.scale.max_depth_mm;
        for (k, ((i, _), mask)) in loaded.iter().zip(&masks).enumerate() {
            let (p, t) = (&pred[k * h * w..(k + 1) * h * w], &truth[k * h * w..(k + 1) * h * w]);
            // Outside the useful disk neither is meaningful: zero, as inference shows it.
            let keep = |d: &[f32]| -> Vec<f32> { d.iter().zip(mask.iter()).map(|(&v, &m)| v * m).collect() };
            let error: Vec<f32> = p.iter().zip(t).zip(mask.iter()).map(|((a, b), &m)| (a - b).abs() * m).collect();
            if let Ok(image) = val.camera_image(*i) {
                v.rgb(&entity::held_out(k, "input"), &image)?;
            }
            v.depth(&entity::held_out(k, "truth"), size, &keep(t), max_mm)?;
            v.depth(&entity::held_out(k, "prediction"), size, &keep(p), max_mm)?;
            v.depth(&entity::held_out(k, "error"), size, &error, ERROR_SPAN_MM)?;
        }
        Ok(())
    }

    /// Sends what is pending; a recording gets its name.
    pub fn finish(self) -> Result<Option<std::path::PathBuf>> {
        Ok(self.view.finish()?)
    }
}

#[cfg(not(feature = "view"))]
impl RunView {
    pub fn open(target: &view::Target, _: &DepthDataset) -> Result<Self> {
        anyhow::bail!("{target:?}: this build has no live view; build it with `--features view`")
    }

    pub fn step(&self, _: u64, _: f64, _: f64) -> Result<()> {
        match *self {}
    }

    pub fn epoch(
        &self,
        _: &EpochMetrics,
        _: u64,
        _: &DenseDepth,
        _: &DepthDataset,
        _: &DepthBatcher,
        _: &Device,
    ) -> Result<()> {
        match *self {}
    }

    pub fn finish(self) -> Result<Option<std::path::PathBuf>> {
        match self {}
    }
}
