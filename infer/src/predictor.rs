//! Frames to depth maps with a bundle's network.

use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use image::RgbImage;
use model::DenseDepth;
use model::InputEncoder;
use model::bundle::{BundleFile, load_bundle};
use sensor::{DepthMap, DomeAreas, PressureMap, Wrench};

#[derive(Debug, thiserror::Error)]
pub enum InferError {
    #[error(transparent)]
    Bundle(#[from] model::bundle::BundleError),
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("frame is {width}x{height} px; this bundle's sensor crop is {crop}x{crop}")]
    FrameSize { width: u32, height: u32, crop: u32 },
    #[error(transparent)]
    Frame(#[from] sensor::frame::FrameError),
    #[error("the elastomer's effective modulus must be a positive number of MPa, got {0}")]
    Modulus(f64),
}

/// When a frame counts as untouched: fewer than `min_pixels` useful pixels differ from the
/// reference image by more than `grey_levels` (mean over the channels).
pub use sensor::gate::ContactGate;

/// A frame's contact force: the pressure solved on the predicted depth or the network's pressure
/// output, and their resultant, or, from a network with the force head, the head's force with
/// that pressure scaled to it.
#[derive(Clone, Debug)]
pub struct Force {
    /// Contact pressure (kPa) on the crop's grid: zero outside the useful disk and wherever
    /// the predicted depth is below `sensor::CONTACT_THRESHOLD_MM` (no contact, no pressure).
    pub pressure: PressureMap,
    /// The pressure's resultant on the sensor (sensor frame).
    pub wrench: Wrench,
}

impl Force {
    /// No pressure on a crop of `size_px`, and no wrench.
    fn zero(size_px: u32) -> Force {
        let pixels = size_px as usize * size_px as usize;
        Force { pressure: PressureMap { size_px, pressure_kpa: vec![0.0; pixels] }, wrench: Wrench::default() }
    }

    /// This pressure map scaled so that its resultant's size is that of `force_n` (N, sensor
    /// frame), which becomes the wrench's force: the map's shape, another estimate's total. The
    /// torque scales with the map. A map without pressure stays zero.
    pub fn scaled_to(mut self, force_n: [f64; 3]) -> Force {
        let size = Wrench { force_n, ..Wrench::default() }.force_magnitude_n();
        let scale = size / self.wrench.force_magnitude_n().max(f64::from(f32::MIN_POSITIVE));
        self.pressure.pressure_kpa.iter_mut().for_each(|p| *p = (*p as f64 * scale) as f32);
        self.wrench.torque_nmm = self.wrench.torque_nmm.map(|t| t * scale);
        self.wrench.force_n = force_n;
        self
    }
}

/// The unit's contact model: the dome as the crop sees it and the elastomer fitted to its labels.
struct ForceSolver {
    dome: mechanics::Dome,
    material: mechanics::Material,
}

impl ForceSolver {
    /// `rays`: the crop's useful pixels' rays, which the predictor already holds.
    fn new(sensor: &sensor::Sensor, rays: &[sensor::PixelRay], elastomer: &model::bundle::ElastomerRecord) -> Self {
        ForceSolver {
            dome: mechanics::Dome::of_rays(sensor, rays.iter().map(|r| (r.index, r.dir))),
            material: mechanics::Material::with_effective_modulus(elastomer.effective_modulus_mpa),
        }
    }

