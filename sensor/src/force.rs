//! A pressure map's resultant: the force and torque that contact pressure on the crop's pixels
//! applies to the sensor. The labeller sums its solved nodes; a network's pressure output is
//! summed here, pixel by pixel, so that `infer` needs nothing of the generator.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::Sensor;

/// Force (N) and torque (N mm, about the dome's centre) that a contact applies to the sensor, in
/// the sensor frame (z along the dome's axis, out of the dome).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
}

impl Wrench {
    /// The force's magnitude (N): the total normal force of a frictionless contact.
    pub fn force_magnitude_n(&self) -> f64 {
        DVec3::from_array(self.force_n).length()
    }

    /// |F - F_other| (N).
    pub fn force_distance_n(&self, other: &Wrench) -> f64 {
        (DVec3::from_array(self.force_n) - DVec3::from_array(other.force_n)).length()
    }
}

/// kPa times mm² in newtons.
const N_PER_KPA_MM2: f64 = 1e-3;

/// Each useful crop pixel's dome point (unit outward direction) and the dome area it sees
/// (mm²), computed once per sensor.
#[derive(Clone, Debug)]
pub struct DomeAreas {
    radius_mm: f64,
    side_px: usize,
    /// Useful pixels: crop index, outward unit normal, area seen (mm²).
    pixels: Vec<(u32, DVec3, f64)>,
}

impl DomeAreas {
    pub fn new(sensor: &Sensor) -> Self {
        let c = &sensor.correspondence;
        let dir = |u: f64, v: f64| c.direction(u, v).map(|(d, _)| d);
        // The derivative of the direction along one frame axis: central where both sides are
        // seen, one-sided at the lens model's edge.
        let slope = |u: f64, v: f64, du: f64, dv: f64| -> Option<DVec3> {
            let h = 0.5;
            match (dir(u + h * du, v + h * dv), dir(u - h * du, v - h * dv)) {
                (Some(a), Some(b)) => Some((a - b) / (2.0 * h)),
                (Some(a), None) => Some(a - dir(u, v)?).map(|d| d / h),
                (None, Some(b)) => Some(dir(u, v)? - b).map(|d| d / h),
                (None, None) => None,
            }
        };
        let r2 = sensor.radius_mm * sensor.radius_mm;
        let pixels = sensor
            .pixel_rays()
            .into_iter()
            .filter_map(|ray| {
                let n = sensor.crop_size_px;
                let (u, v) = sensor.crop_to_frame(ray.index % n, ray.index / n);
                let area = slope(u, v, 1.0, 0.0)?.cross(slope(u, v, 0.0, 1.0)?).length() * r2;
                Some((ray.index, ray.dir.as_dvec3().normalize(), area))
            })
            .collect();
        DomeAreas { radius_mm: sensor.radius_mm, side_px: sensor.crop_size_px as usize, pixels }
    }

    /// Per pixel of a `[h, w]` grid laid over the crop (each takes the crop pixels whose centres
    /// fall in it): the force (N) that 1 kPa on it applies, x, y and z planes one after another.
    /// The resultant of a pressure map on that grid is then a weighted sum, which a training
    /// loss can differentiate.
    pub fn force_per_kpa(&self, [h, w]: [usize; 2]) -> Vec<f32> {
        let mut out = vec![0f64; 3 * h * w];
        let n = self.side_px;
        for &(i, normal, area) in &self.pixels {
            let (x, y) = (i as usize % n, i as usize / n);
            let (ox, oy) = (((x * 2 + 1) * w / (2 * n)).min(w - 1), ((y * 2 + 1) * h / (2 * n)).min(h - 1));
            let push = -normal * (area * N_PER_KPA_MM2);
            for (c, v) in push.to_array().into_iter().enumerate() {
                out[c * h * w + oy * w + ox] += v;
            }
        }
        out.into_iter().map(|v| v as f32).collect()
    }

    /// The dome area the useful pixels see (mm²).
    pub fn total_area_mm2(&self) -> f64 {
        self.pixels.iter().map(|p| p.2).sum()
    }

    /// The resultant of `pressure_kpa` (row-major crop; negative values read as none: contact
    /// cannot pull). Pressure pushes the dome inward, along minus its outward normal.
    pub fn wrench(&self, pressure_kpa: &[f32]) -> Wrench {
        assert_eq!(pressure_kpa.len(), self.side_px * self.side_px, "the pressure map is on the crop");
        let (mut force, mut torque) = (DVec3::ZERO, DVec3::ZERO);
        for &(i, normal, area) in &self.pixels {
            let p = pressure_kpa[i as usize] as f64;
            if p > 0.0 {
                let push = -normal * (p * area * N_PER_KPA_MM2);
                force += push;
                torque += (normal * self.radius_mm).cross(push);
            }
        }
        Wrench { force_n: force.to_array(), torque_nmm: torque.to_array() }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pixels see the dome's cap up to the useful angle: 2 pi R^2 (1 - cos(theta_max)).
    #[test]
    fn the_pixels_tile_the_visible_cap() {
        let sensor = Sensor::default();
        let areas = DomeAreas::new(&sensor);
        let r = sensor.radius_mm;
        let cap = 2.0 * std::f64::consts::PI * r * r * (1.0 - sensor.max_theta_rad.cos());
        let got = areas.total_area_mm2();
        // The disk's pixelated edge: about half a pixel ring of the cap's rim.
        assert!((got - cap).abs() / cap < 0.01, "{got} vs {cap} mm²");
    }

    /// A uniform pressure on the whole visible cap pushes straight down the axis with
    /// p * (the cap's area projected on the base plane) = p pi (R sin theta_max)^2, and no torque.
    #[test]
    fn uniform_pressure_on_the_cap_gives_its_projected_area() {
        let sensor = Sensor::default();
        let areas = DomeAreas::new(&sensor);
        let p_kpa = 50.0f32;
        let w = areas.wrench(&vec![p_kpa; sensor.crop_len()]);
        let r_base = sensor.radius_mm * sensor.max_theta_rad.sin();
        let want = p_kpa as f64 * std::f64::consts::PI * r_base * r_base * 1e-3;
        assert!((w.force_n[2] + want).abs() / want < 0.01, "{:?} vs -{want} N", w.force_n);
        assert!(w.force_n[0].abs() < 1e-3 * want && w.force_n[1].abs() < 1e-3 * want, "{:?}", w.force_n);
        assert!(w.torque_nmm.iter().all(|t| t.abs() < 1e-9 * want), "{:?}", w.torque_nmm);
        assert!((w.force_magnitude_n() - want).abs() / want < 0.01);
        // The same on a coarser grid, as a weighted sum.
        let per_kpa = areas.force_per_kpa([40, 30]);
        let fz: f64 = per_kpa[2 * 1200..].iter().map(|&v| v as f64 * p_kpa as f64).sum();
        assert!((fz - w.force_n[2]).abs() <= 1e-4 * want, "{fz} against {}", w.force_n[2]);
        // Pulling is no contact.
        assert_eq!(areas.wrench(&vec![-p_kpa; sensor.crop_len()]), Wrench::default());
    }
}
