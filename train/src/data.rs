//! Training data: a generated dataset folder read through Burn's `Dataset` and `Batcher`.
//!
//! Each item is the unit's RGB crop resized to the network's input, and the depth map resized to
//! half of it in network units. Augmentations keep the colour-to-normal geometry: brightness and
//! contrast jitter and noise only, never channel swaps, flips or rotations (the LEDs would not
//! turn with them); a base model may also vary each sample's look as units differ ([`Look`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use burn::data::dataloader::batcher::Batcher;
use burn::data::dataset::Dataset;
use burn::tensor::{Device, Tensor, TensorData};
use formats::SplitMix64;
use formats::dataset::{Manifest, SampleRecord, Split};
use image::RgbImage;
use model::{DenseDepthConfig, DepthScale, InputChannels, InputEncoder, InputEncoding};
use sensor::{DepthMap, PressureMap, Sensor};

/// A bad sample: the file and what is wrong with it.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error(transparent)]
    Frame(#[from] sensor::frame::FrameError),
}

fn bad(path: &Path, message: impl std::fmt::Display) -> DataError {
    DataError::File { path: path.to_path_buf(), message: message.to_string() }
}

/// One training pair, ready to batch.
#[derive(Clone, Debug)]
pub struct DepthItem {
    /// [C, H, W]: the network's input (`model::InputEncoder`).
    pub image: Vec<f32>,
    /// [1, OH, OW] (the network's output size), network units.
    pub depth: Vec<f32>,
    /// [1, OH, OW] contact pressure in network units (`model::PRESSURE_KPA_PER_UNIT`), for a
    /// network with the pressure output and a sample that has a pressure map.
    pub pressure: Option<Vec<f32>>,
    /// The sample's force (N, sensor frame: measured where its capture has a measurement, else
    /// labelled) and its unit's force per pressure unit on each output pixel where its depth
    /// target shows contact (`[3, OH * OW]`, zero elsewhere), for a network with the pressure
    /// output and a sample with a wrench.
    pub force: Option<([f32; 3], Arc<Vec<f32>>)>,
    /// [OH * OW]: 1 where the output pixel lies wholly on the unit's useful pixels, else 0
    /// (units differ, so each item carries its own).
    pub mask: Arc<Vec<f32>>,
}

/// Photometric augmentation for one item, drawn from its own stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Jitter {
    pub gain: f32,
    pub offset: f32,
    pub noise_sd: f32,
    pub seed: u64,
    /// Applied only where the dataset varies the look ([`DepthDataset::vary_look`]).
    pub look: Look,
}

impl Jitter {
    pub fn draw(seed: u64, epoch: u64, index: u64) -> Self {
        let mut rng = SplitMix64::for_item(seed ^ epoch.wrapping_mul(0x9e37_79b9), index);
        let (gain, offset, noise_sd, seed) =
            (rng.range(0.9, 1.1) as f32, rng.range(-0.03, 0.03) as f32, rng.range(0.0, 0.01) as f32, rng.next_u64());
        // Drawn after the rest, so that runs without it see the draws they always saw.
        let mut log_uniform = |ratio: f64| rng.range(-ratio.ln(), ratio.ln()).exp() as f32;
        let gain_rgb = std::array::from_fn(|_| log_uniform(Look::GAIN_RATIO));
        let look = Look { gain_rgb, exponent: log_uniform(Look::EXPONENT_RATIO) };
        Jitter { gain, offset, noise_sd, seed, look }
    }
}

/// The same scene as another unit would show it: a gain per colour channel (LED brightness and
/// colour, exposure) and an exponent on the encoded values (a camera of another gamma), applied
/// to the frame and the unit's reference frame alike. Its spread covers
/// `SensorUnit::from_seed`'s between two units: LED gains 0.85-1.15 times 0.92-1.08 per colour,
/// gamma 1.0-2.2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    pub gain_rgb: [f32; 3],
    pub exponent: f32,
}