    /// The contact that `depth` shows (its pixels above the contact threshold) solved: the
    /// pressure on the crop and its resultant. A contact the solver cannot settle (a depth map
    /// no indenter could press) gives no force (`None`, with a warning) rather than a wrong one.
    fn force(&self, depth: &DepthMap) -> Option<Force> {
        let mut pressed = depth.clone();
        for d in &mut pressed.depth_mm {
            // NaN too: `<=` would keep it.
            if d.is_nan() || *d <= sensor::CONTACT_THRESHOLD_MM {
                *d = 0.0;
            }
        }
        let grid = mechanics::GridConfig::default();
        match mechanics::force_label(&self.dome, &pressed, &self.material, &grid) {
            Ok(label) => Some(Force {
                pressure: PressureMap { size_px: depth.size_px, pressure_kpa: label.pressure_kpa },
                wrench: label.wrench,
            }),
            Err(e) => {
                eprintln!("warning: the predicted contact could not be solved for force ({e}); reporting none");
                None
            }
        }
    }
}

/// One line for people: the force, its components and the peak pressure.
pub fn force_line(force: &Force) -> String {
    let [fx, fy, fz] = force.wrench.force_n;
    let peak = force.pressure.pressure_kpa.iter().fold(0f32, |m, &p| m.max(p));
    format!(
        "force {:.3} N (fx {fx:.3}, fy {fy:.3}, fz {fz:.3} N, sensor frame), peak pressure {peak:.1} kPa",
        force.wrench.force_magnitude_n()
    )
}

/// Everything the network gives for one frame.
#[derive(Clone, Debug)]
pub struct Prediction {
    pub depth: DepthMap,
    /// Where the bundle has the pressure output.
    pub force: Option<Force>,
    /// Whether the network ran (false: the contact gate found no contact, and the maps are zero).
    pub network_ran: bool,
}

/// A loaded bundle, ready to turn frames into depth maps.
#[derive(Clone)]
pub struct Predictor {
    /// The bundle's folder.
    pub dir: PathBuf,
    net: DenseDepth,
    pub file: BundleFile,
    device: Device,
    /// The unit's no-contact image, if the bundle has one.
    pub reference: Option<RgbImage>,
    /// Useful pixels of the crop (row-major).
    pub mask: Vec<bool>,
    /// The useful pixels' rays, for point clouds.
    pub rays: Vec<sensor::PixelRay>,
    /// The bundle's contact gate (fitted to its unit's frames); `None`: the network runs on
    /// every frame.
    pub gate: Option<ContactGate>,
    /// Frames to the network's input (with the reference difference if the model reads it).
    encoder: InputEncoder,
    /// Replaces the output pixels the masked loss never trained (not wholly on useful pixels)
    /// by extrapolation from the trained ones, before upsampling.
    border_fill: sensor::resample::FillPlan,
    /// The network's own depth on the reference frame (output grid, mm), subtracted from every
    /// prediction, as a scale is tared: what the network reads into an untouched membrane is
    /// its bias, not contact. `None` without a reference image or after [`Predictor::set_tare`]`(None)`.
    tare_mm: Option<Vec<f32>>,
    /// The same for the pressure output (kPa, output grid).
    tare_kpa: Option<Vec<f32>>,
    /// The same for the force head (N).
    tare_force_n: Option<[f32; 3]>,
    /// The dome area each crop pixel sees, for the pressure's resultant (a bundle with the
    /// pressure output).
    areas: Option<std::sync::Arc<DomeAreas>>,
    /// The contact model with the unit's fitted elastomer (a bundle that records one): each
    /// predicted depth map's contact solved for pressure and wrench.
    solver: Option<std::sync::Arc<ForceSolver>>,
    /// Force from the contact solved on the predicted depth (true where the bundle records its
    /// elastomer) or, false, from the network's pressure output where it has one.
    pub solve_force: bool,
    /// The force from the network's force head where it has one (true by default; the better
    /// estimate on the quickstart's scenes, BENCHMARKS.md "The force head"), with the pressure
    /// map ([`solve_force`](Self::solve_force)'s or the network's) scaled to it; false: the
    /// pressure map's own resultant.
    pub head_force: bool,
    /// Takes each frame's global drift against the reference ([`sensor::gate::Balance`]: an LED
    /// warming, auto exposure, white balance) out before the network reads it, so that it reads
    /// the colours it was trained on. On by default; without a reference there is nothing to
    /// balance against.
    pub balance_input: bool,
}

impl Predictor {
    /// Loads `dir` (a bundle) onto `device`; BatchNorms are folded into their convolutions.
    pub fn load(dir: &Path, device: &Device) -> Result<Self, InferError> {
        let (net, file) = load_bundle(dir, device)?;
        let reference = model::bundle::load_reference(dir, &file)?;
        let bad = |message: String| InferError::File { path: dir.join(model::bundle::BUNDLE_JSON), message };
        let encoding = file.encoding().map_err(bad)?;
        let encoder = InputEncoder::new(encoding, [file.input_height_px, file.input_width_px], reference.as_ref())
            .map_err(|e| bad(e.to_string()))?;
        let mask = file.sensor.valid_mask();
        let rays = file.sensor.pixel_rays();
        let out_hw = file.model.output_hw([file.input_height_px, file.input_width_px]);
        let trained = sensor::resample::covered_mask(&mask, file.sensor.crop_size_px as usize, out_hw);
        let border_fill = sensor::resample::FillPlan::new(&trained, out_hw);
        let gate = file.contact_gate.as_ref().map(|g| g.gate);
        let mut predictor = Predictor {
            dir: dir.to_path_buf(),
            net: net.folded(),
            device: device.clone(),
            reference: None,
            mask,
            rays,
            gate,
            encoder,
            border_fill,
            tare_mm: None,
            tare_kpa: None,
            tare_force_n: None,
            areas: file.model.pressure.then(|| std::sync::Arc::new(DomeAreas::new(&file.sensor))),
            solver: None,
            solve_force: false,
            head_force: true,
            balance_input: true,
            file,
        };
        predictor.set_elastomer(predictor.file.elastomer.clone()).map_err(|e| bad(e.to_string()))?;
        predictor.reference = reference;
        let reference = predictor.reference.clone();
        predictor.set_tare(reference.as_ref())?;
        Ok(predictor)
    }

