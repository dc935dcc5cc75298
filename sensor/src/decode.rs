//! Strict decoding of camera frames: a frame is whole or refused.
//!
//! General-purpose decoders fill what a damaged file lacks (a JPEG cut by a killed capture
//! program decodes with its missing rows grey; a PNG's zlib checksum goes unchecked). A frame
//! that is partly invented gives plausible but wrong depth, so here:
//! - a PNG must pass every chunk CRC and the zlib stream's Adler-32, and end with IEND;
//! - a JPEG is decoded in the decoder's strict mode (a scan that runs out of data or meets an
//!   unexpected marker is an error) and must end with its end-of-image marker;
//! - at most [`TRAILING_SLACK_BYTES`] may follow the image's end (padding some writers add);
//! - an EXIF orientation (JPEG APP1, PNG eXIf) is applied, so the pixels are as the camera meant.

use std::io::Cursor;

use image::metadata::Orientation;
use image::{DynamicImage, RgbImage};

/// Bytes allowed after a PNG's IEND chunk or a JPEG's end-of-image marker.
pub const TRAILING_SLACK_BYTES: usize = 64;

/// What is wrong with a frame's bytes, in words that end a `path: ...` message.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Damage {
    /// Not PNG or JPEG, or broken beyond reading: the decoder's words.
    Unreadable(String),
    /// A one-channel (or one channel and alpha) image.
    Grey(&'static str),
}

/// The pixels of a PNG or JPEG frame (by content) as 8-bit RGB, with its orientation applied.
pub(crate) fn decode_rgb(bytes: &[u8]) -> Result<RgbImage, Damage> {
    let unreadable = |m: String| Damage::Unreadable(m);
    let (img, orientation) = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(bytes)?
    } else if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
        decode_jpeg(bytes)?
    } else {
        let what = image::guess_format(bytes).map_or_else(|_| "an unknown format".to_string(), |f| format!("{f:?}"));
        return Err(unreadable(format!("{what} files are not read; save the frame as PNG or JPEG")));
    };
    let mut img = img;
    if let Some(o) = orientation
        && o != Orientation::NoTransforms
    {
        img.apply_orientation(o);
    }
    match img {
        DynamicImage::ImageLuma8(_) | DynamicImage::ImageLuma16(_) => Err(Damage::Grey("one channel")),
        DynamicImage::ImageLumaA8(_) | DynamicImage::ImageLumaA16(_) => Err(Damage::Grey("one channel and alpha")),
        DynamicImage::ImageRgb8(rgb) => Ok(rgb),
        other => Ok(other.to_rgb8()),
    }
}

