//! Recovering an indicator shell's radii and hole axes from its mesh.
//!
//! The kit gives no hole axes. A hole is drilled through the spherical shell towards the
//! centre, so its wall is a band of triangles whose normals are perpendicular to the radial
//! direction, running between the shell's inner and outer radius. The wall's vertices on the
//! inner radius form the hole's rim: a circle whose plane's normal is the hole's axis.

use glam::{DMat3, DVec3, Vec3};

use crate::mesh::Mesh;

/// Radii of the shell's two spherical surfaces (mm).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShellRadii {
    pub inner_mm: f32,
    pub outer_mm: f32,
}

/// A hole through the shell.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Hole {
    /// Unit axis from the centre outwards, sensor frame.
    pub axis: Vec3,
    /// Radius of the rim on the inner surface (mm).
    pub radius_mm: f32,
}

#[derive(Debug, thiserror::Error)]
pub enum HoleError {
    #[error("no spherical shell found: {0}")]
    NotAShell(String),
    #[error("hole rim of {0} points is too small to fit")]
    TinyRim(usize),
}

/// Tolerance for "on the same sphere" (mm).
const RADIUS_TOL_MM: f32 = 0.02;

/// Finds the inner and outer radii: the two radii that carry the most area of triangles that
/// lie on a sphere about the centre.
pub fn shell_radii(shell: &Mesh) -> Result<ShellRadii, HoleError> {
    let mut bins: std::collections::HashMap<i64, f64> = Default::default();
    for i in 0..shell.triangles.len() {
        let [a, b, c] = shell.triangle(i);
        let (ra, rb, rc) = (a.length(), b.length(), c.length());
        if (ra - rb).abs() > RADIUS_TOL_MM || (ra - rc).abs() > RADIUS_TOL_MM {
            continue;
        }
        let area = 0.5 * (b - a).cross(c - a).length() as f64;
        *bins.entry(((ra + rb + rc) / 3.0 * 20.0).round() as i64).or_default() += area;
    }
    let mut ranked: Vec<(i64, f64)> = bins.into_iter().collect();
    ranked.sort_by(|x, y| y.1.total_cmp(&x.1));
    let [(r1, a1), (r2, a2)] = match ranked.as_slice() {
        [x, y, ..] => [*x, *y],
        _ => {
            return Err(HoleError::NotAShell("fewer than two spherical surfaces".into()));
        }
    };
    if a2 < 0.2 * a1 {
        return Err(HoleError::NotAShell(format!("only one large spherical surface (radius {} mm)", r1 as f32 / 20.0)));
    }
    // Bins are 0.05 mm wide; refine each radius as the mean vertex radius in its bin.
    let refine = |bin: i64| {
        let (sum, n) = shell
            .vertices
            .iter()
            .map(|v| v.length())
            .filter(|r| ((r * 20.0).round() as i64 - bin).abs() <= 1)
            .fold((0.0f64, 0usize), |(s, n), r| (s + r as f64, n + 1));
        (sum / n.max(1) as f64) as f32
    };
    let (lo, hi) = if r1 < r2 { (r1, r2) } else { (r2, r1) };
    Ok(ShellRadii { inner_mm: refine(lo), outer_mm: refine(hi) })
}

/// Finds the shell's holes, ordered from the top (smallest polar angle) down, ties by azimuth.
pub fn find_holes(shell: &Mesh) -> Result<(ShellRadii, Vec<Hole>), HoleError> {
    let radii = shell_radii(shell)?;
    let base_z = shell.bounds().0.z;
    let in_band = |r: f32| r > radii.inner_mm - RADIUS_TOL_MM && r < radii.outer_mm + RADIUS_TOL_MM;
    let mut rim: Vec<DVec3> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (i, tri) in shell.triangles.iter().enumerate() {
        let [a, b, c] = shell.triangle(i);
        let centroid = (a + b + c) / 3.0;
        let n = (b - a).cross(c - a).normalize_or_zero();
        let radial = centroid.normalize_or_zero();
        let is_wall = n.dot(radial).abs() < 0.2
            && [a, b, c].iter().all(|v| in_band(v.length()))
            // The open base also has walls; holes are well above it.
            && centroid.z > base_z + 1.0;
        if !is_wall {
            continue;
        }
        for &vi in tri {
            let v = shell.vertices[vi as usize];
            if (v.length() - radii.inner_mm).abs() < RADIUS_TOL_MM && seen.insert(vi) {
                rim.push(v.as_dvec3());
            }
        }
    }
    let mut holes = Vec::new();
    for cluster in clusters(&rim, 3.0) {
        if cluster.len() < 6 {
            return Err(HoleError::TinyRim(cluster.len()));
        }
        holes.push(fit_rim(&cluster));
    }
    holes.sort_by(|a, b| {
        let key = |h: &Hole| ((h.axis.z.clamp(-1.0, 1.0).acos().to_degrees()).round(), h.axis.y.atan2(h.axis.x));
        let (ka, kb) = (key(a), key(b));
        ka.0.total_cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
    });
    Ok((radii, holes))
}