impl Look {
    /// Gains are drawn log-uniform in `1/GAIN_RATIO ..= GAIN_RATIO`.
    pub const GAIN_RATIO: f64 = 1.25;
    /// Exponents are drawn log-uniform in `1/EXPONENT_RATIO ..= EXPONENT_RATIO`.
    pub const EXPONENT_RATIO: f64 = 1.5;

    /// Changes channel-major R, G, B planes (values in 0..=1) in place.
    pub fn apply(&self, planes: &mut [f32]) {
        let per = planes.len() / 3;
        for (plane, gain) in planes.chunks_mut(per.max(1)).zip(self.gain_rgb) {
            for v in plane {
                *v = (gain * v.powf(self.exponent)).clamp(0.0, 1.0);
            }
        }
    }
}

/// One sensor unit's dataset folder: its geometry, reference frame and the encoder and output
/// mask that follow from them.
#[derive(Clone)]
struct UnitFolder {
    dir: PathBuf,
    sensor: Sensor,
    reference: Option<PathBuf>,
    /// Crops to the network's input; RGB until [`DepthDataset::set_model`] says otherwise.
    encoder: InputEncoder,
    mask: Arc<Vec<f32>>,
    /// Force per pressure unit on each output pixel (`sensor::DomeAreas::force_per_kpa`);
    /// computed for a network with the pressure output.
    force_per_unit: Option<Arc<Vec<f32>>>,
}

/// What a unit's frames are balanced against when read as `infer` reads them.
struct UnitBalance {
    reference: Option<image::RgbImage>,
    useful: Vec<bool>,
}

/// The samples of one split of one or more dataset folders that have images: one unit's, or
/// several units' at once (a base model for new units). Every sample is read with its own
/// unit's geometry and reference frame.
#[derive(Clone)]
pub struct DepthDataset {
    units: Vec<UnitFolder>,
    /// Which of `units` each of `records` comes from.
    unit_of: Vec<usize>,
    records: Vec<SampleRecord>,
    /// The first folder's sensor (the one a bundle describes).
    pub sensor: Sensor,
    pub input_hw: [usize; 2],
    /// The network's output size (half the input's unless the model says otherwise).
    pub output_hw: [usize; 2],
    pub scale: DepthScale,
    /// Whether a jittered item's look varies too ([`Jitter::look`]): training a base model
    /// for units it has not seen. Default false.
    pub vary_look: bool,
    /// Where frames are read as `infer` reads them ([`read_as_infer`](Self::read_as_infer)):
    /// per unit, its reference frame and useful pixels, read once, against which each frame's
    /// global drift is taken out at the crop's size (`sensor::gate::Balance`, where it is not
    /// none), before resizing and any jitter. `None`: frames as stored, as training reads them;
    /// the force head's refit reads them this way, since its map is fitted to the features
    /// inference computes.
    balance: Option<Arc<Vec<UnitBalance>>>,
    /// Whether items carry their pressure maps (a network with the pressure output).
    pressure: bool,
    /// Samples decoded in an earlier epoch ([`DepthDataset::keep_decoded`]); shared by clones
    /// (the loader's threads), emptied when the samples or the model change.
    decoded: Arc<Mutex<DecodedCache>>,
}

/// What a sample's decoding gives before any augmentation: the crop resized to the network's
/// input (8-bit RGB, as the encoding resizes it) and the depth at the output size in network
/// units. Encoding and jitter run on it every epoch; decoding, checking and resizing once.
struct Decoded {
    image: RgbImage,
    depth: Vec<f32>,
    pressure: Option<Vec<f32>>,
}

impl Decoded {
    fn bytes(&self) -> usize {
        let planes = self.depth.len() + self.pressure.as_ref().map_or(0, Vec::len);
        self.image.as_raw().len() + planes * std::mem::size_of::<f32>()
    }
}

