//! The fisheye correspondence between camera pixels and ray directions.
//!
//! The sensor's camera sits at the centre of the hemisphere behind a circular fisheye. Its
//! distortion is radially symmetric about the optical centre `(u_c, v_c)`: a pixel at image radius
//! `r` (pixels) and azimuth `phi` sees the direction at polar angle `theta(r)` from the sensor axis
//! and the same azimuth. The paper writes the radial map as `r -> R * sin(theta)`; we keep `theta`
//! itself as the primary quantity (it stays invertible past 90 degrees) and derive `R * sin(theta)`
//! where a caller wants it.
//!
//! Sensor frame: origin at the sphere's centre, `x` along image `u` (right), `y` along image `v`
//! (down), `z` along the optical axis towards the top of the dome. Right-handed.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::SensorError;

/// Monotone map between image radius (pixels) and polar angle `theta` (radians).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum RadialMap {
    /// `r = f * theta`: the ideal fisheye.
    Equidistant { focal_px_per_rad: f64 },
    /// Kannala-Brandt: `r = f * (theta + k1 theta^3 + k2 theta^5 + k3 theta^7 + k4 theta^9)`.
    /// Models the spread of real lenses; simulated units vary `f` and `k`.
    KannalaBrandt { focal_px_per_rad: f64, k: [f64; 4] },
    /// Piecewise-linear table, strictly increasing in both columns; starts at (0, 0).
    /// What a calibration exports.
    Tabulated { radius_px: Vec<f64>, theta_rad: Vec<f64> },
}

impl RadialMap {
    /// Polar angle (radians) seen at image radius `r_px`. `None` where the map is undefined
    /// (negative radius, beyond a table's last entry, or a non-monotone polynomial region).
    pub fn theta_of_radius(&self, r_px: f64) -> Option<f64> {
        if !(r_px >= 0.0) {
            return None;
        }
        match self {
            RadialMap::Equidistant { focal_px_per_rad } => Some(r_px / focal_px_per_rad),
            RadialMap::KannalaBrandt { .. } => self.invert_polynomial(r_px),
            RadialMap::Tabulated { radius_px, theta_rad } => interpolate(radius_px, theta_rad, r_px),
        }
    }

    /// Image radius (pixels) at which polar angle `theta_rad` is seen.
    pub fn radius_of_theta(&self, theta_rad: f64) -> Option<f64> {
        if !(theta_rad >= 0.0) {
            return None;
        }
        match self {
            RadialMap::Equidistant { focal_px_per_rad } => Some(theta_rad * focal_px_per_rad),
            RadialMap::KannalaBrandt { focal_px_per_rad, k } => Some(focal_px_per_rad * kb_poly(k, theta_rad)),
            RadialMap::Tabulated { radius_px, theta_rad: th } => interpolate(th, radius_px, theta_rad),
        }
    }

    /// Newton iteration on the Kannala-Brandt polynomial, started from the equidistant guess.
    fn invert_polynomial(&self, r_px: f64) -> Option<f64> {
        let RadialMap::KannalaBrandt { focal_px_per_rad: f, k } = self else {
            return None;
        };
        let target = r_px / f;
        let mut theta = target;
        for _ in 0..50 {
            let err = kb_poly(k, theta) - target;
            let slope = kb_slope(k, theta);
            if !(slope > 0.0) {
                return None;
            }
            let step = err / slope;
            theta -= step;
            if step.abs() < 1e-14 {
                break;
            }
        }
        ((kb_poly(k, theta) - target).abs() < 1e-9 && theta >= 0.0).then_some(theta)
    }

