//! Camera frames: decoding (PNG or JPEG, by content), the checks that keep a wrong frame from
//! giving plausible but wrong depth, the crop around the optical centre, and PNG encoding.
//!
//! Every command that takes a frame reads it here, so they all accept the same frames and
//! refuse the same ones with the same words:
//! - a damaged file refused (a truncated JPEG or PNG, a failed checksum, bytes after the image's
//!   end), an EXIF orientation applied (`crate::decode`);
//! - 8-bit RGB as it is; 16-bit RGB scaled to 8 bits; an alpha channel dropped;
//! - the camera's full frame cropped around the sensor's optical centre; the crop itself taken
//!   as it is; any other size refused with both expected sizes;
//! - a greyscale frame (or an RGB one whose three channels are equal) refused, after its size:
//!   the sensor's colours encode the direction of the surface's slope, so depth needs all three;
//! - against the unit's reference frame, a frame whose red and blue match the reference's blue
//!   and red (a BGR frame, OpenCV's order) refused with that diagnosis.

use std::path::{Path, PathBuf};

use image::RgbImage;

use crate::Sensor;
use crate::decode::Damage;

/// Why a frame cannot be used; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a readable PNG or JPEG image: {message}")]
    Decode { path: PathBuf, message: String },
    #[error(
        "{path}: the frame is greyscale ({what}); the sensor's colours encode the surface's slope, so depth \
         needs the camera's RGB frame"
    )]
    Grey { path: PathBuf, what: String },
    #[error(
        "{path}: the frame is {width}x{height} px: neither the sensor's camera frame ({frame_width}x{frame_height}) \
         nor its crop ({crop}x{crop})"
    )]
    Size { path: PathBuf, width: u32, height: u32, frame_width: u32, frame_height: u32, crop: u32 },
    #[error(
        "{path}: its red and blue channels match the unit's reference frame's blue and red ({swapped:.0} against \
         {direct:.0} grey levels rms): the frame looks BGR-ordered (OpenCV's order); convert it to RGB"
    )]
    ChannelsSwapped { path: PathBuf, direct: f64, swapped: f64 },
    #[error("{path}: the reference frame is {width}x{height} px; the sensor's crop is {crop}x{crop}")]
    ReferenceSize { path: PathBuf, width: u32, height: u32, crop: u32 },
}

/// Decodes a frame's bytes (PNG or JPEG, by content) to 8-bit RGB, refusing a damaged file
/// (`crate::decode`) and applying an EXIF orientation; `path` names it in errors. Whether the
/// frame has the sensor's size and is in colour is checked by [`crop`] and [`read_reference`],
/// size first.
pub fn decode(path: &Path, bytes: &[u8]) -> Result<RgbImage, FrameError> {
    let rgb = crate::decode::decode_rgb(bytes).map_err(|damage| match damage {
        Damage::Unreadable(message) => FrameError::Decode { path: path.to_path_buf(), message },
        Damage::Grey(what) => FrameError::Grey { path: path.to_path_buf(), what: what.to_string() },
    })?;
    if rgb.width() == 0 || rgb.height() == 0 {
        return Err(FrameError::Decode { path: path.to_path_buf(), message: "the image is empty".into() });
    }
    Ok(rgb)
}

/// Refuses an RGB frame whose three channels are equal everywhere: a greyscale picture saved as
/// RGB, from which the surface's slope cannot be read.
pub fn check_colour(path: &Path, img: &RgbImage) -> Result<(), FrameError> {
    if img.pixels().all(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2]) {
        return Err(FrameError::Grey { path: path.to_path_buf(), what: "its three channels are equal".into() });
    }
    Ok(())
}

/// Reads and decodes a frame file.
pub fn read(path: &Path) -> Result<RgbImage, FrameError> {
    let bytes = std::fs::read(path).map_err(|source| FrameError::Io { path: path.to_path_buf(), source })?;
    decode(path, &bytes)
}

/// Reads a unit's reference frame as datasets and bundles store it: exactly the `crop`-sided
/// crop (a full camera frame or any other size is an error).
pub fn read_reference(path: &Path, crop: u32) -> Result<RgbImage, FrameError> {
    let img = read(path)?;
    if img.dimensions() != (crop, crop) {
        let (width, height) = img.dimensions();
        return Err(FrameError::ReferenceSize { path: path.to_path_buf(), width, height, crop });
    }
    check_colour(path, &img)?;
    Ok(img)
}