/// Decoded samples by index, up to a byte budget (0: none kept). Samples past the budget are
/// decoded every epoch, as without it; a sample that failed is never kept, so it fails again.
#[derive(Default)]
struct DecodedCache {
    budget_bytes: usize,
    used_bytes: usize,
    samples: HashMap<usize, Arc<Decoded>>,
}

impl DepthDataset {
    pub fn open(dir: &Path, split: Option<Split>, input_hw: [usize; 2]) -> anyhow::Result<Self> {
        Self::open_all(std::slice::from_ref(&dir.to_path_buf()), split, input_hw)
    }

    /// The samples of `split` of every folder in `dirs` (at least one); the first folder's
    /// sensor is the dataset's. Folders whose sensors differ in radius or depth range are
    /// refused: one network's depth units cannot serve both.
    pub fn open_all(dirs: &[PathBuf], split: Option<Split>, input_hw: [usize; 2]) -> anyhow::Result<Self> {
        anyhow::ensure!(!dirs.is_empty(), "no dataset folder given");
        let output_hw = [input_hw[0].div_ceil(2), input_hw[1].div_ceil(2)];
        let (mut units, mut unit_of, mut records) = (Vec::new(), Vec::new(), Vec::new());
        for dir in dirs {
            let manifest = Manifest::load(dir)?;
            let chosen: Vec<SampleRecord> =
                manifest.samples.into_iter().filter(|s| split.is_none_or(|want| s.split == want)).collect();
            if let Some(s) = chosen.iter().find(|s| s.image.is_none()) {
                anyhow::bail!(
                    "{}: sample {} has no camera image; generate the dataset with --unit SEED",
                    dir.join("manifest.json").display(),
                    s.id
                );
            }
            let sensor = manifest.sensor;
            if let Some(first) = units.first().map(|u: &UnitFolder| &u.sensor)
                && (first.radius_mm != sensor.radius_mm || first.max_depth_mm != sensor.max_depth_mm)
            {
                anyhow::bail!(
                    "{}: its sensor ({} mm radius, {} mm deep) differs from {}'s ({} mm, {} mm); one network needs one",
                    dir.join("manifest.json").display(),
                    sensor.radius_mm,
                    sensor.max_depth_mm,
                    dirs[0].display(),
                    first.radius_mm,
                    first.max_depth_mm
                );
            }
            unit_of.extend(std::iter::repeat_n(units.len(), chosen.len()));
            records.extend(chosen);
            units.push(UnitFolder {
                dir: dir.clone(),
                mask: Arc::new(output_mask(&sensor, output_hw)),
                reference: Some(dir.join("unit/reference.png")).filter(|p| p.is_file()),
                encoder: InputEncoder::new(InputEncoding::new(InputChannels::Rgb), input_hw, None)?,
                force_per_unit: None,
                sensor,
            });
        }
        let sensor = units[0].sensor.clone();
        Ok(DepthDataset {
            scale: DepthScale::paper(sensor.max_depth_mm as f32),
            sensor,
            units,
            unit_of,
            records,
            input_hw,
            output_hw,
            vary_look: false,
            balance: None,
            pressure: false,
            decoded: Arc::default(),
        })
    }