fn decode_png(bytes: &[u8]) -> Result<(DynamicImage, Option<Orientation>), Damage> {
    let end = png_end(bytes)?;
    trailing(bytes.len() - end, "the PNG's IEND chunk")?;
    let bad = |e: png::DecodingError| Damage::Unreadable(format!("PNG: {e}"));
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    decoder.ignore_checksums(false);
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(bad)?;
    let (w, h) = (reader.info().width, reader.info().height);
    if w.max(h) > crate::MAX_FRAME_SIDE_PX {
        return Err(Damage::Unreadable(format!("PNG: {w}x{h} px is larger than any camera frame")));
    }
    let size = reader.output_buffer_size().ok_or_else(|| Damage::Unreadable("PNG: image too large".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    // Everything after the pixels too: later chunks' CRCs and the end of the zlib stream.
    reader.finish().map_err(bad)?;
    buf.truncate(info.buffer_size());
    let orientation = reader.info().exif_metadata.as_deref().and_then(Orientation::from_exif_chunk);
    let (w, h) = (info.width, info.height);
    let sixteen = info.bit_depth == png::BitDepth::Sixteen;
    let wide = |buf: &[u8]| buf.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect::<Vec<u16>>();
    let short = || Damage::Unreadable("PNG: pixel data shorter than the image".into());
    let img = match (info.color_type, sixteen) {
        (png::ColorType::Grayscale, false) => {
            DynamicImage::ImageLuma8(image::GrayImage::from_raw(w, h, buf).ok_or_else(short)?)
        }
        (png::ColorType::Grayscale, true) => {
            DynamicImage::ImageLuma16(image::ImageBuffer::from_raw(w, h, wide(&buf)).ok_or_else(short)?)
        }
        (png::ColorType::GrayscaleAlpha, false) => {
            DynamicImage::ImageLumaA8(image::ImageBuffer::from_raw(w, h, buf).ok_or_else(short)?)
        }
        (png::ColorType::GrayscaleAlpha, true) => {
            DynamicImage::ImageLumaA16(image::ImageBuffer::from_raw(w, h, wide(&buf)).ok_or_else(short)?)
        }
        (png::ColorType::Rgb, false) => DynamicImage::ImageRgb8(RgbImage::from_raw(w, h, buf).ok_or_else(short)?),
        (png::ColorType::Rgb, true) => {
            DynamicImage::ImageRgb16(image::ImageBuffer::from_raw(w, h, wide(&buf)).ok_or_else(short)?)
        }
        (png::ColorType::Rgba, false) => {
            DynamicImage::ImageRgba8(image::ImageBuffer::from_raw(w, h, buf).ok_or_else(short)?)
        }
        (png::ColorType::Rgba, true) => {
            DynamicImage::ImageRgba16(image::ImageBuffer::from_raw(w, h, wide(&buf)).ok_or_else(short)?)
        }
        (png::ColorType::Indexed, _) => return Err(Damage::Unreadable("PNG: palette left unexpanded".into())),
    };
    Ok((img, orientation))
}

/// Offset just past a PNG's IEND chunk, walking the chunk lengths (their CRCs are the
/// decoder's to check).
fn png_end(bytes: &[u8]) -> Result<usize, Damage> {
    let mut at = 8;
    loop {
        let Some(head) = bytes.get(at..at + 8) else {
            return Err(Damage::Unreadable(
                "PNG: the file ends before its IEND chunk (truncated: cut while it was written or copied?)".into(),
            ));
        };
        let len = u32::from_be_bytes([head[0], head[1], head[2], head[3]]) as usize;
        let next = at + 12 + len;
        if &head[4..8] == b"IEND" {
            return if next <= bytes.len() {
                Ok(next)
            } else {
                Err(Damage::Unreadable("PNG: the file ends inside its IEND chunk (truncated)".into()))
            };
        }
        if next > bytes.len() {
            let name = String::from_utf8_lossy(&head[4..8]).into_owned();
            return Err(Damage::Unreadable(format!(
                "PNG: the file ends inside its {name} chunk at byte {} of {} (truncated: cut while it was written \
                 or copied?)",
                bytes.len(),
                next
            )));
        }
        at = next;
    }
}

fn trailing(extra: usize, end: &str) -> Result<(), Damage> {
    if extra > TRAILING_SLACK_BYTES {
        return Err(Damage::Unreadable(format!(
            "{extra} bytes follow {end} (at most {TRAILING_SLACK_BYTES} are allowed): two files joined, or a \
             damaged one"
        )));
    }
    Ok(())
}

/// Offset just past a JPEG's end-of-image marker, walking its segments (each with its length)
/// and its scans' entropy-coded data (where `FF` is followed by `00` or a restart marker) to the
/// marker that ends them.
fn jpeg_end(bytes: &[u8]) -> Result<usize, Damage> {
    let truncated =
        || Damage::Unreadable("JPEG: no end-of-image marker (truncated: cut while it was written or copied?)".into());
    let mut at = 2;
    loop {
        // Fill bytes (FF) may precede a marker.
        while bytes.get(at) == Some(&0xff) && bytes.get(at + 1) == Some(&0xff) {
            at += 1;
        }
        let (Some(&0xff), Some(&marker)) = (bytes.get(at), bytes.get(at + 1)) else {
            return Err(if at + 1 >= bytes.len() {
                truncated()
            } else {
                Damage::Unreadable(format!("JPEG: no marker at byte {at} where a segment should begin"))
            });
        };
        at += 2;
        match marker {
            0xd9 => return Ok(at),
            0x01 | 0xd0..=0xd7 => continue,
            _ => {}
        }
        let len = match (bytes.get(at), bytes.get(at + 1)) {
            (Some(&h), Some(&l)) => u16::from_be_bytes([h, l]) as usize,
            _ => return Err(truncated()),
        };
        at += len;
        if at > bytes.len() {
            return Err(truncated());
        }
        if marker == 0xda {
            // Entropy-coded data up to the next marker that is not a stuffed byte or a restart.
            loop {
                let Some(ff) = bytes[at..].iter().position(|&b| b == 0xff) else { return Err(truncated()) };
                at += ff;
                match bytes.get(at + 1) {
                    None => return Err(truncated()),
                    Some(0x00) | Some(0xd0..=0xd7) | Some(0xff) => at += 1,
                    Some(_) => break,
                }
            }
        }
    }
}

fn decode_jpeg(bytes: &[u8]) -> Result<(DynamicImage, Option<Orientation>), Damage> {
    let end = jpeg_end(bytes)?;
    trailing(bytes.len() - end, "the JPEG's end-of-image marker")?;
    let options = zune_core::options::DecoderOptions::default()
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(zune_core::colorspace::ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(zune_core::bytestream::ZCursor::new(bytes), options);
    let bad = |e: zune_jpeg::errors::DecodeErrors| Damage::Unreadable(format!("JPEG: {e}"));
    decoder.decode_headers().map_err(bad)?;
    let grey = matches!(decoder.input_colorspace(), Some(zune_core::colorspace::ColorSpace::Luma));
    let orientation = decoder.exif().and_then(|e| Orientation::from_exif_chunk(e));
    let (w, h) = decoder.dimensions().ok_or_else(|| Damage::Unreadable("JPEG: no frame header".into()))?;
    if w.max(h) > crate::MAX_FRAME_SIDE_PX as usize {
        return Err(Damage::Unreadable(format!("JPEG: {w}x{h} px is larger than any camera frame")));
    }
    let pixels = decoder.decode().map_err(bad)?;
    if grey {
        return Err(Damage::Grey("one channel"));
    }
    let img = RgbImage::from_raw(w as u32, h as u32, pixels)
        .ok_or_else(|| Damage::Unreadable("JPEG: pixel data shorter than the image".into()))?;
    Ok((DynamicImage::ImageRgb8(img), orientation))
}
