//! Depth maps on the crop's pixel grid, and their lossless 16-bit PNG encoding.

use std::path::Path;

use image::{ImageBuffer, Luma};

use crate::SensorError;

/// Depth (mm, how far the surface is pressed in along each pixel's ray) on the square crop,
/// row-major. Pixels outside the useful disk hold 0.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    pub size_px: u32,
    pub depth_mm: Vec<f32>,
}

/// Depth above which a pixel counts as in contact (mm): well above the PNG's 1 um step and the
/// ray caster's error, well below the 0.11 mm uncertainty of 3D-printed ground truth. Shared by
/// the dataset's statistics, evaluation and inference.
pub const CONTACT_THRESHOLD_MM: f32 = 0.02;

/// One step of the 16-bit PNG encoding: a micrometre (so 65.535 mm is the largest depth).
pub const PNG_UM_PER_STEP: f32 = 1.0;

/// Steps of the 16-bit depth encoding per millimetre.
pub const DEPTH_STEPS_PER_MM: f32 = 1000.0 / PNG_UM_PER_STEP;

/// Depth (mm) as a step of the 16-bit encoding (rounded, clamped to 0..65535): the depth PNG's,
/// and the live view's.
pub fn depth_step(depth_mm: f32) -> u16 {
    ((depth_mm * DEPTH_STEPS_PER_MM).clamp(0.0, 65535.0) + 0.5) as u16
}

/// The depth (mm) a step of the 16-bit encoding stands for.
pub fn step_depth_mm(step: u16) -> f32 {
    step as f32 * PNG_UM_PER_STEP / 1000.0
}

impl DepthMap {
    pub fn zeros(size_px: u32) -> Self {
        DepthMap { size_px, depth_mm: vec![0.0; (size_px as usize).pow(2)] }
    }

    /// Pixels pressed deeper than `threshold_mm` (row-major).
    pub fn contact_px(&self, threshold_mm: f32) -> Vec<bool> {
        self.depth_mm.iter().map(|&d| d > threshold_mm).collect()
    }

    pub fn max_mm(&self) -> f32 {
        self.depth_mm.iter().copied().fold(0.0, f32::max)
    }

    /// Encodes as 16-bit grey PNG in micrometres (rounded): lossless at 0.5 um.
    pub fn to_png_um(&self) -> Vec<u8> {
        let px: Vec<u16> = self.depth_mm.iter().map(|&d| depth_step(d)).collect();
        encode_png(self.size_px, px)
    }

    /// Float32 depth (mm) as NumPy's `.npy` file, shape (size, size): exact, and one
    /// `numpy.load` away for Python users.
    pub fn to_npy(&self) -> Vec<u8> {
        let n = self.size_px as usize;
        npy_f32(&[n, n], &self.depth_mm)
    }

    /// The paper's 8-bit encoding: 0..255 spans 0..`max_depth_mm` (about 0.037 mm a step).
    pub fn to_png_u8(&self, max_depth_mm: f32) -> Vec<u8> {
        let px: Vec<u8> =
            self.depth_mm.iter().map(|&d| ((d / max_depth_mm * 255.0).clamp(0.0, 255.0) + 0.5) as u8).collect();
        encode_png(self.size_px, px)
    }

    /// Reads a 16-bit micrometre PNG; the error names the file and what is wrong with it.
    pub fn load_png_um(path: &Path) -> Result<Self, SensorError> {
        let bytes = std::fs::read(path).map_err(|e| SensorError::io(path, e))?;
        Self::decode_png_um(path, &bytes)
    }

    /// Decodes a 16-bit micrometre PNG's bytes; `path` names it in errors.
    pub fn decode_png_um(path: &Path, bytes: &[u8]) -> Result<Self, SensorError> {
        let (size_px, raw) = decode_square_u16(path, bytes, "depth")?;
        let depth_mm = raw.into_iter().map(step_depth_mm).collect();
        Ok(DepthMap { size_px, depth_mm })
    }
}

/// `values` as a little-endian float32 NumPy array file (format 1.0) of `shape`, row-major.
pub fn npy_f32(shape: &[usize], values: &[f32]) -> Vec<u8> {
    assert_eq!(shape.iter().product::<usize>(), values.len(), "npy shape and data disagree");
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    // The magic, version and length take 10 bytes; the header ends in a newline and pads the
    // whole preamble to a multiple of 64 bytes, as NumPy writes it.
    let used = 10 + header.len() + 1;
    header.extend(std::iter::repeat_n(' ', used.next_multiple_of(64) - used));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + 4 * values.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out
}

/// Contact pressure (kPa) on the crop's pixel grid, row-major: what the elastomer's contact
/// model puts under each pixel's point of the dome. Pixels off contact hold 0.
#[derive(Clone, Debug, PartialEq)]
pub struct PressureMap {
    pub size_px: u32,
    pub pressure_kpa: Vec<f32>,
}

/// One step of the pressure PNG's 16-bit encoding (kPa): 6553.5 kPa at most, far above what a
/// 0.3 MPa silicone bears before it tears.
pub const PNG_KPA_PER_STEP: f32 = 0.1;