    /// Takes `frame` (an untouched view of this unit, normally the reference image) as zero
    /// depth from now on; `None` turns the tare off. One network pass.
    pub fn set_tare(&mut self, frame: Option<&RgbImage>) -> Result<(), InferError> {
        // Worked out before anything changes: a frame that fails leaves the tare as it was.
        (self.tare_mm, self.tare_kpa, self.tare_force_n) = match frame {
            Some(frame) => {
                let heads = self.net.forward_heads(self.input(std::slice::from_ref(frame))?);
                let force = heads.force.map(|f| output_n(f)[0].map(|v| v as f32));
                (Some(self.output_mm(heads.depth)), heads.pressure.map(output_kpa), force)
            }
            None => (None, None, None),
        };
        Ok(())
    }

    /// Reads frames against `reference` (an untouched frame of the unit as it looks now) from
    /// now on: the input's reference difference, the gate and the tare (if on) all use it. For
    /// the samples of a dataset rendered under random looks, each with its own untouched frame,
    /// and for a stream keeping its reference current ([`crate::ReferenceKeeper`]).
    pub fn set_reference(&mut self, reference: RgbImage) -> Result<(), InferError> {
        self.check(&reference)?;
        let hw = [self.file.input_height_px, self.file.input_width_px];
        let encoder = InputEncoder::new(self.encoder.encoding(), hw, Some(&reference)).map_err(|e| {
            InferError::File { path: self.dir.join(model::bundle::BUNDLE_JSON), message: e.to_string() }
        })?;
        // The tare reads the reference as every frame will be read: against itself.
        let old = (std::mem::replace(&mut self.encoder, encoder), self.reference.replace(reference.clone()));
        if self.is_tared()
            && let Err(e) = self.set_tare(Some(&reference))
        {
            (self.encoder, self.reference) = old;
            return Err(e);
        }
        Ok(())
    }

    /// Whether predictions are tared (see [`set_tare`](Self::set_tare)).
    pub fn is_tared(&self) -> bool {
        self.tare_mm.is_some()
    }