    /// Items for `model`: its input channels and output size. The reference difference reads
    /// each folder's `unit/reference.png`, which must then be there, at the gain fitted to how
    /// much contact changes that folder's train frames ([`InputEncoding::fitted`]): each unit's
    /// own, whichever split this is.
    ///
    /// A network with the pressure output reads each sample's pressure map; a split none of
    /// whose samples has one is refused (regenerate or relabel with force labels).
    pub fn set_model(&mut self, model: &DenseDepthConfig) -> anyhow::Result<()> {
        self.output_hw = model.output_hw(self.input_hw);
        self.pressure = model.pressure;
        if model.pressure && !self.records.is_empty() && self.records.iter().all(|r| r.pressure.is_none()) {
            anyhow::bail!(
                "{}: no sample has a pressure map, which the network's force output trains on; generate or \
                 label the dataset with force labels (the default), or train without --force-weight",
                self.dir().join("manifest.json").display()
            );
        }
        for unit in &mut self.units {
            let reference = match (&unit.reference, model.input.needs_reference()) {
                (Some(path), true) => Some(sensor::frame::read_reference(path, unit.sensor.crop_size_px)?),
                (None, true) => anyhow::bail!(
                    "{}: missing; the network's input ({}) needs the unit's reference frame",
                    unit.dir.join("unit/reference.png").display(),
                    model.input.name()
                ),
                (_, false) => None,
            };
            let encoding = match &reference {
                Some(r) => InputEncoding::fitted(
                    model.input,
                    crate::contrast::contact_change(&unit.dir, &unit.sensor, self.input_hw, r)?,
                ),
                None => InputEncoding::new(model.input),
            };
            unit.encoder = InputEncoder::new(encoding, self.input_hw, reference.as_ref())?;
            unit.mask = Arc::new(output_mask(&unit.sensor, self.output_hw));
            unit.force_per_unit = model.pressure.then(|| {
                let per_kpa = sensor::DomeAreas::new(&unit.sensor).force_per_kpa(self.output_hw);
                Arc::new(per_kpa.into_iter().map(|v| v * model::PRESSURE_KPA_PER_UNIT).collect())
            });
        }
        self.forget_decoded();
        Ok(())
    }

    /// Keeps decoded samples between epochs, up to `budget_bytes` (115 kB a sample at the
    /// quickstart's 128x128, 1.2 MB at the paper's 480x640). Items are the same with or
    /// without it; it spares each epoch the decoding, checking and resizing of every frame and
    /// depth map, which on 2 cores the loader's threads take from the training step.
    pub fn keep_decoded(&mut self, budget_bytes: usize) {
        self.decoded = Arc::new(Mutex::new(DecodedCache { budget_bytes, ..DecodedCache::default() }));
    }

    /// Empties the kept samples (their indices or sizes no longer hold), keeping the budget.
    fn forget_decoded(&mut self) {
        let budget = self.decoded.lock().map_or(0, |c| c.budget_bytes);
        self.keep_decoded(budget);
    }

    /// The bytes of decoded samples kept.
    pub fn decoded_bytes(&self) -> usize {
        self.decoded.lock().map_or(0, |c| c.used_bytes)
    }

    /// The first folder.
    pub fn dir(&self) -> &Path {
        &self.units[0].dir
    }

    /// How the first folder's unit's crops are encoded (the bundle's `input_encoding`).
    pub fn encoding(&self) -> InputEncoding {
        self.units[0].encoder.encoding()
    }

