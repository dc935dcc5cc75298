//! Closed, welded triangle meshes of simple solids, for the procedural kit and for tests.
//!
//! Every solid is watertight by construction: neighbouring faces share vertex indices.
//! Solids of revolution are built about the `z` axis; callers pose them with an `Affine3A`.

use glam::{Vec3, vec3};

use crate::mesh::Mesh;

/// Surface of revolution about `z` of a profile of `(rho, z)` points.
///
/// Profile ends with `rho == 0` close onto the axis with a single pole vertex, so a profile that
/// starts and ends on the axis gives a closed solid. With `closed_loop` the profile's last point
/// joins its first (a torus).
pub fn revolve(profile: &[(f32, f32)], segments: u32, closed_loop: bool) -> Mesh {
    let n = segments as usize;
    let mut mesh = Mesh::default();
    // Vertex indices per profile point: one pole or a ring of `n`.
    let mut rings: Vec<Vec<u32>> = Vec::with_capacity(profile.len());
    for &(rho, z) in profile {
        let start = mesh.vertices.len() as u32;
        if rho == 0.0 {
            mesh.vertices.push(vec3(0.0, 0.0, z));
            rings.push(vec![start; n]);
        } else {
            for j in 0..n {
                let a = std::f32::consts::TAU * j as f32 / n as f32;
                mesh.vertices.push(vec3(rho * a.cos(), rho * a.sin(), z));
            }
            rings.push((start..start + n as u32).collect());
        }
    }
    let links = if closed_loop { profile.len() } else { profile.len() - 1 };
    for k in 0..links {
        let (a, b) = (&rings[k], &rings[(k + 1) % profile.len()]);
        for j in 0..n {
            let j1 = (j + 1) % n;
            // Quad a[j] a[j1] b[j1] b[j], split in two; degenerate halves at poles are dropped.
            for t in [[a[j], a[j1], b[j1]], [a[j], b[j1], b[j]]] {
                if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                    mesh.triangles.push(t);
                }
            }
        }
    }
    mesh
}

/// Sphere of `radius` centred at the origin.
pub fn sphere(radius: f32, segments: u32) -> Mesh {
    let rings = (segments / 2).max(2);
    let profile: Vec<(f32, f32)> = (0..=rings)
        .map(|i| {
            let a = std::f32::consts::PI * i as f32 / rings as f32;
            if i == 0 || i == rings { (0.0, -radius * a.cos()) } else { (radius * a.sin(), -radius * a.cos()) }
        })
        .collect();
    revolve(&profile, segments, false)
}

/// Solid cylinder along `z` from `z = 0` to `z = height`.
pub fn cylinder(radius: f32, height: f32, segments: u32) -> Mesh {
    revolve(&[(0.0, 0.0), (radius, 0.0), (radius, height), (0.0, height)], segments, false)
}

/// Solid ring (torus) about `z`: `major` to the tube's centre, `minor` the tube's radius.
pub fn torus(major: f32, minor: f32, segments: u32) -> Mesh {
    let m = (segments / 2).max(6);
    let profile: Vec<(f32, f32)> = (0..m)
        .map(|i| {
            let a = std::f32::consts::TAU * i as f32 / m as f32;
            (major + minor * a.cos(), minor * a.sin())
        })
        .collect();
    revolve(&profile, segments, true)
}

/// Axis-aligned box of the given full size, centred at the origin.
pub fn box_mesh(size: Vec3) -> Mesh {
    let h = size * 0.5;
    let vertices: Vec<Vec3> = (0..8)
        .map(|i| {
            vec3(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            )
        })
        .collect();
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    Mesh { vertices, triangles }
}