/// The sensor's crop of `img`: cut around the optical centre from the camera's full frame, or
/// `img` itself when it already is the crop.
pub fn crop(path: &Path, img: RgbImage, sensor: &Sensor) -> Result<RgbImage, FrameError> {
    let (w, h) = img.dimensions();
    let n = sensor.crop_size_px;
    if (w, h) == (n, n) {
        check_colour(path, &img)?;
        return Ok(img);
    }
    if (w, h) == (sensor.frame_width_px, sensor.frame_height_px) {
        let (x0, y0) = sensor.crop_origin_px();
        // `Sensor::validate` keeps the crop inside the frame.
        let crop = image::imageops::crop_imm(&img, x0 as u32, y0 as u32, n, n).to_image();
        check_colour(path, &crop)?;
        return Ok(crop);
    }
    Err(FrameError::Size {
        path: path.to_path_buf(),
        width: w,
        height: h,
        frame_width: sensor.frame_width_px,
        frame_height: sensor.frame_height_px,
        crop: n,
    })
}

/// Reads a frame file and returns the sensor's crop of it.
pub fn read_crop(path: &Path, sensor: &Sensor) -> Result<RgbImage, FrameError> {
    crop(path, read(path)?, sensor)
}

/// Refuses a crop whose red and blue channels fit the reference crop's blue and red far better
/// than its own: the spatial pattern of each LED's light (red from one side, blue from another)
/// tells the channels apart even where their means are alike. Contact changes a part of the
/// frame, not which side each colour lights, so a pressed frame passes.
pub fn check_channel_order(
    path: &Path,
    crop: &RgbImage,
    reference: &RgbImage,
    mask: &[bool],
) -> Result<(), FrameError> {
    let (mut direct, mut swapped, mut n) = (0f64, 0f64, 0usize);
    for ((p, q), &useful) in crop.pixels().zip(reference.pixels()).zip(mask).step_by(3) {
        if !useful {
            continue;
        }
        let [r, _, b] = p.0.map(f64::from);
        let [rr, _, rb] = q.0.map(f64::from);
        direct += (r - rr).powi(2) + (b - rb).powi(2);
        swapped += (r - rb).powi(2) + (b - rr).powi(2);
        n += 1;
    }
    let rms = |s: f64| (s / (2 * n.max(1)) as f64).sqrt();
    let (direct, swapped) = (rms(direct), rms(swapped));
    // Swapped channels fit at least twice as well, and the frame is well off its own reference
    // (an RGB frame sits within noise and contact of it).
    if swapped < 0.5 * direct && direct > 12.0 {
        return Err(FrameError::ChannelsSwapped { path: path.to_path_buf(), direct, swapped });
    }
    Ok(())
}

/// Encodes an RGB image as PNG, with fast compression: camera frames are noisy and barely
/// compress, and a generator or a frame loop writes many.
pub fn encode_png_rgb(img: &RgbImage) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(img.len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Up)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .expect("in-memory PNG encode");
    out
}

/// Encodes an RGB image as JPEG at `quality` (1..=100), as USB cameras stream it (MJPEG).
/// Panics on a side beyond JPEG's 65535, which no sensor frame comes near.
pub fn encode_jpeg_rgb(img: &RgbImage, quality: u8) -> Vec<u8> {
    encode_jpeg_rgb_with(img, quality, Chroma::Full)
}

/// How a JPEG stores colour: one chroma sample per pixel, or one per 2x2 pixels (4:2:0, as most
/// cameras' MJPEG streams do).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chroma {
    Full,
    Sub420,
}

/// [`encode_jpeg_rgb`] with the chroma sampling chosen.
pub fn encode_jpeg_rgb_with(img: &RgbImage, quality: u8, chroma: Chroma) -> Vec<u8> {
    let mut out = Vec::with_capacity(img.len() / 8);
    let (w, h) = (u16::try_from(img.width()), u16::try_from(img.height()));
    let (Ok(w), Ok(h)) = (w, h) else { panic!("a {}x{} frame is too large for JPEG", img.width(), img.height()) };
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, quality.clamp(1, 100));
    encoder.set_sampling_factor(match chroma {
        Chroma::Full => jpeg_encoder::SamplingFactor::R_4_4_4,
        Chroma::Sub420 => jpeg_encoder::SamplingFactor::R_4_2_0,
    });
    encoder.encode(img.as_raw(), w, h, jpeg_encoder::ColorType::Rgb).expect("in-memory JPEG encode");
    out
}