impl PressureMap {
    /// 16-bit grey PNG, [`PNG_KPA_PER_STEP`] a level, rounded to the nearest.
    pub fn to_png(&self) -> Vec<u8> {
        let px: Vec<u16> =
            self.pressure_kpa.iter().map(|&p| ((p / PNG_KPA_PER_STEP).clamp(0.0, 65535.0) + 0.5) as u16).collect();
        encode_png(self.size_px, px)
    }

    /// Reads a pressure PNG; the error names the file and what is wrong with it.
    pub fn load_png(path: &Path) -> Result<Self, SensorError> {
        let bytes = std::fs::read(path).map_err(|e| SensorError::io(path, e))?;
        let (size_px, raw) = decode_square_u16(path, &bytes, "pressure")?;
        Ok(PressureMap { size_px, pressure_kpa: raw.into_iter().map(|v| v as f32 * PNG_KPA_PER_STEP).collect() })
    }
}

/// A square 16-bit grey PNG's side and levels; `what` names the map in errors.
fn decode_square_u16(path: &Path, bytes: &[u8], what: &str) -> Result<(u32, Vec<u16>), SensorError> {
    let bad = |message: String| SensorError::InFile { path: path.to_path_buf(), message };
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| bad(format!("not a readable PNG: {e}")))?;
    let image::DynamicImage::ImageLuma16(img) = img else {
        return Err(bad(format!("expected a 16-bit greyscale {what} PNG, got {:?}", img.color())));
    };
    if img.width() != img.height() {
        return Err(bad(format!("{what} map must be square, got {}x{}", img.width(), img.height())));
    }
    Ok((img.width(), img.into_raw()))
}

/// A square grey image as PNG bytes, in memory. Fast deflate with the `Up` filter: lossless like
/// every PNG, a few percent larger than the default level and several times quicker to write.
fn encode_png<P: image::Primitive>(size_px: u32, px: Vec<P>) -> Vec<u8>
where
    Luma<P>: image::Pixel<Subpixel = P> + image::PixelWithColorType,
    [P]: image::EncodableLayout,
{
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let img: ImageBuffer<Luma<P>, Vec<P>> = ImageBuffer::from_raw(size_px, size_px, px).expect("square buffer");
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Up)
        .write_image(
            image::EncodableLayout::as_bytes(img.as_raw().as_slice()),
            size_px,
            size_px,
            <Luma<P> as image::PixelWithColorType>::COLOR_TYPE,
        )
        .expect("in-memory PNG encode");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_files_have_numpys_preamble_and_the_values_row_major() {
        let d = DepthMap { size_px: 3, depth_mm: (0..9).map(|k| k as f32 * 0.25 - 1.0).collect() };
        let bytes = d.to_npy();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        let data = 10 + header_len;
        assert_eq!(data % 64, 0, "NumPy aligns the data to 64 bytes");
        let header = std::str::from_utf8(&bytes[10..data]).unwrap();
        assert!(header.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (3, 3), }"), "{header}");
        assert!(header.ends_with('\n'));
        let values: Vec<f32> =
            bytes[data..].chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        assert_eq!(values, d.depth_mm);
        let one = npy_f32(&[2], &[1.0, 2.0]);
        assert!(std::str::from_utf8(&one[10..64]).unwrap().contains("'shape': (2,)"));
    }

    #[test]
    fn png_round_trip_within_half_a_micrometre() {
        let mut d = DepthMap::zeros(37);
        for (i, v) in d.depth_mm.iter_mut().enumerate() {
            *v = (i as f32 * 0.0137) % 9.4;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        std::fs::write(&path, d.to_png_um()).unwrap();
        let back = DepthMap::load_png_um(&path).unwrap();
        assert_eq!(back.size_px, 37);
        for (a, b) in d.depth_mm.iter().zip(&back.depth_mm) {
            assert!((a - b).abs() <= 0.0005 + 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn pressure_round_trips_within_half_a_step_and_is_not_read_as_depth_colours() {
        let mut p = PressureMap { size_px: 23, pressure_kpa: vec![0.0; 23 * 23] };
        for (i, v) in p.pressure_kpa.iter_mut().enumerate() {
            *v = (i as f32 * 1.37) % 900.0;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        std::fs::write(&path, p.to_png()).unwrap();
        let back = PressureMap::load_png(&path).unwrap();
        assert_eq!(back.size_px, 23);
        for (a, b) in p.pressure_kpa.iter().zip(&back.pressure_kpa) {
            assert!((a - b).abs() <= PNG_KPA_PER_STEP / 2.0 + 1e-3, "{a} vs {b}");
        }
        // An 8-bit map is refused, naming the file and the map.
        std::fs::write(&path, DepthMap::zeros(5).to_png_u8(1.0)).unwrap();
        let err = PressureMap::load_png(&path).unwrap_err().to_string();
        assert!(err.contains("p.png") && err.contains("16-bit greyscale pressure"), "{err}");
    }

    #[test]
    fn bad_png_is_a_named_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("broken.png");
        std::fs::write(&path, b"\x89PNG\r\n\x1a\nnonsense").unwrap();
        let e = DepthMap::load_png_um(&path).unwrap_err().to_string();
        assert!(e.contains("broken.png"), "{e}");
        let eight = DepthMap::zeros(4).to_png_u8(9.4);
        std::fs::write(&path, eight).unwrap();
        let e = DepthMap::load_png_um(&path).unwrap_err().to_string();
        assert!(e.contains("16-bit"), "{e}");
    }
}
