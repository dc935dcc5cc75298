//! Data parallelism over several devices (`--devices cuda:0,cuda:1`, `wgpu:0,wgpu:1`, or any
//! mix): each step's batch is cut into one contiguous share per device, every share runs forward
//! and backward on its own device at the same time, and the gradients are summed on the first
//! device, where the optimiser steps. Each share's loss is weighted by its fraction of the batch,
//! so the summed gradient is the batch's mean gradient (exactly so but for batch norm, whose
//! training statistics are per share, as in PyTorch's `DataParallel`).
//!
//! The first device's share runs on the calling thread with the model itself, so its batch norm
//! layers update the running statistics just as single-device training does; the other devices
//! get a fresh copy each step (their running statistics are dropped). The other devices have one
//! long-lived worker thread each: GPU runtimes keep per-thread state, which a thread per step
//! would create anew every step. With one device nothing is copied and no thread is started.
//!
//! Why this is not Burn's own data parallelism (`burn::tensor::distributed`: one replica per
//! device, gradients all-reduced during the backward pass): in Burn 0.22.1 the collectives are
//! implemented for CubeCL's CUDA runtime alone (NCCL). The CPU backend this project trains with
//! (Flex) and wgpu have none (`unimplemented!()`, no device transport), so there this module is
//! what Burn lacks; under CUDA, Burn's path is the one to move to once a CUDA machine can test it
//! (`docs/multi-node.md`).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

use anyhow::{Result, anyhow, bail};
use burn::data::dataloader::batcher::Batcher;
use burn::module::Module;
use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::tensor::Device;
use model::{DenseDepth, DepthLossConfig};

use crate::data::{DepthBatcher, DepthItem};

/// One step's loss (the batch mean, as single-device training reports it) and gradients, on the
/// first device.
pub struct StepGrads {
    pub loss: f64,
    pub grads: GradientsParams,
}

/// The devices of a run and the workers that drive all but the first.
pub struct DataParallel {
    workers: Vec<Worker>,
    batcher: DepthBatcher,
    loss: DepthLossConfig,
}

struct Job {
    /// The model's current weights, without autodiff (a cheap copy of handles).
    weights: DenseDepth,
    items: Vec<DepthItem>,
    fraction: f32,
}

struct Worker {
    name: String,
    jobs: Option<Sender<Job>>,
    results: Receiver<std::result::Result<StepGrads, String>>,
    thread: Option<JoinHandle<()>>,
}

impl DataParallel {
    /// `devices` are plain (not autodiff) devices; the first one holds the model and the
    /// optimiser. A device named twice is an error: two shares on one device only compete.
    pub fn new(devices: &[Device], batcher: DepthBatcher, loss: DepthLossConfig) -> Result<Self> {
        if let Some(i) = model::backend::first_repeat(devices) {
            bail!("device {:?} is named twice; name each device once", devices[i]);
        }
        Self::new_allowing_repeats(devices, batcher, loss)
    }

    /// Like [`DataParallel::new`] but lets a device appear more than once: tests run several
    /// shares on the one CPU device to check the splitting and summing.
    #[doc(hidden)]
    pub fn new_allowing_repeats(devices: &[Device], batcher: DepthBatcher, loss: DepthLossConfig) -> Result<Self> {
        let Some(primary) = devices.first().cloned() else { bail!("no training device given") };
        let workers = devices[1..]
            .iter()
            .map(|d| Worker::start(d.clone(), primary.clone(), batcher.clone(), loss.clone()))
            .collect::<Result<Vec<_>>>()?;
        Ok(DataParallel { workers, batcher, loss })
    }

    /// How many devices share each step.
    pub fn device_count(&self) -> usize {
        self.workers.len() + 1
    }

