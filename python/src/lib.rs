//! The native half of the Python package `densetact` (`densetact._densetact`): the predictor,
//! the dataset reader, the calibration and the labelling that the command-line tools run, with
//! NumPy arrays in and out. The pure-Python half (`python/densetact/__init__.py`) adds the
//! dataset's sequence protocol and a collate function for PyTorch's `DataLoader`.
//!
//! Errors carry the command-line tools' messages (the file and the problem) as
//! `densetact.DenseTactError`; a wrong argument type is Python's `TypeError`.

use pyo3::prelude::*;

mod arrays;
mod data;
mod predictor;
mod tools;

pyo3::create_exception!(
    densetact,
    DenseTactError,
    pyo3::exceptions::PyException,
    "A densetact operation failed: the message names the file and the problem, as the command-line tools do."
);

/// `e` and its causes, one after another, as the command-line tools print them.
pub(crate) fn error(e: impl Into<anyhow::Error>) -> PyErr {
    DenseTactError::new_err(format!("{:#}", e.into()))
}

#[pymodule]
fn _densetact(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("DenseTactError", m.py().get_type::<DenseTactError>())?;
    m.add("CONTACT_THRESHOLD_MM", sensor::CONTACT_THRESHOLD_MM)?;
    m.add_class::<predictor::Predictor>()?;
    m.add_class::<predictor::Prediction>()?;
    m.add_class::<predictor::Force>()?;
    m.add_class::<data::NativeDataset>()?;
    m.add_function(wrap_pyfunction!(tools::read_frame, m)?)?;
    m.add_function(wrap_pyfunction!(tools::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(tools::label_session, m)?)?;
    m.add_function(wrap_pyfunction!(tools::set_spin_ms, m)?)?;
    Ok(())
}