/// Single-linkage clusters of points closer than `link_mm`.
fn clusters(points: &[DVec3], link_mm: f64) -> Vec<Vec<DVec3>> {
    let mut label = vec![usize::MAX; points.len()];
    let mut out = Vec::new();
    for start in 0..points.len() {
        if label[start] != usize::MAX {
            continue;
        }
        let id = out.len();
        let mut members = vec![start];
        label[start] = id;
        let mut k = 0;
        while k < members.len() {
            let p = points[members[k]];
            for (j, q) in points.iter().enumerate() {
                if label[j] == usize::MAX && p.distance(*q) < link_mm {
                    label[j] = id;
                    members.push(j);
                }
            }
            k += 1;
        }
        out.push(members.into_iter().map(|i| points[i]).collect());
    }
    out
}

/// Axis of a rim: the normal of its best-fit plane, oriented outwards.
fn fit_rim(points: &[DVec3]) -> Hole {
    let n = points.len() as f64;
    let mean = points.iter().copied().sum::<DVec3>() / n;
    let mut cov = DMat3::ZERO;
    for p in points {
        let d = *p - mean;
        cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    let mut axis = smallest_eigenvector(cov / n);
    if axis.dot(mean) < 0.0 {
        axis = -axis;
    }
    let radius = points.iter().map(|p| p.reject_from_normalized(axis).length()).sum::<f64>() / n;
    Hole { axis: axis.as_vec3(), radius_mm: radius as f32 }
}

/// Eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix (cyclic Jacobi rotations).
#[allow(clippy::needless_range_loop)] // index arithmetic mirrors the rotation formulas
pub fn smallest_eigenvector(m: DMat3) -> DVec3 {
    let mut a = m.to_cols_array_2d();
    let mut v = DMat3::IDENTITY.to_cols_array_2d();
    for _ in 0..64 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        if off < 1e-30 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A <- J^T A J, V <- V J, with J the rotation in the (p, q) plane.
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[p][k], v[q][k]);
                v[p][k] = c * vkp - s * vkq;
                v[q][k] = s * vkp + c * vkq;
            }
        }
    }
    let i = (0..3).min_by(|&x, &y| a[x][x].total_cmp(&a[y][y])).unwrap();
    DVec3::from_array(v[i]).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::{ShellHole, shell_cap};

    #[test]
    fn eigenvector_of_known_matrix() {
        let axes = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let m = axes * DMat3::from_diagonal(DVec3::new(5.0, 0.1, 2.0)) * axes.transpose();
        let e = smallest_eigenvector(m);
        let want = axes.col(1);
        assert!(e.dot(want).abs() > 1.0 - 1e-10, "{e} vs {want}");
    }

    #[test]
    fn recovers_axes_of_a_procedural_shell() {
        let truth = [DVec3::new(0.0, 0.5, 0.8).normalize(), DVec3::new(-0.6, -0.3, 0.5).normalize()];
        let holes: Vec<ShellHole> =
            truth.iter().map(|a| ShellHole { axis: a.as_vec3(), half_angle_rad: 0.14 }).collect();
        let shell = shell_cap(25.75, 26.75, 1.51, &holes, 180, 360);
        let (radii, found) = find_holes(&shell).unwrap();
        assert!((radii.inner_mm - 25.75).abs() < 1e-3 && (radii.outer_mm - 26.75).abs() < 1e-3, "{radii:?}");
        assert_eq!(found.len(), 2);
        for (h, t) in found.iter().zip(truth) {
            let err_deg = h.axis.as_dvec3().angle_between(t).to_degrees();
            assert!(err_deg < 0.5, "axis off by {err_deg} degrees");
            assert!((h.radius_mm - 25.75 * 0.14f32.sin()).abs() < 0.3, "{}", h.radius_mm);
        }
    }

    #[test]
    fn a_solid_ball_is_not_a_shell() {
        assert!(find_holes(&crate::shapes::sphere(10.0, 32)).is_err());
    }
}
