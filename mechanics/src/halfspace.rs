//! The linear-elastic half-space under normal surface load (Boussinesq): a point force `F` sinks
//! the surface at distance `r` by `(1 - nu^2) F / (pi E r)`. A uniform pressure over a square
//! element sinks a point by `(1 - nu^2) p / (pi E)` times the integral of `1 / r` over the
//! element, which has a closed form (Love, 1929); the element's own centre is the integral's
//! singular case and needs it.

/// `ln(a + sqrt(a^2 + b^2))` without the cancellation of `a + r` when `a` is negative and `|b|`
/// small: there `a + r = b^2 / (r - a)`.
fn ln_a_plus_r(a: f64, b: f64, r: f64) -> f64 {
    if a >= 0.0 { (a + r).ln() } else { (b * b / (r - a)).ln() }
}

/// A primitive of `1 / sqrt(x^2 + y^2)` in both variables: `d^2 F / dx dy = 1 / r`. Each term
/// vanishes with its factor (`x ln(...)` at `x = 0`), which the element's own corners reach.
fn primitive(x: f64, y: f64) -> f64 {
    let r = x.hypot(y);
    let term = |a: f64, b: f64| if a == 0.0 { 0.0 } else { a * ln_a_plus_r(b, a, r) };
    term(x, y) + term(y, x)
}

/// The integral of `1 / r` (mm) over a rectangle of half sides `half_x_mm`, `half_y_mm` centred
/// at `(dx_mm, dy_mm)` from the point where the displacement is wanted.
pub(crate) fn rectangle_integral_mm(dx_mm: f64, dy_mm: f64, half_x_mm: f64, half_y_mm: f64) -> f64 {
    let (x0, x1) = (dx_mm - half_x_mm, dx_mm + half_x_mm);
    let (y0, y1) = (dy_mm - half_y_mm, dy_mm + half_y_mm);
    primitive(x1, y1) - primitive(x0, y1) - primitive(x1, y0) + primitive(x0, y0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A midpoint rule on a fine sub-grid, the reference for a rectangle that does not hold the
    /// point (where `1 / r` is smooth).
    fn quadrature(dx: f64, dy: f64, hx: f64, hy: f64) -> f64 {
        let n = 400;
        let (sx, sy) = (2.0 * hx / n as f64, 2.0 * hy / n as f64);
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let x = dx - hx + (i as f64 + 0.5) * sx;
                let y = dy - hy + (j as f64 + 0.5) * sy;
                sum += 1.0 / x.hypot(y);
            }
        }
        sum * sx * sy
    }

    #[test]
    fn the_closed_form_matches_quadrature_near_and_far() {
        for (dx, dy, hx, hy) in
            [(1.0, 0.0, 0.5, 0.5), (0.0, -1.0, 0.5, 0.5), (-2.0, 1.0, 0.5, 0.5), (3.0, -4.0, 0.25, 0.75)]
        {
            let exact = rectangle_integral_mm(dx, dy, hx, hy);
            let numeric = quadrature(dx, dy, hx, hy);
            assert!((exact - numeric).abs() <= 1e-5 * numeric, "({dx}, {dy}): {exact} against {numeric}");
        }
        // Far away the element is a point: area / distance.
        let far = rectangle_integral_mm(40.0, -30.0, 0.5, 0.5);
        assert!((far - 1.0 / 50.0).abs() <= 1e-4 / 50.0, "{far}");
    }

    #[test]
    fn an_elements_own_centre_has_the_known_singular_integral() {
        // Over a square of side h from its centre: 4 h ln(1 + sqrt 2).
        for h in [0.1, 1.0, 2.5] {
            let own = rectangle_integral_mm(0.0, 0.0, h / 2.0, h / 2.0);
            let known = 4.0 * h * (1.0 + 2f64.sqrt()).ln();
            assert!((own - known).abs() <= 1e-12 * known, "h {h}: {own} against {known}");
        }
        // Mirror images see the same element alike (the matrix built from it is symmetric).
        let a = rectangle_integral_mm(1.5, -2.0, 0.5, 0.5);
        for (x, y) in [(-1.5, -2.0), (1.5, 2.0), (-1.5, 2.0)] {
            assert!((rectangle_integral_mm(x, y, 0.5, 0.5) - a).abs() <= 1e-13);
        }
    }
}