    fn check(&self, frame: &RgbImage) -> Result<(), InferError> {
        let crop = self.file.sensor.crop_size_px;
        if frame.dimensions() != (crop, crop) {
            return Err(InferError::FrameSize { width: frame.width(), height: frame.height(), crop });
        }
        Ok(())
    }

    /// Whether `frame` differs from the unit's reference by more than noise (always true
    /// without a reference image or a gate).
    pub fn has_contact(&self, frame: &RgbImage) -> bool {
        let (Some(reference), Some(gate)) = (&self.reference, &self.gate) else { return true };
        gate.differs(frame, reference, &self.mask)
    }

    /// Reads a camera frame for this bundle's unit: PNG or JPEG, the camera's full frame (cut to
    /// the sensor's crop around the calibrated optical centre) or the crop itself; a greyscale
    /// frame, a frame of another size, or one whose colours are BGR-ordered against the unit's
    /// reference frame is refused with the reason.
    pub fn read_frame(&self, path: &Path) -> Result<RgbImage, InferError> {
        self.accept_frame(path, sensor::frame::read(path)?, true)
    }

    /// A decoded camera frame made this unit's crop, the one way every frame comes in (a file,
    /// or a stream's frame, decoded or a camera's pixels): the full frame cut to the crop, or
    /// the crop itself (its size checked here, once), colour required; with `check_channels`,
    /// BGR order against the reference refused (a stream checks its first frame only). `name`
    /// names the frame in errors.
    pub fn accept_frame(&self, name: &Path, image: RgbImage, check_channels: bool) -> Result<RgbImage, InferError> {
        let crop = sensor::frame::crop(name, image, &self.file.sensor)?;
        if let (true, Some(reference)) = (check_channels, &self.reference) {
            sensor::frame::check_channel_order(name, &crop, reference, &self.mask)?;
        }
        Ok(crop)
    }

    /// Depth (mm) on the crop's grid, zero outside the useful disk. A frame with no contact
    /// (see [`has_contact`](Self::has_contact)) returns zeros without running the network.
    pub fn predict(&self, frame: &RgbImage) -> Result<DepthMap, InferError> {
        Ok(self.predict_gated(frame)?.0)
    }

    /// Like [`predict`](Self::predict), also saying whether the network ran.
    pub fn predict_gated(&self, frame: &RgbImage) -> Result<(DepthMap, bool), InferError> {
        self.check(frame)?;
        Ok(self.predict_crop(frame))
    }

    /// [`predict_gated`](Self::predict_gated) for a frame known to be the crop: one that
    /// [`accept_frame`](Self::accept_frame) returned, whose size is not checked again.
    pub(crate) fn predict_crop(&self, frame: &RgbImage) -> (DepthMap, bool) {
        let p = self.predict_all_crop(frame);
        (p.depth, p.network_ran)
    }

    /// The network's depth maps for a batch of frames (no contact gate).
    pub fn predict_network(&self, frames: &[RgbImage]) -> Result<Vec<DepthMap>, InferError> {
        Ok(self.predict_network_all(frames)?.into_iter().map(|p| p.depth).collect())
    }

    /// Solves each predicted contact with `elastomer` from now on (`None`: force only from a
    /// network's pressure output), e.g. a stiffness fitted to a force-torque sensor's readings.
    /// An effective modulus that is not a positive finite number is refused, and nothing changes.
    pub fn set_elastomer(&mut self, elastomer: Option<model::bundle::ElastomerRecord>) -> Result<(), InferError> {
        if let Some(e) = &elastomer
            && !(e.effective_modulus_mpa > 0.0 && e.effective_modulus_mpa.is_finite())
        {
            return Err(InferError::Modulus(e.effective_modulus_mpa));
        }
        self.solver =
            elastomer.as_ref().map(|e| std::sync::Arc::new(ForceSolver::new(&self.file.sensor, &self.rays, e)));
        self.solve_force = elastomer.is_some();
        self.file.elastomer = elastomer;
        Ok(())
    }

