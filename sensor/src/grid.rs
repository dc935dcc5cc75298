//! Where a renderer samples the image: a regular grid in frame pixel coordinates.

use crate::Sensor;

/// A regular grid of sample points in frame pixel coordinates (pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelGrid {
    pub origin_u_px: f64,
    pub origin_v_px: f64,
    pub step_px: f64,
    pub width: u32,
    pub height: u32,
}

impl PixelGrid {
    /// The sensor's square crop, one sample per pixel.
    pub fn crop(sensor: &Sensor) -> Self {
        let (u, v) = sensor.crop_to_frame(0, 0);
        PixelGrid {
            origin_u_px: u,
            origin_v_px: v,
            step_px: 1.0,
            width: sensor.crop_size_px,
            height: sensor.crop_size_px,
        }
    }

    /// The whole camera frame with `samples`^2 samples per pixel (for antialiased images).
    pub fn frame(sensor: &Sensor, samples: u32) -> Self {
        let step = 1.0 / samples as f64;
        PixelGrid {
            origin_u_px: -0.5 + step / 2.0,
            origin_v_px: -0.5 + step / 2.0,
            step_px: step,
            width: sensor.frame_width_px * samples,
            height: sensor.frame_height_px * samples,
        }
    }

    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn point(&self, i: usize) -> (f64, f64) {
        let (x, y) = (i % self.width as usize, i / self.width as usize);
        (self.origin_u_px + x as f64 * self.step_px, self.origin_v_px + y as f64 * self.step_px)
    }
}