    /// Checks that the map is finite and strictly increasing on `[0, r_max_px]`.
    pub fn validate(&self, r_max_px: f64) -> Result<(), SensorError> {
        let bad = |why: String| Err(SensorError::Invalid(format!("radial map: {why}")));
        match self {
            RadialMap::Equidistant { focal_px_per_rad: f } | RadialMap::KannalaBrandt { focal_px_per_rad: f, .. }
                if !(f.is_finite() && *f > 0.0) =>
            {
                return bad(format!("focal length must be a positive number of px/rad, got {f}"));
            }
            RadialMap::KannalaBrandt { k, .. } if k.iter().any(|c| !c.is_finite()) => {
                return bad(format!("coefficients must be finite, got {k:?}"));
            }
            RadialMap::Tabulated { radius_px, theta_rad } => {
                if radius_px.len() != theta_rad.len() || radius_px.len() < 2 {
                    return bad(format!(
                        "table needs two columns of equal length >= 2, got {} and {}",
                        radius_px.len(),
                        theta_rad.len()
                    ));
                }
                if radius_px[0] != 0.0 || theta_rad[0] != 0.0 {
                    return bad("table must start at radius 0, theta 0 (the optical axis)".into());
                }
                for w in 0..radius_px.len() - 1 {
                    let ok = radius_px[w + 1] > radius_px[w] && theta_rad[w + 1] > theta_rad[w];
                    if !ok || !radius_px[w + 1].is_finite() || !theta_rad[w + 1].is_finite() {
                        return bad(format!("table is not strictly increasing at row {}", w + 1));
                    }
                }
                if *radius_px.last().unwrap() < r_max_px {
                    return bad(format!(
                        "table ends at radius {} px but the crop reaches {r_max_px:.1} px",
                        radius_px.last().unwrap()
                    ));
                }
            }
            _ => {}
        }
        if let RadialMap::KannalaBrandt { k, .. } = self {
            // Monotone where used: the slope stays positive up to the crop's corner.
            let theta_end = self.theta_of_radius(r_max_px);
            let Some(theta_end) = theta_end else {
                return bad(format!("polynomial is not invertible up to radius {r_max_px:.1} px"));
            };
            let steps = 256;
            for i in 0..=steps {
                let t = theta_end * i as f64 / steps as f64;
                if !(kb_slope(k, t) > 0.0) {
                    return bad(format!("polynomial is not monotone at theta = {t:.4} rad"));
                }
            }
        }
        Ok(())
    }
}

fn kb_poly(k: &[f64; 4], t: f64) -> f64 {
    let t2 = t * t;
    t * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
}

fn kb_slope(k: &[f64; 4], t: f64) -> f64 {
    let t2 = t * t;
    1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
}

/// Linear interpolation in a strictly increasing table `xs -> ys`; `None` beyond its ends.
fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> Option<f64> {
    let last = *xs.last()?;
    if x < xs[0] || x > last {
        return None;
    }
    let i = xs.partition_point(|&v| v <= x).clamp(1, xs.len() - 1);
    let (x0, x1, y0, y1) = (xs[i - 1], xs[i], ys[i - 1], ys[i]);
    Some(y0 + (y1 - y0) * (x - x0) / (x1 - x0))
}

/// Pixel <-> direction correspondence in full-frame pixel coordinates (pixel centres at integers).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Correspondence {
    /// Optical centre, frame pixels.
    pub centre_u_px: f64,
    pub centre_v_px: f64,
    pub radial: RadialMap,
}

impl Correspondence {
    /// Unit direction (sensor frame) seen at frame pixel `(u, v)`, with its polar angle.
    pub fn direction(&self, u_px: f64, v_px: f64) -> Option<(DVec3, f64)> {
        let (du, dv) = (u_px - self.centre_u_px, v_px - self.centre_v_px);
        let r = du.hypot(dv);
        let theta = self.radial.theta_of_radius(r)?;
        let (sin_t, cos_t) = theta.sin_cos();
        // On the axis the azimuth is undefined; any value gives the same direction.
        let (sin_p, cos_p) = if r > 0.0 { (dv / r, du / r) } else { (0.0, 1.0) };
        Some((DVec3::new(sin_t * cos_p, sin_t * sin_p, cos_t), theta))
    }