    /// The contact that `depth` shows (its pixels above the contact threshold) solved with the
    /// unit's elastomer: what predictions report as force while [`solve_force`](Self::solve_force)
    /// is on. `None` without an elastomer, or where the solve does not settle (with a warning).
    pub fn solved_force(&self, depth: &DepthMap) -> Option<Force> {
        self.solver.as_ref()?.force(depth)
    }

    /// Whether predictions carry contact force: solved on the predicted depth (the bundle
    /// records its unit's elastomer) or from the network's pressure output.
    pub fn has_force(&self) -> bool {
        self.solving() || self.areas.is_some() || self.heading()
    }

    /// Where predictions' force comes from, in words (`None`: they carry none).
    pub fn force_source(&self) -> Option<&'static str> {
        Some(match (self.heading(), self.solving(), self.areas.is_some()) {
            (true, true, _) => "the network's force head, with the contact solved on the predicted depth scaled to it",
            (true, false, true) => "the network's force head, with its pressure output scaled to it",
            (true, false, false) => "the network's force head (no pressure map: no elastomer, no pressure output)",
            (false, true, _) => {
                "the contact solved on the predicted depth with the elastomer fitted to the train labels"
            }
            (false, false, true) => "the network's pressure output",
            (false, false, false) => return None,
        })
    }

    fn heading(&self) -> bool {
        self.head_force && self.net.has_force_head()
    }

    fn solving(&self) -> bool {
        self.solve_force && self.solver.is_some()
    }

    /// Depth and, where the bundle has the pressure output, the contact force, behind the
    /// contact gate as [`predict`](Self::predict) is.
    pub fn predict_all(&self, frame: &RgbImage) -> Result<Prediction, InferError> {
        self.check(frame)?;
        Ok(self.predict_all_crop(frame))
    }

    /// [`predict_all`](Self::predict_all) for a frame [`accept_frame`](Self::accept_frame) returned.
    pub(crate) fn predict_all_crop(&self, frame: &RgbImage) -> Prediction {
        if !self.has_contact(frame) {
            return self.untouched();
        }
        self.all_on_crops(std::slice::from_ref(frame)).remove(0)
    }

    /// What a frame the contact gate answers gets: zero depth and, with the force output, zero
    /// pressure and wrench.
    fn untouched(&self) -> Prediction {
        let depth = DepthMap::zeros(self.file.sensor.crop_size_px);
        let force = self.has_force().then(|| Force::zero(depth.size_px));
        Prediction { depth, force, network_ran: false }
    }

    /// [`predict_all`](Self::predict_all) for several frames: each behind the contact gate, the
    /// frames with contact through the network as one batch. Each answer equals the frame's own
    /// [`predict_all`](Self::predict_all).
    pub fn predict_batch(&self, frames: &[RgbImage]) -> Result<Vec<Prediction>, InferError> {
        frames.iter().try_for_each(|f| self.check(f))?;
        let touched: Vec<bool> = frames.iter().map(|f| self.has_contact(f)).collect();
        let batch: Vec<RgbImage> = frames.iter().zip(&touched).filter(|(_, t)| **t).map(|(f, _)| f.clone()).collect();
        let mut ran = self.all_on_crops(&batch).into_iter();
        Ok(touched
            .iter()
            .map(|&t| if t { ran.next().expect("one answer per frame with contact") } else { self.untouched() })
            .collect())
    }

    /// [`predict_all`](Self::predict_all) for a batch of frames, without the contact gate.
    pub fn predict_network_all(&self, frames: &[RgbImage]) -> Result<Vec<Prediction>, InferError> {
        frames.iter().try_for_each(|f| self.check(f))?;
        Ok(self.all_on_crops(frames))
    }

