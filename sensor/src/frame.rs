//! Camera frames: the RGB images a sensor's camera records, and their PNG encoding.

/// Encodes an RGB image as PNG, with fast compression: camera frames are noisy and barely
/// compress, and a generator or a frame loop writes many.
pub fn encode_png_rgb(img: &image::RgbImage) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(img.len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Up)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .expect("in-memory PNG encode");
    out
}
