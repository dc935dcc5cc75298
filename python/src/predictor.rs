//! `densetact.Predictor`: a bundle loaded once, frames to depth, contact, point clouds and force
//! with the same contact gate, tare and colour balance as `infer predict` and `infer stream`.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use image::RgbImage;
use numpy::{PyArray1, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensor::CONTACT_THRESHOLD_MM;

use crate::arrays::{FrameArg, frame_arg, plane};
use crate::error;

/// A bundle (`train export`) loaded for prediction.
#[pyclass(module = "densetact", frozen)]
pub(crate) struct Predictor {
    /// Behind a lock: `retare` changes it, and the lock is held, not the GIL, while the
    /// network runs.
    inner: Mutex<infer::Predictor>,
    #[pyo3(get)]
    bundle: PathBuf,
}

/// Everything one frame gives.
#[pyclass(module = "densetact", frozen, get_all)]
pub(crate) struct Prediction {
    /// Depth (mm, float32) on the sensor's crop: how far the surface is pressed in along each
    /// pixel's ray; zero outside the useful disk.
    depth_mm: Py<PyArray2<f32>>,
    /// Pixels deeper than `CONTACT_THRESHOLD_MM` (bool, the crop's shape).
    contact: Py<PyArray2<bool>>,
    /// The contact patch's surface points (N x 3, float32, mm, sensor frame), as `infer predict
    /// --ply` writes them.
    points_mm: Py<PyArray2<f32>>,
    /// Whether the network ran (False: the contact gate found no contact; the maps are zero).
    network_ran: bool,
    /// The contact force, where the bundle's network has the force output; else None.
    force: Option<Py<Force>>,
}

/// A frame's contact force.
#[pyclass(module = "densetact", frozen, get_all)]
pub(crate) struct Force {
    /// Contact pressure (kPa, float32) on the crop; zero off contact.
    pressure_kpa: Py<PyArray2<f32>>,
    /// The force on the sensor (N, sensor frame: x, y, z): the network's force head's where it
    /// has one (the pressure then scaled to it), else the pressure's resultant.
    force_n: Py<PyArray1<f64>>,
    /// Its moment about the dome's centre (N mm, sensor frame).
    torque_nmm: Py<PyArray1<f64>>,
}

/// A prediction in Rust's hands, before NumPy's: made without the GIL.
struct Answer {
    size_px: usize,
    depth_mm: Vec<f32>,
    contact: Vec<bool>,
    points_mm: Vec<f32>,
    network_ran: bool,
    force: Option<infer::Force>,
}

impl Predictor {
    /// The predictor, for work done without the GIL: a thread waiting here holds no GIL, so
    /// the thread inside can always take it back.
    fn lock(&self) -> std::sync::MutexGuard<'_, infer::Predictor> {
        // A panic inside the network leaves the predictor as it was: its state changes only by
        // assignment after the work is done.
        self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// `f` on the predictor with the GIL released (the lock taken without it).
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut infer::Predictor) -> anyhow::Result<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| f(&mut self.lock())).map_err(error)
    }

    /// `frame` as this bundle's crop: a file read as `infer predict` reads it, or pixels cut and
    /// checked the same way (full frame or crop, colour, RGB order against the reference).
    fn crop(p: &infer::Predictor, frame: FrameArg, name: &str) -> anyhow::Result<RgbImage> {
        Ok(match frame {
            FrameArg::File(path) => p.read_frame(&path)?,
            FrameArg::Pixels(image) => p.accept_frame(Path::new(name), image, true)?,
        })
    }

    fn answer(p: &infer::Predictor, prediction: infer::Prediction) -> Answer {
        let contact = infer::Predictor::contact_mask(&prediction.depth, CONTACT_THRESHOLD_MM);
        let cloud = p.point_cloud(&prediction.depth, CONTACT_THRESHOLD_MM);
        Answer {
            size_px: prediction.depth.size_px as usize,
            contact,
            points_mm: cloud.points_mm.iter().flatten().copied().collect(),
            depth_mm: prediction.depth.depth_mm,
            network_ran: prediction.network_ran,
            force: prediction.force,
        }
    }

    fn force_to_python(py: Python<'_>, f: infer::Force) -> PyResult<Py<Force>> {
        let n = f.pressure.size_px as usize;
        Py::new(
            py,
            Force {
                pressure_kpa: plane(py, f.pressure.pressure_kpa, [n, n]).unbind(),
                force_n: PyArray1::from_slice(py, &f.wrench.force_n).unbind(),
                torque_nmm: PyArray1::from_slice(py, &f.wrench.torque_nmm).unbind(),
            },
        )
    }

    fn to_python(py: Python<'_>, a: Answer) -> PyResult<Prediction> {
        let n = a.size_px;
        let force = a.force.map(|f| Self::force_to_python(py, f)).transpose()?;
        let points = a.points_mm.len() / 3;
        Ok(Prediction {
            depth_mm: plane(py, a.depth_mm, [n, n]).unbind(),
            contact: plane(py, a.contact, [n, n]).unbind(),
            points_mm: plane(py, a.points_mm, [points, 3]).unbind(),
            network_ran: a.network_ran,
            force,
        })
    }
}