    /// Loss and gradients of `net` (on the first device, autodiff) over `items`.
    pub fn step(&self, net: &DenseDepth, items: Vec<DepthItem>) -> Result<StepGrads> {
        let total = items.len();
        if total == 0 {
            bail!("a training step needs at least one sample");
        }
        let mut items = items.into_iter();
        let mut parts = share_sizes(total, self.device_count()).into_iter().map(|n| items.by_ref().take(n).collect());
        let own: Vec<DepthItem> = parts.next().expect("the first share is never empty");
        if self.workers.is_empty() {
            return Ok(share_grads(net, own, 1.0, &self.batcher, &self.loss, None));
        }
        // Hand the other shares out first so that every device works while this one does.
        let weights = net.valid();
        let mut busy = Vec::new();
        let mut failure = None;
        for (worker, part) in self.workers.iter().zip(parts) {
            let fraction = part.len() as f32 / total as f32;
            let job = Job { weights: weights.clone(), items: part, fraction };
            match worker.jobs.as_ref().expect("running").send(job) {
                Ok(()) => busy.push(worker),
                Err(_) => failure = failure.or(Some(worker.stopped())),
            }
        }
        let fraction = own.len() as f32 / total as f32;
        let mine = share_grads(net, own, fraction, &self.batcher, &self.loss, None);
        let mut sum = GradientsAccumulator::<DenseDepth>::new();
        let mut loss = mine.loss;
        sum.accumulate(net, mine.grads);
        // Every busy worker's answer is taken, failed or not, so that none is left queued for
        // the next step.
        for worker in busy {
            match worker.results.recv() {
                Ok(Ok(theirs)) => {
                    loss += theirs.loss;
                    sum.accumulate(net, theirs.grads);
                }
                Ok(Err(e)) => failure = failure.or(Some(anyhow!("training on {}: {e}", worker.name))),
                Err(_) => failure = failure.or(Some(worker.stopped())),
            }
        }
        match failure {
            Some(e) => Err(e),
            None => Ok(StepGrads { loss, grads: sum.grads() }),
        }
    }
}

/// Batch sizes of the shares: as equal as possible, the larger ones first, none empty (fewer
/// shares than devices when the batch is smaller than the device count).
pub fn share_sizes(total: usize, devices: usize) -> Vec<usize> {
    let devices = devices.max(1).min(total.max(1));
    let (base, extra) = (total / devices, total % devices);
    (0..devices).map(|i| base + usize::from(i < extra)).collect()
}

/// Forward and backward of one share on `net`'s device; gradients moved to `to` when given.
fn share_grads(
    net: &DenseDepth,
    items: Vec<DepthItem>,
    fraction: f32,
    batcher: &DepthBatcher,
    loss: &DepthLossConfig,
    to: Option<&Device>,
) -> StepGrads {
    let device = net.devices()[0].clone();
    let batch = batcher.batch(items, &device);
    let heads = net.forward_heads(batch.images);
    let mut total = loss.forward_heads(heads, batch.depths, batch.masks, batch.pressures, batch.forces).total;
    if fraction != 1.0 {
        total = total.mul_scalar(fraction);
    }
    let value = total.clone().into_scalar::<f32>() as f64;
    let mut grads = GradientsParams::from_grads(total.backward(), net);
    if let Some(to) = to {
        grads = grads.to_device(to, net);
    }
    StepGrads { loss: value, grads }
}

impl Worker {
    fn start(device: Device, primary: Device, batcher: DepthBatcher, loss: DepthLossConfig) -> Result<Worker> {
        let name = format!("{device:?}");
        let (jobs, job_rx) = channel::<Job>();
        let (result_tx, results) = channel();
        let thread = std::thread::Builder::new()
            .name(format!("train {name}"))
            .spawn(move || {
                for job in job_rx {
                    let run = || {
                        let replica = job.weights.fork(&device).train();
                        share_grads(&replica, job.items, job.fraction, &batcher, &loss, Some(&primary))
                    };
                    let out =
                        catch_unwind(AssertUnwindSafe(run)).map_err(|p| model::backend::panic_message(p.as_ref()));
                    if result_tx.send(out).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| anyhow!("cannot start a thread for {name}: {e}"))?;
        Ok(Worker { name, jobs: Some(jobs), results, thread: Some(thread) })
    }

    fn stopped(&self) -> anyhow::Error {
        anyhow!("the worker for {} stopped", self.name)
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Closing the job channel ends the worker's loop.
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