    /// Frame pixel `(u, v)` that sees unit direction `dir` (sensor frame).
    pub fn pixel(&self, dir: DVec3) -> Option<(f64, f64)> {
        let len = dir.length();
        if !(len > 0.0) {
            return None;
        }
        let theta = (dir.z / len).clamp(-1.0, 1.0).acos();
        let r = self.radial.radius_of_theta(theta)?;
        let phi = dir.y.atan2(dir.x);
        Some((self.centre_u_px + r * phi.cos(), self.centre_v_px + r * phi.sin()))
    }

    /// `(theta, phi)` in radians for frame pixel `(u, v)`; `phi = atan2(v - v_c, u - u_c)`.
    pub fn angles(&self, u_px: f64, v_px: f64) -> Option<(f64, f64)> {
        let (du, dv) = (u_px - self.centre_u_px, v_px - self.centre_v_px);
        let theta = self.radial.theta_of_radius(du.hypot(dv))?;
        Some((theta, dv.atan2(du)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kb() -> RadialMap {
        RadialMap::KannalaBrandt { focal_px_per_rad: 185.0, k: [-0.02, 0.003, 0.0, 0.0] }
    }

    #[test]
    fn maps_invert_each_other() {
        let table =
            RadialMap::Tabulated { radius_px: vec![0.0, 100.0, 250.0, 400.0], theta_rad: vec![0.0, 0.55, 1.3, 2.0] };
        for map in [RadialMap::Equidistant { focal_px_per_rad: 180.0 }, kb(), table] {
            map.validate(400.0).unwrap();
            for i in 0..=100 {
                let r = 3.9 * i as f64;
                let t = map.theta_of_radius(r).unwrap();
                let back = map.radius_of_theta(t).unwrap();
                assert!((back - r).abs() < 1e-7, "{map:?}: r {r} -> theta {t} -> r {back}");
            }
        }
    }

    #[test]
    fn pixel_and_direction_round_trip() {
        let c = Correspondence { centre_u_px: 401.3, centre_v_px: 297.8, radial: kb() };
        for (u, v) in [(401.3, 297.8), (500.0, 300.0), (120.0, 40.0), (690.2, 580.9), (401.3, 20.0)] {
            let (d, theta) = c.direction(u, v).unwrap();
            assert!((d.length() - 1.0).abs() < 1e-12);
            assert!((d.z.acos() - theta).abs() < 1e-9);
            let (u2, v2) = c.pixel(d).unwrap();
            assert!((u2 - u).abs() < 1e-7 && (v2 - v).abs() < 1e-7, "({u},{v}) -> ({u2},{v2})");
        }
    }

    #[test]
    fn image_axes_match_sensor_axes() {
        // Right of the centre looks towards +x, below it towards +y.
        let c = Correspondence { centre_u_px: 400.0, centre_v_px: 300.0, radial: kb() };
        let (right, _) = c.direction(500.0, 300.0).unwrap();
        let (down, _) = c.direction(400.0, 400.0).unwrap();
        assert!(right.x > 0.0 && right.y.abs() < 1e-12);
        assert!(down.y > 0.0 && down.x.abs() < 1e-12);
    }

    #[test]
    fn invalid_maps_are_rejected() {
        let flat = RadialMap::Tabulated { radius_px: vec![0.0, 10.0, 10.0], theta_rad: vec![0.0, 0.1, 0.2] };
        assert!(flat.validate(5.0).is_err());
        let short = RadialMap::Tabulated { radius_px: vec![0.0, 10.0], theta_rad: vec![0.0, 0.1] };
        assert!(short.validate(50.0).unwrap_err().to_string().contains("crop reaches"));
        let folding = RadialMap::KannalaBrandt { focal_px_per_rad: 180.0, k: [-0.5, 0.0, 0.0, 0.0] };
        assert!(folding.validate(300.0).is_err());
        assert!(RadialMap::Equidistant { focal_px_per_rad: f64::NAN }.validate(1.0).is_err());
        assert!(RadialMap::Equidistant { focal_px_per_rad: 1.0 }.theta_of_radius(-1.0).is_none());
    }
}