    /// The first folder's unit's no-contact image, if it has one.
    pub fn reference_png(&self) -> Option<Vec<u8>> {
        self.units[0].reference.as_ref().and_then(|p| std::fs::read(p).ok())
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// Sample `i`'s record.
    pub fn record(&self, i: usize) -> &SampleRecord {
        &self.records[i]
    }

    /// Keeps samples `ids` (indices into the current samples, in that order), drops the rest.
    pub fn keep(&mut self, ids: &[usize]) {
        self.records = ids.iter().map(|&i| self.records[i].clone()).collect();
        self.unit_of = ids.iter().map(|&i| self.unit_of[i]).collect();
        self.forget_decoded();
    }

    /// The first folder's output mask (every item carries its own unit's).
    pub fn mask(&self) -> &[f32] {
        &self.units[0].mask
    }

    /// Loads item `i`, with `jitter` applied to the image when given.
    pub fn load(&self, i: usize, jitter: Option<Jitter>) -> Result<DepthItem, DataError> {
        let record = &self.records[i];
        let unit = &self.units[self.unit_of[i]];
        let crop = unit.sensor.crop_size_px;
        let kept = self.decoded.lock().ok().and_then(|c| c.samples.get(&i).cloned());
        let decoded = match kept {
            Some(d) => d,
            None => {
                let d = Arc::new(self.decode(i)?);
                if let Ok(mut cache) = self.decoded.lock()
                    && cache.used_bytes + d.bytes() <= cache.budget_bytes
                    && !cache.samples.contains_key(&i)
                {
                    cache.used_bytes += d.bytes();
                    cache.samples.insert(i, d.clone());
                }
                d
            }
        };
        let img = &decoded.image;
        // A sample rendered under its own look carries its own untouched frame.
        let own_encoder;
        let encoder = match &record.reference {
            Some(rel) if unit.encoder.channels().needs_reference() => {
                let path = unit.dir.join(rel);
                let reference = sensor::frame::read_reference(&path, crop)?;
                own_encoder = InputEncoder::new(unit.encoder.encoding(), self.input_hw, Some(&reference))
                    .map_err(|e| bad(&path, e))?;
                &own_encoder
            }
            _ => &unit.encoder,
        };
        let look = jitter.filter(|_| self.vary_look).map(|j| move |planes: &mut [f32]| j.look.apply(planes));
        let look = look.as_ref().map(|f| f as &dyn Fn(&mut [f32]));
        let image = encoder.encode_looking(img, look, |planes| {
            if let Some(j) = jitter {
                let mut rng = SplitMix64::new(j.seed);
                for v in planes {
                    let noise = if j.noise_sd > 0.0 { rng.normal() as f32 * j.noise_sd } else { 0.0 };
                    *v = (*v * j.gain + j.offset + noise).clamp(0.0, 1.0);
                }
            }
        });
        Ok(DepthItem {
            image,
            depth: decoded.depth.clone(),
            pressure: decoded.pressure.clone(),
            force: unit.force_per_unit.as_ref().and_then(|w| {
                let f = record.force_label()?.force_n;
                // Only where the depth target shows contact: inference counts pressure there alone.
                let contact = self.scale.to_net(sensor::CONTACT_THRESHOLD_MM);
                let px = decoded.depth.len();
                let masked =
                    w.iter().enumerate().map(|(k, &v)| if decoded.depth[k % px] > contact { v } else { 0.0 }).collect();
                Some(([f[0] as f32, f[1] as f32, f[2] as f32], Arc::new(masked)))
            }),
            mask: unit.mask.clone(),
        })
    }

    /// This dataset reading frames as `infer` reads them ([`DepthDataset::balance`]), with a
    /// cache of its own (the same budget) since its decoded frames differ. Fails where a
    /// unit's reference frame cannot be read.
    pub fn read_as_infer(&self) -> Result<DepthDataset, DataError> {
        let units = self.units.iter().map(|unit| {
            let reference = unit.reference.as_ref().map(|p| sensor::frame::read_reference(p, unit.sensor.crop_size_px));
            Ok(UnitBalance { reference: reference.transpose()?, useful: unit.sensor.valid_mask() })
        });
        let mut data = self.clone();
        data.balance = Some(Arc::new(units.collect::<Result<_, DataError>>()?));
        data.forget_decoded();
        Ok(data)
    }

    /// Sample `i`'s crop-size frame `img` with its global drift against its reference (its own,
    /// else its unit's) undone, as `infer::Predictor::input` undoes it before resizing;
    /// unchanged where there is no reference or no drift to undo.
    fn balanced(&self, img: image::RgbImage, i: usize, base: &UnitBalance) -> Result<image::RgbImage, DataError> {
        let unit = &self.units[self.unit_of[i]];
        let own = match &self.records[i].reference {
            Some(rel) => Some(sensor::frame::read_reference(&unit.dir.join(rel), unit.sensor.crop_size_px)?),
            None => None,
        };
        let Some(reference) = own.as_ref().or(base.reference.as_ref()) else { return Ok(img) };
        let balance = sensor::gate::Balance::fit(&img, reference, &base.useful);
        Ok(if balance.is_none() { img } else { balance.undo(&img, reference) })
    }

    /// Sample `i`'s camera image file.
    fn image_path(&self, i: usize) -> PathBuf {
        self.units[self.unit_of[i]].dir.join(self.records[i].image.as_ref().expect("checked at open"))
    }

    /// Sample `i`'s camera image (the crop, RGB) as its file has it.
    pub fn camera_image(&self, i: usize) -> Result<image::RgbImage, DataError> {
        Ok(sensor::frame::read(&self.image_path(i))?)
    }

    /// Sample `i` read, checked and resized: the part of [`load`](Self::load) that is the same
    /// every epoch.
    fn decode(&self, i: usize) -> Result<Decoded, DataError> {
        let record = &self.records[i];
        let unit = &self.units[self.unit_of[i]];
        let crop = unit.sensor.crop_size_px;
        let image_path = self.image_path(i);
        let img = sensor::frame::read(&image_path)?;
        if img.width() != crop || img.height() != crop {
            return Err(bad(
                &image_path,
                format!("image is {}x{}, the sensor's crop is {crop}x{crop}", img.width(), img.height()),
            ));
        }
        let img = match &self.balance {
            Some(units) => self.balanced(img, i, &units[self.unit_of[i]])?,
            None => img,
        };
        let depth_path = unit.dir.join(&record.depth);
        let depth = DepthMap::load_png_um(&depth_path).map_err(|e| bad(&depth_path, e))?;
        if depth.size_px != crop {
            return Err(bad(&depth_path, format!("depth map is {0}x{0}, the crop is {crop}x{crop}", depth.size_px)));
        }
        let limit = unit.sensor.max_depth_mm as f32 + 1e-3;
        if let Some(d) = depth.depth_mm.iter().find(|&&d| !(0.0..=limit).contains(&d)) {
            return Err(bad(&depth_path, format!("depth {d} mm is outside 0..{} mm", unit.sensor.max_depth_mm)));
        }
        let small = resize_plane(&depth.depth_mm, crop as usize, self.output_hw);
        let pressure = match &record.pressure {
            Some(rel) if self.pressure => {
                let path = unit.dir.join(rel);
                let map = PressureMap::load_png(&path).map_err(|e| bad(&path, e))?;
                if map.size_px != crop {
                    return Err(bad(&path, format!("pressure map is {0}x{0}, the crop is {crop}x{crop}", map.size_px)));
                }
                let small = resize_plane(&map.pressure_kpa, crop as usize, self.output_hw);
                Some(small.iter().map(|&p| p / model::PRESSURE_KPA_PER_UNIT).collect())
            }
            _ => None,
        };
        Ok(Decoded {
            image: model::input::resized(&img, self.input_hw),
            depth: small.iter().map(|&d| self.scale.to_net(d)).collect(),
            pressure,
        })
    }
}

impl Dataset<DepthItem, DataError> for DepthDataset {
    /// Burn's view of the dataset: items without augmentation.
    fn get(&self, index: usize) -> Result<DepthItem, DataError> {
        self.load(index, None)
    }

