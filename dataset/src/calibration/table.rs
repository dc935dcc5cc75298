//! From matched tooth edges and the rim to the sensor's radial map: a Gaussian process through
//! the centre, every edge and the rim, tabulated pixel by pixel out to the frame's corner.

use sensor::{Correspondence, RadialMap, Sensor};

use super::gp::Gp;
use super::rim::Rim;
use super::{CalibrationError, CalibrationOptions, GpTarget, MatchedEdge, fail};

/// The fitted map and how well it fits.
pub(super) struct Fit {
    pub(super) sensor: Sensor,
    /// The edges with their residuals against the map.
    pub(super) edges: Vec<MatchedEdge>,
    pub(super) fit_rms_px: f64,
    /// Predictive standard deviation of theta at each tabulated radius inside the rim (rad).
    pub(super) sds: Vec<f64>,
    pub(super) patched_px: f64,
}

/// Fits the map through `edges` and the rim for a frame of `frame_px` (width, height).
pub(super) fn fit(
    edges: Vec<MatchedEdge>,
    rim: &Rim,
    opts: &CalibrationOptions,
    frame_px: (u32, u32),
) -> Result<Fit, CalibrationError> {
    let (uc, vc, r_rim) = rim.circle;
    let mut xs = vec![0.0];
    let mut thetas = vec![0.0];
    for e in &edges {
        xs.push(e.radius_px);
        thetas.push(e.theta_rad);
    }
    xs.push(r_rim);
    thetas.push(std::f64::consts::FRAC_PI_2);
    let radius_mm = opts.radius_mm;
    let ys: Vec<f64> = match opts.target {
        GpTarget::Theta => thetas.clone(),
        GpTarget::RSinTheta => thetas.iter().map(|t| radius_mm * t.sin()).collect(),
    };
    // The rim is placed less precisely the softer it is (a tenth of its fall's width, 0.3 px at
    // least): it pulls the map less than the teeth beside it.
    let rim_theta_sd = rim.radius_sd_px() * std::f64::consts::FRAC_PI_2 / r_rim;
    let mut point_sd = vec![0.0; ys.len()];
    point_sd[ys.len() - 1] = match opts.target {
        GpTarget::Theta => rim_theta_sd,
        GpTarget::RSinTheta => radius_mm * rim_theta_sd * rim_theta_sd / 2.0,
    };
    let gp = Gp::fit_with_noise(&xs, &ys, &point_sd, 1e-6).map_err(|e| CalibrationError(format!("regression: {e}")))?;
    let theta_at = |r: f64| -> (f64, f64) {
        let (m, sd) = gp.predict(r);
        match opts.target {
            GpTarget::Theta => (m, sd),
            GpTarget::RSinTheta => {
                let s = (m / radius_mm).clamp(-1.0, 1.0);
                let slope = 1.0 / (radius_mm * (1.0 - s * s).sqrt().max(1e-3));
                (s.asin(), sd * slope)
            }
        }
    };

    // Table out to the frame's far corner. Inside the rim: the GP. Where `R sin(theta)` is the
    // target it flattens at the rim and its inverse loses precision; from where the inverse stops
    // rising, theta is interpolated to the rim's 90 degrees. Past the rim (not useful pixels)
    // theta continues along the map's slope at the rim.
    let mut sensor = Sensor::with_radius(radius_mm);
    sensor.frame_width_px = frame_px.0;
    sensor.frame_height_px = frame_px.1;
    let r_end = (frame_px.0 as f64).hypot(frame_px.1 as f64);
    let (mut radius_px, mut theta_rad) = (vec![0.0], vec![0.0]);
    let mut sds = Vec::new();
    let rim_theta = match opts.target {
        GpTarget::Theta => theta_at(r_rim).0,
        GpTarget::RSinTheta => std::f64::consts::FRAC_PI_2,
    };
    let mut r = 1.0;
    while r < r_rim {
        let (t, sd) = theta_at(r);
        let rising = t > *theta_rad.last().unwrap() && (t < rim_theta || opts.target == GpTarget::Theta);
        if !rising {
            if opts.target == GpTarget::Theta {
                return fail(format!(
                    "the fitted map is not increasing at radius {r:.0} px (theta {:.2} deg): \
                     the tooth edges found do not describe a fisheye",
                    t.to_degrees()
                ));
            }
            break;
        }
        radius_px.push(r);
        theta_rad.push(t);
        sds.push(sd);
        r += 1.0;
    }
    let (r0, t0) = (*radius_px.last().unwrap(), *theta_rad.last().unwrap());
    let patched_px = (r_rim - r0 - 1.0).max(0.0);
    while r < r_rim {
        radius_px.push(r);
        theta_rad.push(t0 + (rim_theta - t0) * (r - r0) / (r_rim - r0));
        r += 1.0;
    }
    let n = radius_px.len();
    let rim_slope = (rim_theta - theta_rad[n - 4]) / (r_rim - radius_px[n - 4]);
    while r <= r_end + 1.0 {
        radius_px.push(r);
        theta_rad.push(rim_theta + (r - r_rim) * rim_slope);
        r += 1.0;
    }
    sensor.correspondence =
        Correspondence { centre_u_px: uc, centre_v_px: vc, radial: RadialMap::Tabulated { radius_px, theta_rad } };
    sensor.validate().map_err(|e| CalibrationError(format!("the result is not a valid sensor: {e}")))?;

    // Residuals in pixels: theta residual over the local slope of the map.
    let mut edges = edges;
    let mut sum2 = 0.0;
    for e in &mut edges {
        let (t, _) = theta_at(e.radius_px);
        let slope = (theta_at(e.radius_px + 0.5).0 - theta_at(e.radius_px - 0.5).0).max(1e-9);
        e.residual_px = (t - e.theta_rad) / slope;
        sum2 += e.residual_px * e.residual_px;
    }
    let fit_rms_px = (sum2 / edges.len() as f64).sqrt();
    if fit_rms_px > 1.0 {
        return fail(format!(
            "matched edges lie {fit_rms_px:.2} px (rms) from a smooth map: the image is too noisy or \
             the indicator is not pressed along the row through the centre"
        ));
    }
    Ok(Fit { sensor, edges, fit_rms_px, sds, patched_px })
}