#[pymethods]
impl Predictor {
    /// Loads `bundle` (a folder `train export` wrote; every file checked against its SHA-256)
    /// onto `device`: "cpu", or "wgpu" / "cuda" in a build with that backend. Tared on the
    /// bundle's reference image, as the command-line tools are.
    #[new]
    #[pyo3(signature = (bundle, device = "cpu"))]
    fn new(py: Python<'_>, bundle: PathBuf, device: &str) -> PyResult<Self> {
        let name = if device == "cpu" { "flex" } else { device };
        let device = model::backend::working_device(name).map_err(error)?;
        let inner = py.detach(|| infer::Predictor::load(&bundle, &device)).map_err(error)?;
        Ok(Predictor { inner: Mutex::new(inner), bundle })
    }

    /// Depth, contact, point cloud (and force) for one frame: an HxWx3 uint8 RGB array or a
    /// PNG/JPEG path, the camera's full frame or the sensor's crop. A frame the contact gate
    /// finds untouched gets zeros without the network, unless `always`. Equal, bit for bit, to
    /// `infer predict` on the same frame.
    #[pyo3(signature = (frame, always = false))]
    fn predict(&self, py: Python<'_>, frame: &Bound<'_, PyAny>, always: bool) -> PyResult<Prediction> {
        let frame = frame_arg(frame, "frame")?;
        let answer = self.with(py, |p| {
            let crop = Self::crop(p, frame, "frame")?;
            let prediction = match always {
                true => p.predict_network_all(std::slice::from_ref(&crop))?.remove(0),
                false => p.predict_all(&crop)?,
            };
            Ok(Self::answer(p, prediction))
        })?;
        Self::to_python(py, answer)
    }

    /// [`predict`] for several frames: the ones with contact go through the network as one
    /// batch. Each answer equals the frame's own `predict`.
    #[pyo3(signature = (frames, always = false))]
    fn predict_batch(&self, py: Python<'_>, frames: Vec<Bound<'_, PyAny>>, always: bool) -> PyResult<Vec<Prediction>> {
        let args: Vec<FrameArg> =
            frames.iter().enumerate().map(|(k, f)| frame_arg(f, &format!("frames[{k}]"))).collect::<PyResult<_>>()?;
        let answers = self.with(py, |p| {
            let crops: Vec<RgbImage> = args
                .into_iter()
                .enumerate()
                .map(|(k, f)| Self::crop(p, f, &format!("frames[{k}]")))
                .collect::<anyhow::Result<_>>()?;
            let predictions = match always {
                true => p.predict_network_all(&crops)?,
                false => p.predict_batch(&crops)?,
            };
            Ok(predictions.into_iter().map(|prediction| Self::answer(p, prediction)).collect::<Vec<_>>())
        })?;
        answers.into_iter().map(|a| Self::to_python(py, a)).collect()
    }

    /// Takes `frame` (an untouched view of the unit) as zero depth from now on, as the bundle's
    /// reference is taken at load; None turns the tare off (the network's raw reading).
    #[pyo3(signature = (frame))]
    fn retare(&self, py: Python<'_>, frame: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let frame = frame.map(|f| frame_arg(f, "frame")).transpose()?;
        self.with(py, |p| {
            let crop = frame.map(|f| Self::crop(p, f, "frame")).transpose()?;
            Ok(p.set_tare(crop.as_ref())?)
        })
    }

    /// Reads frames against `frame` (an untouched frame of the unit as it looks now) from now
    /// on: the input's reference difference, the contact gate and the tare all use it.
    fn set_reference(&self, py: Python<'_>, frame: &Bound<'_, PyAny>) -> PyResult<()> {
        let frame = frame_arg(frame, "frame")?;
        self.with(py, |p| {
            let crop = Self::crop(p, frame, "frame")?;
            Ok(p.set_reference(crop)?)
        })
    }

