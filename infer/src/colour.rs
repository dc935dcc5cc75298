//! False-colour depth images for people.

use image::RgbImage;
use sensor::DepthMap;

/// Dark blue (no depth) through cyan, green and yellow to red (`max_mm`); pixels outside the
/// useful disk (`mask` false) are black.
pub fn false_colour(depth: &DepthMap, mask: &[bool], max_mm: f32) -> RgbImage {
    let n = depth.size_px;
    let mut img = RgbImage::new(n, n);
    for (i, px) in img.pixels_mut().enumerate() {
        if mask[i] {
            px.0 = depth_colour(depth.depth_mm[i], max_mm);
        }
    }
    img
}

/// The colour of `depth_mm` on the ramp from 0 to `max_mm` (clamped): shared by the depth
/// images and the live view's point clouds.
pub fn depth_colour(depth_mm: f32, max_mm: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] =
        [[20.0, 20.0, 90.0], [0.0, 170.0, 220.0], [40.0, 200.0, 90.0], [250.0, 220.0, 40.0], [220.0, 30.0, 30.0]];
    let t = (depth_mm / max_mm).clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let k = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - k as f32;
    std::array::from_fn(|c| (STOPS[k][c] * (1.0 - f) + STOPS[k + 1][c] * f).round() as u8)
}