    fn all_on_crops(&self, frames: &[RgbImage]) -> Vec<Prediction> {
        if frames.is_empty() {
            return Vec::new();
        }
        let heads = self.net.forward_heads(self.input_of_crops(frames));
        let depths = self.depth_maps(heads.depth);
        let mut forces: Vec<Option<Force>> = match heads.pressure {
            _ if self.solving() => depths.iter().map(|d| self.solved_force(d)).collect(),
            Some(p) => self.forces(p, &depths).into_iter().map(Some).collect(),
            None => vec![None; depths.len()],
        };
        if let Some(head) = heads.force.filter(|_| self.heading()) {
            for ((force, depth), f) in forces.iter_mut().zip(&depths).zip(output_n(head)) {
                *force = Some(self.head_force_of(force.take(), depth, f));
            }
        }
        depths.into_iter().zip(forces).map(|(depth, force)| Prediction { depth, force, network_ran: true }).collect()
    }

    /// The force head's `head_n` (N) as predictions report it: less its reading of the tare
    /// frame, zero where `depth` shows no contact, with `map`'s pressure scaled to it (a zero
    /// map where there is none).
    fn head_force_of(&self, map: Option<Force>, depth: &DepthMap, head_n: [f64; 3]) -> Force {
        let contact = depth.depth_mm.iter().any(|&d| d > sensor::CONTACT_THRESHOLD_MM);
        let tare = self.tare_force_n.unwrap_or_default();
        let force_n: [f64; 3] = std::array::from_fn(|k| if contact { head_n[k] - tare[k] as f64 } else { 0.0 });
        map.unwrap_or_else(|| Force::zero(depth.size_px)).scaled_to(force_n)
    }

    /// The pressure output (network units) to pressure maps (kPa) on the crop's grid, each
    /// tared, filled at the border and resized as its depth map is, kept only where that depth
    /// map shows contact, and their resultants.
    fn forces(&self, out: Tensor<4>, depths: &[DepthMap]) -> Vec<Force> {
        let [_, _, oh, ow] = out.dims();
        let crop = self.file.sensor.crop_size_px;
        let areas = self.areas.as_ref().expect("a network with the pressure output has its areas");
        output_kpa(out)
            .chunks_mut(oh * ow)
            .zip(depths)
            .map(|(kpa, depth)| {
                let pressure_kpa = self
                    .on_crop(kpa, self.tare_kpa.as_deref(), [oh, ow])
                    .iter()
                    .zip(&depth.depth_mm)
                    .map(|(&p, &d)| if d > sensor::CONTACT_THRESHOLD_MM { p.max(0.0) } else { 0.0 })
                    .collect::<Vec<f32>>();
                let wrench = areas.wrench(&pressure_kpa);
                Force { pressure: PressureMap { size_px: crop, pressure_kpa }, wrench }
            })
            .collect()
    }

    /// The network's input for a batch of frames: resized, RGB, values / 255 (and the
    /// reference difference if the model reads it).
    pub fn input(&self, frames: &[RgbImage]) -> Result<Tensor<4>, InferError> {
        frames.iter().try_for_each(|f| self.check(f))?;
        Ok(self.input_of_crops(frames))
    }

    fn input_of_crops(&self, frames: &[RgbImage]) -> Tensor<4> {
        let [h, w] = self.encoder.hw();
        let c = self.encoder.channels().count();
        let input: Vec<f32> = frames
            .iter()
            .flat_map(|f| match (self.drift(f), &self.reference) {
                (Some(balance), Some(reference)) => self.encoder.encode(&balance.undo(f, reference)),
                _ => self.encoder.encode(f),
            })
            .collect();
        Tensor::<4>::from_data(TensorData::new(input, [frames.len(), c, h, w]), &self.device)
    }

    /// The drift [`input`](Self::input) takes out of `frame`, if any.
    pub fn drift(&self, frame: &RgbImage) -> Option<sensor::gate::Balance> {
        let reference = self.reference.as_ref().filter(|_| self.balance_input)?;
        Some(sensor::gate::Balance::fit(frame, reference, &self.mask)).filter(|b| !b.is_none())
    }