    /// Whether the contact gate sees contact in `frame` (always True without a reference image
    /// or a gate in the bundle).
    fn has_contact(&self, py: Python<'_>, frame: &Bound<'_, PyAny>) -> PyResult<bool> {
        let frame = frame_arg(frame, "frame")?;
        self.with(py, |p| Ok(p.has_contact(&Self::crop(p, frame, "frame")?)))
    }

    /// Solves each predicted contact for force from now on with an elastomer of effective
    /// modulus `effective_modulus_mpa` (E / (1 - nu^2), MPa), e.g. fitted to a force-torque
    /// sensor's readings; predictions then carry `force`. None: force only from a network with
    /// the force output. A modulus that is not a positive number raises ValueError and changes
    /// nothing.
    fn set_elastomer(&self, py: Python<'_>, effective_modulus_mpa: Option<f64>) -> PyResult<()> {
        let record = effective_modulus_mpa.map(model::bundle::ElastomerRecord::given);
        py.detach(|| self.lock().set_elastomer(record)).map_err(|e| match e {
            infer::InferError::Modulus(_) => PyValueError::new_err(e.to_string()),
            e => error(e),
        })
    }

    /// The effective modulus (MPa) each predicted contact is solved with: the bundle's fitted
    /// elastomer or `set_elastomer`'s; None when force comes only from the network, or not at all.
    #[getter]
    fn effective_modulus_mpa(&self) -> Option<f64> {
        self.lock().file.elastomer.as_ref().map(|e| e.effective_modulus_mpa)
    }

    /// Where predictions' force comes from, in words; None where they carry none.
    #[getter]
    fn force_source(&self) -> Option<&'static str> {
        self.lock().force_source()
    }

    /// The contact that `depth_mm` (float32, the crop's shape, e.g. a prediction's or a
    /// label's) shows, solved with the elastomer: pixels above `CONTACT_THRESHOLD_MM` pressed,
    /// the rest free. None where the solve does not settle (a map no indenter could press).
    /// Raises DenseTactError without an elastomer (see `set_elastomer`).
    fn solve_force(&self, py: Python<'_>, depth_mm: PyReadonlyArray2<'_, f32>) -> PyResult<Option<Py<Force>>> {
        let n = self.crop_size_px() as usize;
        if depth_mm.shape() != [n, n] {
            return Err(PyValueError::new_err(format!(
                "depth_mm must be the crop's {n}x{n}, got shape {:?}",
                depth_mm.shape()
            )));
        }
        let depth = sensor::DepthMap { size_px: n as u32, depth_mm: depth_mm.as_array().iter().copied().collect() };
        let force = py.detach(|| {
            let p = self.lock();
            match p.file.elastomer {
                Some(_) => Ok(p.solved_force(&depth)),
                None => Err(error(anyhow::anyhow!(
                    "this predictor has no elastomer to solve with (its bundle records none): call set_elastomer first"
                ))),
            }
        })?;
        force.map(|f| Self::force_to_python(py, f)).transpose()
    }

    /// Whether predictions are tared (see `retare`).
    #[getter]
    fn is_tared(&self) -> bool {
        self.lock().is_tared()
    }

    /// Whether the network has the force output (`Prediction.force` is then set).
    #[getter]
    fn has_force(&self) -> bool {
        self.lock().has_force()
    }

    /// The side of the sensor's square crop (px): the size of every map.
    #[getter]
    fn crop_size_px(&self) -> u32 {
        self.lock().file.sensor.crop_size_px
    }

    /// The camera frame's pixel (x, y) of the crop's top-left pixel: a full frame is cut as
    /// `frame[y:y + crop_size_px, x:x + crop_size_px]`.
    #[getter]
    fn crop_origin_px(&self) -> (i64, i64) {
        self.lock().file.sensor.crop_origin_px()
    }

    /// The useful disk: the crop's pixels that see the dome (bool).
    #[getter]
    fn mask<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<bool>> {
        let p = self.lock();
        let n = p.file.sensor.crop_size_px as usize;
        plane(py, p.mask.clone(), [n, n])
    }

    /// The unit's sensor description (the `sensor` of `bundle.json`), as a dict.
    #[getter]
    fn sensor<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let json = serde_json::to_string(&self.lock().file.sensor).map_err(error)?;
        py.import("json")?.call_method1("loads", (json,))
    }

    fn __repr__(&self) -> String {
        let p = self.lock();
        format!(
            "Predictor({:?}, crop {}x{1} px, input {}x{}, force output: {})",
            self.bundle.display().to_string(),
            p.file.sensor.crop_size_px,
            p.file.input_width_px,
            p.file.input_height_px,
            if p.has_force() { "yes" } else { "no" }
        )
    }
}
