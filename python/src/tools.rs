//! `densetact.read_frame`, `densetact.calibrate` and `densetact.label_session`: the dataset
//! tool's steps a lab meets first, on the same code as `dataset calibrate` and `dataset label`;
//! and `densetact.set_spin_ms`, the CPU workers' polling between predictions.

use std::path::PathBuf;

use clap::ValueEnum;
use dataset::calibration::{CalibrationOptions, DEFAULT_MAX_UNCERTAINTY_PX, calibrate as calibrate_frame};
use numpy::PyArray3;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sensor::Sensor;

use crate::arrays::{FrameArg, frame_arg, rgb};
use crate::error;

/// Reads a camera frame (PNG or JPEG, as the tools read it: a cut or damaged file, or a
/// greyscale one, is refused with the file named) as an HxWx3 uint8 RGB array.
#[pyfunction]
pub(crate) fn read_frame<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyArray3<u8>>> {
    let image = py
        .detach(|| {
            let image = sensor::frame::read(&path)?;
            sensor::frame::check_colour(&path, &image)?;
            Ok::<_, sensor::frame::FrameError>(image)
        })
        .map_err(error)?;
    Ok(rgb(py, image))
}

/// Keeps all but one of the network's CPU worker threads polling for work for `ms` milliseconds
/// after each prediction instead of sleeping, as ONNX Runtime's do by default: a frame at a
/// camera's rate then need not wait for a sleeping core (the quickstart's network at 20 fps on
/// a 2-vCPU VM: 4.4 ms against 5.9), for a core kept busy between frames. 0 (the default) lets
/// them sleep. Process-wide.
#[pyfunction]
pub(crate) fn set_spin_ms(ms: f64) -> PyResult<()> {
    if !ms.is_finite() || ms < 0.0 {
        return Err(PyValueError::new_err(format!("set_spin_ms: {ms} is no number of milliseconds (0 or more)")));
    }
    model::backend::set_spin(std::time::Duration::from_secs_f64(ms / 1e3));
    Ok(())
}

/// Calibrates a unit's fisheye from its camera's frame of the pressed saw-tooth indicator (an
/// array or a path), as `dataset calibrate` does: the sensor description as JSON, and the
/// calibration's figures as JSON.
#[pyfunction]
#[pyo3(signature = (frame, radius_mm = 25.0, pitch_deg = 5.0, teeth = 17, max_uncertainty_px = DEFAULT_MAX_UNCERTAINTY_PX))]
pub(crate) fn calibrate(
    py: Python<'_>,
    frame: &Bound<'_, PyAny>,
    radius_mm: f64,
    pitch_deg: f64,
    teeth: u32,
    max_uncertainty_px: f64,
) -> PyResult<(String, String)> {
    let frame = frame_arg(frame, "frame")?;
    let mut opts = CalibrationOptions { radius_mm, max_uncertainty_px, ..Default::default() };
    (opts.indicator.pitch_deg, opts.indicator.teeth) = (pitch_deg, teeth);
    opts.validate().map_err(|e| PyValueError::new_err(e.to_string()))?;
    py.detach(|| {
        let (name, image) = match frame {
            FrameArg::File(path) => (path.clone(), sensor::frame::read(&path)?),
            FrameArg::Pixels(image) => (PathBuf::from("frame"), image),
        };
        sensor::frame::check_colour(&name, &image)?;
        let cal = calibrate_frame(&image, &opts).map_err(|e| anyhow::anyhow!("{}: {e}", name.display()))?;
        let figures = serde_json::json!({
            "rim_radius_px": cal.rim_radius_px,
            "rim_rms_px": cal.rim_rms_px,
            "edges": cal.edges.len(),
            "missing_teeth": cal.missing_teeth(),
            "fit_rms_px": cal.fit_rms_px,
            "mean_sd_deg": cal.mean_sd_deg,
            "max_sd_deg": cal.max_sd_deg,
            "centre_sd_px": cal.centre_sd_px,
            "uncertainty_px": cal.uncertainty_px,
        });
        Ok::<_, anyhow::Error>((serde_json::to_string(&cal.sensor)?, figures.to_string()))
    })
    .map_err(error)
}

/// Labels a capture session into a dataset folder, as `dataset label` does (resumable, locked,
/// written atomically): the report's lines.
#[pyfunction]
#[pyo3(signature = (
    session, out, sensor_json, kit = "procedural", kit_scale = 1.0, on_bad_row = "stop",
    z_from = "seated", z_zero_mm = None, force_labels = true,
    youngs_modulus_mpa = dataset::mechanics::Material::PAPER.youngs_modulus_mpa,
    poisson_ratio = dataset::mechanics::Material::PAPER.poisson_ratio, shard = None, register = false
))]
#[allow(clippy::too_many_arguments)] // Python's keyword arguments, one per flag of `dataset label`.
pub(crate) fn label_session(
    py: Python<'_>,
    session: PathBuf,
    out: PathBuf,
    sensor_json: &str,
    kit: &str,
    kit_scale: f32,
    on_bad_row: &str,
    z_from: &str,
    z_zero_mm: Option<f32>,
    force_labels: bool,
    youngs_modulus_mpa: f64,
    poisson_ratio: f64,
    shard: Option<&str>,
    register: bool,
) -> PyResult<Vec<String>> {
    let sensor: Sensor = serde_json::from_str(sensor_json)
        .map_err(|e| PyValueError::new_err(format!("the sensor description is not one: {e}")))?;
    sensor.validate().map_err(|e| PyValueError::new_err(format!("the sensor description: {e}")))?;
    let request = dataset::label::LabelRequest {
        session,
        kit: kit.to_string(),
        kit_scale,
        sensor,
        out,
        on_bad_row: choice(on_bad_row, "on_bad_row")?,
        z: dataset::touch::ZReading { from: choice(z_from, "z_from")?, zero_mm: z_zero_mm },
        force: force_labels.then_some(dataset::mechanics::Material { youngs_modulus_mpa, poisson_ratio }),
        shard: shard
            .map(|s| s.parse::<formats::Shard>().map_err(|e| PyValueError::new_err(format!("shard: {e}"))))
            .transpose()?,
        register,
        flags: false,
    };
    let report = py.detach(|| request.run()).map_err(error)?;
    Ok(dataset::label::report_lines(&report))
}

/// `value` as one of a command-line choice's values (`first_touch` or `first-touch`).
fn choice<T: ValueEnum>(value: &str, name: &str) -> PyResult<T> {
    T::from_str(&value.replace('_', "-"), true).map_err(|_| {
        let names: Vec<String> = T::value_variants()
            .iter()
            .filter_map(|v| v.to_possible_value())
            .map(|v| v.get_name().replace('-', "_"))
            .collect();
        PyValueError::new_err(format!("{name} must be one of {}, got {value:?}", names.join(", ")))
    })
}