    /// `frame` in this predictor's reference's colours: its global drift taken out, as
    /// [`input`](Self::input) takes it out of every frame (unchanged without a reference or with
    /// `balance_input` off). A stream's following reference is kept this way, so that it holds
    /// only what drift does unevenly.
    pub fn undrifted(&self, frame: RgbImage) -> RgbImage {
        match self.reference.as_ref().filter(|_| self.balance_input) {
            Some(base) => sensor::gate::Balance::fit(&frame, base, &self.mask).undo(&frame, base),
            None => frame,
        }
    }

    /// The network alone: input tensor to output tensor (network units, the model's output size).
    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        self.net.forward(input)
    }

    /// Network output to depth maps (mm) on the crop's grid, zero outside the useful disk.
    pub fn depth_maps(&self, out: Tensor<4>) -> Vec<DepthMap> {
        let [_, _, oh, ow] = out.dims();
        let crop = self.file.sensor.crop_size_px;
        let max = self.file.sensor.max_depth_mm as f32;
        self.output_mm(out)
            .chunks_mut(oh * ow)
            .map(|mm| {
                let full = self.on_crop(mm, self.tare_mm.as_deref(), [oh, ow]);
                let depth_mm =
                    full.iter().zip(&self.mask).map(|(&d, &m)| if m { d.clamp(0.0, max) } else { 0.0 }).collect();
                DepthMap { size_px: crop, depth_mm }
            })
            .collect()
    }

    /// One output plane (`[oh, ow]`) on the crop's grid: `tare` subtracted, the border filled,
    /// resized. Depth and pressure alike.
    fn on_crop(&self, plane: &mut [f32], tare: Option<&[f32]>, [oh, ow]: [usize; 2]) -> Vec<f32> {
        if let Some(tare) = tare {
            plane.iter_mut().zip(tare).for_each(|(v, t)| *v -= t);
        }
        // Rim pixels of the crop interpolate between output pixels; the untrained ones outside
        // the useful disk would leak into them (0.45 mm ghosts on untouched frames).
        if self.border_fill.len() == plane.len() {
            self.border_fill.apply(plane);
        }
        // Not `image`'s resize: it clamps float pixels to [0, 1].
        let crop = self.file.sensor.crop_size_px as usize;
        sensor::resample::resize_plane(plane, [oh, ow], [crop, crop])
    }

    /// The network's output (network units) in millimetres, planes one after another.
    fn output_mm(&self, out: Tensor<4>) -> Vec<f32> {
        let scale = self.file.depth_scale;
        let values: Vec<f32> = out.into_data().try_to_vec::<f32>().expect("f32 output");
        values.into_iter().map(|v| scale.to_mm(v)).collect()
    }

    /// The contact patch (pixels deeper than `min_depth_mm`) as points, sensor frame, mm.
    pub fn point_cloud(&self, depth: &DepthMap, min_depth_mm: f32) -> crate::PointCloud {
        crate::PointCloud::from_rays(depth, &self.rays, self.file.sensor.radius_mm, Some(min_depth_mm))
    }

    /// Pixels pressed deeper than `threshold_mm`.
    pub fn contact_mask(depth: &DepthMap, threshold_mm: f32) -> Vec<bool> {
        depth.contact_px(threshold_mm)
    }
}

/// The force head's output (`[N, 3]`, loss units) in N, one force per image.
fn output_n(out: Tensor<2>) -> Vec<[f64; 3]> {
    let values: Vec<f32> = out.into_data().convert::<f32>().try_into_vec::<f32>().expect("f32 output");
    values.chunks(3).map(|v| std::array::from_fn(|k| (v[k] * model::FORCE_N_PER_LOSS_UNIT) as f64)).collect()
}

/// The pressure output (network units) in kPa, planes one after another.
fn output_kpa(out: Tensor<4>) -> Vec<f32> {
    let values: Vec<f32> = out.into_data().try_to_vec::<f32>().expect("f32 output");
    values.into_iter().map(|v| v * model::PRESSURE_KPA_PER_UNIT).collect()
}