    fn len(&self) -> usize {
        self.records.len()
    }
}

/// A square plane resized to `[h, w]` (triangle filter, values kept as they are).
fn resize_plane(values: &[f32], side: usize, hw: [usize; 2]) -> Vec<f32> {
    sensor::resample::resize_plane(values, [side, side], hw)
}

/// Output pixels that lie wholly on useful crop pixels.
fn output_mask(sensor: &Sensor, output_hw: [usize; 2]) -> Vec<f32> {
    sensor::resample::covered_mask(&sensor.valid_mask(), sensor.crop_size_px as usize, output_hw)
        .into_iter()
        .map(|m| if m { 1.0 } else { 0.0 })
        .collect()
}

/// A batch on a device.
#[derive(Clone, Debug)]
pub struct DepthBatch {
    pub images: Tensor<4>,
    pub depths: Tensor<4>,
    pub masks: Tensor<4>,
    /// Pressure targets and the mask of the pixels that have one (an item without a pressure
    /// map counts nowhere), where any item has one.
    pub pressures: Option<(Tensor<4>, Tensor<4>)>,
    /// Force targets where any item has one (an item without counts nowhere).
    pub forces: Option<model::ForceTargets>,
}

/// Stacks items into tensors.
#[derive(Clone, Debug)]
pub struct DepthBatcher {
    pub input_hw: [usize; 2],
    pub output_hw: [usize; 2],
}

impl DepthBatcher {
    /// Batches of `data`'s items.
    pub fn for_data(data: &DepthDataset) -> Self {
        DepthBatcher { input_hw: data.input_hw, output_hw: data.output_hw }
    }
}

impl Batcher<DepthItem, DepthBatch> for DepthBatcher {
    fn batch(&self, items: Vec<DepthItem>, device: &Device) -> DepthBatch {
        let n = items.len();
        let [h, w] = self.input_hw;
        let [oh, ow] = self.output_hw;
        let channels = items.first().map_or(3, |i| i.image.len() / (h * w));
        assert!(items.iter().all(|i| i.image.len() == channels * h * w), "items of one batch differ in size");
        let images: Vec<f32> = items.iter().flat_map(|i| i.image.iter().copied()).collect();
        let depths: Vec<f32> = items.iter().flat_map(|i| i.depth.iter().copied()).collect();
        assert!(items.iter().all(|i| i.mask.len() == oh * ow), "an item's mask is not the output's size");
        let masks: Vec<f32> = items.iter().flat_map(|i| i.mask.iter().copied()).collect();
        let pressures = items.iter().any(|i| i.pressure.is_some()).then(|| {
            let (mut targets, mut kept) = (Vec::with_capacity(n * oh * ow), Vec::with_capacity(n * oh * ow));
            for item in &items {
                match &item.pressure {
                    Some(p) => {
                        assert_eq!(p.len(), oh * ow, "an item's pressure map is not the output's size");
                        targets.extend_from_slice(p);
                        kept.extend(item.mask.iter().copied());
                    }
                    None => {
                        targets.extend(std::iter::repeat_n(0.0, oh * ow));
                        kept.extend(std::iter::repeat_n(0.0, oh * ow));
                    }
                }
            }
            let tensor = |v: Vec<f32>| Tensor::from_data(TensorData::new(v, [n, 1, oh, ow]), device);
            (tensor(targets), tensor(kept))
        });
        let forces = items.iter().any(|i| i.force.is_some()).then(|| {
            let (mut per_unit, mut force_n, mut has) = (Vec::new(), Vec::new(), Vec::new());
            for item in &items {
                match &item.force {
                    Some((f, w)) => {
                        assert_eq!(w.len(), 3 * oh * ow, "an item's force weights are not the output's size");
                        per_unit.extend_from_slice(w);
                        force_n.extend_from_slice(f);
                        has.push(1.0);
                    }
                    None => {
                        per_unit.extend(std::iter::repeat_n(0.0, 3 * oh * ow));
                        force_n.extend([0.0; 3]);
                        has.push(0.0);
                    }
                }
            }
            model::ForceTargets {
                per_unit: Tensor::from_data(TensorData::new(per_unit, [n, 3, oh * ow]), device),
                force_n: Tensor::from_data(TensorData::new(force_n, [n, 3]), device),
                has: Tensor::from_data(TensorData::new(has, [n, 1]), device),
            }
        });
        DepthBatch {
            pressures,
            forces,
            images: Tensor::from_data(TensorData::new(images, [n, channels, h, w]), device),
            depths: Tensor::from_data(TensorData::new(depths, [n, 1, oh, ow]), device),
            masks: Tensor::from_data(TensorData::new(masks, [n, 1, oh, ow]), device),
        }
    }
}