#[cfg(test)]
mod tests {
    use image::DynamicImage;

    use super::*;

    fn png(img: DynamicImage) -> Vec<u8> {
        let mut out = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
        out
    }

    /// A colourful test pattern.
    fn pattern(w: u32, h: u32) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7 % 256) as u8, (y * 5 % 256) as u8, ((x + y) % 256) as u8]))
    }

    #[test]
    fn rgb_16_bit_and_alpha_frames_are_read_as_8_bit_rgb() {
        let p = Path::new("f.png");
        let rgb = pattern(20, 10);
        assert_eq!(decode(p, &png(DynamicImage::ImageRgb8(rgb.clone()))).unwrap(), rgb);
        let rgba = DynamicImage::ImageRgb8(rgb.clone()).to_rgba8();
        assert_eq!(decode(p, &png(DynamicImage::ImageRgba8(rgba))).unwrap(), rgb);
        let wide = DynamicImage::ImageRgb8(rgb.clone()).to_rgb16();
        assert_eq!(decode(p, &png(DynamicImage::ImageRgb16(wide))).unwrap(), rgb);
        // JPEG: lossy, but RGB and close.
        let jpeg = decode(Path::new("f.jpg"), &encode_jpeg_rgb(&rgb, 95)).unwrap();
        assert_eq!(jpeg.dimensions(), (20, 10));
    }

    #[test]
    fn greyscale_and_unreadable_frames_are_refused_with_the_reason() {
        let p = Path::new("cam/f.png");
        let grey = DynamicImage::ImageRgb8(pattern(8, 8)).to_luma8();
        let e = decode(p, &png(DynamicImage::ImageLuma8(grey.clone()))).unwrap_err().to_string();
        assert!(e.contains("cam/f.png") && e.contains("greyscale"), "{e}");
        let as_rgb = DynamicImage::ImageLuma8(grey).to_rgb8();
        let e = check_colour(p, &as_rgb).unwrap_err().to_string();
        assert!(e.contains("greyscale") && e.contains("equal"), "{e}");
        let e = decode(p, b"GIF89a not a frame").unwrap_err().to_string();
        assert!(e.contains("cam/f.png") && e.contains("PNG or JPEG"), "{e}");
        let e = decode(p, b"\x89PNG\r\n\x1a\nbroken").unwrap_err().to_string();
        assert!(e.contains("not a readable"), "{e}");
    }

    #[test]
    fn full_frames_are_cut_around_the_optical_centre_and_other_sizes_refused() {
        let mut sensor = Sensor::default();
        sensor.correspondence.centre_u_px = 402.3;
        sensor.correspondence.centre_v_px = 296.6;
        let frame = pattern(800, 600);
        let (x0, y0) = sensor.crop_origin_px();
        let crop = crop(Path::new("f.png"), frame.clone(), &sensor).unwrap();
        assert_eq!(crop.dimensions(), (570, 570));
        assert_eq!(crop.get_pixel(0, 0), frame.get_pixel(x0 as u32, y0 as u32));
        assert_eq!(crop.get_pixel(569, 569), frame.get_pixel(x0 as u32 + 569, y0 as u32 + 569));
        // The crop itself passes through.
        assert_eq!(super::crop(Path::new("f.png"), crop.clone(), &sensor).unwrap(), crop);
        let e = super::crop(Path::new("f.png"), pattern(640, 480), &sensor).unwrap_err().to_string();
        assert!(e.contains("640x480") && e.contains("800x600") && e.contains("570x570"), "{e}");
        // A 1x1 frame is refused for its size, not as greyscale (its one pixel's channels may
        // well be equal).
        let one = RgbImage::from_pixel(1, 1, image::Rgb([7, 7, 7]));
        let e = super::crop(Path::new("f.png"), one, &sensor).unwrap_err().to_string();
        assert!(e.contains("1x1") && e.contains("800x600") && !e.contains("greyscale"), "{e}");
    }

    /// A JPEG of a colourful frame (4:2:0, as cameras stream).
    fn jpeg(img: &RgbImage) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = jpeg_encoder::Encoder::new(&mut out, 90);
        enc.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_2_0);
        enc.encode(img.as_raw(), img.width() as u16, img.height() as u16, jpeg_encoder::ColorType::Rgb).unwrap();
        out
    }

    #[test]
    fn truncated_or_damaged_files_are_refused_not_filled_in() {
        let p = Path::new("cam/f.jpg");
        let img = pattern(96, 64);
        let good = jpeg(&img);
        assert!(decode(p, &good).is_ok());
        // Cut as a killed capture program leaves it: at several places, with and without the
        // last bytes.
        for keep in [good.len() / 20, good.len() / 2, good.len() - 2, good.len() - 1] {
            let e = decode(p, &good[..keep]).unwrap_err().to_string();
            assert!(e.contains("cam/f.jpg") && e.contains("truncated"), "cut to {keep}: {e}");
        }
        // Bytes after the end beyond the slack: two files joined.
        let mut joined = good.clone();
        joined.extend_from_slice(&good);
        let e = decode(p, &joined).unwrap_err().to_string();
        assert!(e.contains("follow"), "{e}");
        let mut padded = good.clone();
        padded.extend_from_slice(&[0u8; 16]);
        assert!(decode(p, &padded).is_ok(), "a little padding after the end is allowed");

        let p = Path::new("cam/f.png");
        let good = png(DynamicImage::ImageRgb8(img));
        assert!(decode(p, &good).is_ok());
        for keep in [40, good.len() / 2, good.len() - 12, good.len() - 1] {
            let e = decode(p, &good[..keep]).unwrap_err().to_string();
            assert!(e.contains("cam/f.png") && e.contains("truncated"), "cut to {keep}: {e}");
        }
        // A flipped bit in the pixel data: the chunk's CRC (or the zlib checksum) fails.
        let idat = good.windows(4).position(|w| w == b"IDAT").unwrap();
        let mut flipped = good.clone();
        flipped[idat + 20] ^= 0x10;
        assert!(decode(p, &flipped).is_err(), "a damaged PNG is refused");
        let mut joined = good.clone();
        joined.extend_from_slice(&good);
        assert!(decode(p, &joined).unwrap_err().to_string().contains("follow"));
    }

    /// `bytes` with an APP1 EXIF segment saying `orientation`, after the SOI marker.
    fn with_exif_orientation(bytes: &[u8], orientation: u16) -> Vec<u8> {
        let mut tiff = b"II*\0\x08\0\0\0".to_vec();
        tiff.extend_from_slice(&1u16.to_le_bytes());
        tiff.extend_from_slice(&0x0112u16.to_le_bytes());
        tiff.extend_from_slice(&3u16.to_le_bytes());
        tiff.extend_from_slice(&1u32.to_le_bytes());
        tiff.extend_from_slice(&orientation.to_le_bytes());
        tiff.extend_from_slice(&[0, 0, 0, 0, 0, 0]);
        let mut app1 = b"Exif\0\0".to_vec();
        app1.extend_from_slice(&tiff);
        let mut out = bytes[..2].to_vec();
        out.extend_from_slice(&[0xff, 0xe1]);
        out.extend_from_slice(&((app1.len() + 2) as u16).to_be_bytes());
        out.extend_from_slice(&app1);
        out.extend_from_slice(&bytes[2..]);
        out
    }

    #[test]
    fn an_exif_orientation_is_applied() {
        let p = Path::new("f.jpg");
        // Left half bright red, right half dark blue: a rotation moves them.
        let img = RgbImage::from_fn(
            64,
            32,
            |x, _| if x < 32 { image::Rgb([230, 20, 20]) } else { image::Rgb([10, 10, 120]) },
        );
        let plain = decode(p, &jpeg(&img)).unwrap();
        assert_eq!(plain.dimensions(), (64, 32));
        // Orientation 6: shown rotated 90 degrees clockwise.
        let turned = decode(p, &with_exif_orientation(&jpeg(&img), 6)).unwrap();
        assert_eq!(turned.dimensions(), (32, 64), "rotated by the EXIF orientation");
        assert!(turned.get_pixel(16, 8).0[0] > 150 && turned.get_pixel(16, 56).0[2] > 80, "red on top after the turn");
        // Orientation 1 changes nothing.
        assert_eq!(decode(p, &with_exif_orientation(&jpeg(&img), 1)).unwrap(), plain);
    }
}