/// Triangular prism along `x` (length `length`): a knife edge of `width` at `z = 0` rising to
/// its apex at `z = height`.
pub fn wedge(length: f32, width: f32, height: f32) -> Mesh {
    let (l, w) = (length * 0.5, width * 0.5);
    let vertices = vec![
        vec3(-l, -w, 0.0),
        vec3(-l, w, 0.0),
        vec3(-l, 0.0, height),
        vec3(l, -w, 0.0),
        vec3(l, w, 0.0),
        vec3(l, 0.0, height),
    ];
    let triangles = vec![[0, 2, 1], [3, 4, 5], [0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [0, 3, 5], [0, 5, 2]];
    Mesh { vertices, triangles }
}

/// A hole through a shell: cells whose centre lies within `half_angle_rad` of `axis` are removed.
#[derive(Clone, Copy, Debug)]
pub struct ShellHole {
    pub axis: Vec3,
    pub half_angle_rad: f32,
}

/// Spherical shell cap about `+z` between radii `r_in` and `r_out`, from the pole down to polar
/// angle `theta_max`, with holes. Built as a cell complex on a (theta, phi) grid: the holes' rims
/// follow cell edges, and walls close every boundary, so the solid stays watertight.
pub fn shell_cap(r_in: f32, r_out: f32, theta_max: f32, holes: &[ShellHole], n_theta: u32, n_phi: u32) -> Mesh {
    let (nt, np) = (n_theta as usize, n_phi as usize);
    let dir = |i: usize, j: usize| {
        let t = theta_max * i as f32 / nt as f32;
        let p = std::f32::consts::TAU * j as f32 / np as f32;
        vec3(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
    };
    let mut mesh = Mesh::default();
    // vertex index of ring i, column j on the inner (layer 0) or outer (layer 1) surface.
    let mut index = vec![[0u32; 2]; (nt + 1) * np];
    for i in 0..=nt {
        for j in 0..np {
            if i == 0 && j > 0 {
                index[j] = index[0];
                continue;
            }
            let d = dir(i, j);
            let base = mesh.vertices.len() as u32;
            mesh.vertices.push(d * r_in);
            mesh.vertices.push(d * r_out);
            index[i * np + j] = [base, base + 1];
        }
    }
    let v = |i: usize, j: usize, layer: usize| index[i * np + j % np][layer];
    let kept = |i: isize, j: usize| -> bool {
        if i < 0 || i >= nt as isize {
            return false;
        }
        let t = theta_max * (i as f32 + 0.5) / nt as f32;
        let p = std::f32::consts::TAU * (j as f32 + 0.5) / np as f32;
        let c = vec3(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        holes.iter().all(|h| c.angle_between(h.axis.normalize()) > h.half_angle_rad)
    };
    let mut push = |t: [u32; 3]| {
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            mesh.triangles.push(t);
        }
    };
    for i in 0..nt {
        for j in 0..np {
            if !kept(i as isize, j) {
                continue;
            }
            let j1 = j + 1;
            let (a, b, c, d) = ((i, j), (i, j1), (i + 1, j1), (i + 1, j));
            // Outer face seen from outside, inner face seen from the centre.
            for layer in 0..2 {
                let q = [v(a.0, a.1, layer), v(b.0, b.1, layer), v(c.0, c.1, layer), v(d.0, d.1, layer)];
                if layer == 1 {
                    push([q[0], q[3], q[2]]);
                    push([q[0], q[2], q[1]]);
                } else {
                    push([q[0], q[1], q[2]]);
                    push([q[0], q[2], q[3]]);
                }
            }
            // Walls towards every removed neighbour (or the open base).
            let jm = (j + np - 1) % np;
            let edges = [
                (i as isize - 1, j, a, b),
                (i as isize + 1, j, c, d),
                (i as isize, jm, d, a),
                (i as isize, (j + 1) % np, b, c),
            ];
            for (ni, nj, p, q) in edges {
                if kept(ni, nj) || (i == 0 && ni < 0) {
                    continue;
                }
                let (p0, p1) = (v(p.0, p.1, 0), v(p.0, p.1, 1));
                let (q0, q1) = (v(q.0, q.1, 0), v(q.0, q.1, 1));
                // Opposite in direction to the faces' own traversal of this edge.
                push([q0, p0, p1]);
                push([q0, p1, q1]);
            }
        }
    }
    mesh
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Every edge of a closed 2-manifold is used exactly twice, once in each direction.
    pub fn assert_closed(mesh: &Mesh) {
        let mut count: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        let open: Vec<_> = count.iter().filter(|(_, c)| **c != 0).take(5).collect();
        assert!(open.is_empty(), "edges not matched in opposite directions: {open:?}");
    }

    /// Signed volume by the divergence theorem: positive for outward winding.
    pub fn volume(mesh: &Mesh) -> f32 {
        (0..mesh.triangles.len())
            .map(|i| {
                let [a, b, c] = mesh.triangle(i);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn solids_are_closed_with_the_right_volume() {
        let pi = std::f32::consts::PI;
        let cases: Vec<(Mesh, f32)> = vec![
            (sphere(2.0, 96), 4.0 / 3.0 * pi * 8.0),
            (cylinder(1.5, 3.0, 96), pi * 2.25 * 3.0),
            (torus(4.0, 1.0, 96), 2.0 * pi * pi * 4.0),
            (box_mesh(vec3(1.0, 2.0, 3.0)), 6.0),
            (wedge(4.0, 2.0, 3.0), 12.0),
        ];
        for (mesh, expected) in cases {
            assert_closed(&mesh);
            let v = volume(&mesh);
            assert!((v - expected).abs() < 0.01 * expected, "volume {v} vs {expected}");
        }
    }

    #[test]
    fn shell_with_holes_is_closed() {
        let holes = [
            ShellHole { axis: vec3(0.0, 0.7, 0.7), half_angle_rad: 0.14 },
            ShellHole { axis: vec3(0.5, -0.5, 0.7), half_angle_rad: 0.2 },
        ];
        let shell = shell_cap(25.75, 26.75, 1.5, &holes, 60, 120);
        assert_closed(&shell);
        assert!(volume(&shell) > 0.0);
        let solid = shell_cap(25.75, 26.75, 1.5, &[], 60, 120);
        assert!(volume(&solid) > volume(&shell));
    }
}
