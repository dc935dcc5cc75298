//! Frames and maps between NumPy and the crates: HxWx3 uint8 RGB arrays in, owned arrays out
//! (each map's buffer handed to NumPy, not copied).

use std::path::PathBuf;

use image::RgbImage;
use numpy::ndarray::{Array2, Array3};
use numpy::{Element, PyArray2, PyArray3, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;

/// A frame as a caller gives it: a file (read as the command-line tools read it) or pixels.
pub(crate) enum FrameArg {
    File(PathBuf),
    Pixels(RgbImage),
}

/// `obj` as a frame: `str` or `os.PathLike`, or an HxWx3 `uint8` array in RGB order (any
/// strides). `what` names it in errors.
pub(crate) fn frame_arg(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<FrameArg> {
    if let Ok(path) = obj.extract::<PathBuf>() {
        return Ok(FrameArg::File(path));
    }
    let Ok(array) = obj.extract::<PyReadonlyArray3<'_, u8>>() else {
        return Err(PyTypeError::new_err(format!(
            "{what} must be a path or an HxWx3 uint8 RGB array, got {}",
            describe(obj)
        )));
    };
    let [h, w, c] = [0, 1, 2].map(|k| array.shape()[k]);
    if c != 3 {
        return Err(PyTypeError::new_err(format!("{what} must be HxWx3 (RGB), got shape ({h}, {w}, {c})")));
    }
    let pixels = match array.as_slice() {
        Ok(contiguous) => contiguous.to_vec(),
        Err(_) => array.as_array().iter().copied().collect(),
    };
    let image = RgbImage::from_raw(w as u32, h as u32, pixels).expect("h x w x 3 bytes make an RGB image");
    Ok(FrameArg::Pixels(image))
}

/// What `obj` is, for an error: an array's dtype and shape, else its type.
fn describe(obj: &Bound<'_, PyAny>) -> String {
    match (obj.getattr("dtype"), obj.getattr("shape")) {
        (Ok(dtype), Ok(shape)) => format!("an array of {dtype} with shape {shape}"),
        _ => obj.get_type().name().map_or_else(|_| "an object".into(), |n| format!("a {n}")),
    }
}

/// `values` (row-major) as an `h` x `w` array; NumPy takes the buffer as it is.
pub(crate) fn plane<'py, T: Element>(py: Python<'py>, values: Vec<T>, [h, w]: [usize; 2]) -> Bound<'py, PyArray2<T>> {
    let array = Array2::from_shape_vec((h, w), values).expect("a plane of h x w values");
    PyArray2::from_owned_array(py, array)
}

/// An RGB image as an HxWx3 uint8 array.
pub(crate) fn rgb<'py>(py: Python<'py>, image: RgbImage) -> Bound<'py, PyArray3<u8>> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let array = Array3::from_shape_vec((h, w, 3), image.into_raw()).expect("an RGB image holds h x w x 3 bytes");
    PyArray3::from_owned_array(py, array)
}
