//! The embedded procedural kit: indicator shells with holes and indenters of varied shapes,
//! built like the authors' kit (same shell radii relative to the sensor, caps that rest against
//! the shell, features that press inwards), so that the main job needs no file.

use glam::{Affine3A, Quat, Vec3, vec3};

use crate::mesh::Mesh;
use crate::scene::{Indenter, Indicator};
use crate::shapes::{self, ShellHole};

/// Gap between the undeformed sensor and the shell's inner surface (the kit's 25.75 - 25 mm).
const SHELL_GAP_MM: f32 = 0.75;
const SHELL_THICKNESS_MM: f32 = 1.0;
/// Angular radius of the holes (the kit's holes are about 7 mm across).
const HOLE_HALF_ANGLE_DEG: f32 = 8.0;
/// Height of the shell's flat base above the sensor's base plane (the kit's y = 1.5).
const BASE_HEIGHT_MM: f32 = 1.5;
const CAP_THICKNESS_MM: f32 = 1.5;
/// Lateral radius of an indenter's cap (the kit's are 25.4 mm across).
const CAP_RADIUS_MM: f32 = 12.7;

/// The procedural kit's parts.
pub struct ProceduralKit {
    pub indicators: Vec<Indicator>,
    pub indenters: Vec<Indenter>,
}

fn dir_deg(theta: f32, phi: f32) -> Vec3 {
    let (t, p) = (theta.to_radians(), phi.to_radians());
    vec3(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

impl ProceduralKit {
    /// Builds the kit for a sensor of hemisphere radius `radius_mm`.
    pub fn new(radius_mm: f32) -> Self {
        let r_in = radius_mm + SHELL_GAP_MM;
        let r_out = r_in + SHELL_THICKNESS_MM;
        // (hole directions as (theta, phi) in degrees, inner texture)
        let designs: [(&[(f32, f32)], Texture); 8] = [
            (&[(30.0, 0.0)], Texture::Smooth),
            (&[(45.0, 90.0)], Texture::Smooth),
            (&[(35.0, 0.0), (35.0, 180.0)], Texture::Smooth),
            (&[(20.0, 45.0), (50.0, 225.0)], Texture::Bumps),
            (&[(0.0, 0.0)], Texture::Ridges),
            (&[(40.0, 120.0), (40.0, 300.0)], Texture::Ridges),
            (&[(55.0, 270.0)], Texture::Bumps),
            (&[(25.0, 200.0), (60.0, 20.0)], Texture::Smooth),
        ];
        let theta_max = (BASE_HEIGHT_MM / r_in).acos();
        let indicators = designs
            .iter()
            .enumerate()
            .map(|(i, (holes, texture))| {
                let holes: Vec<ShellHole> = holes
                    .iter()
                    .map(|&(t, p)| ShellHole { axis: dir_deg(t, p), half_angle_rad: HOLE_HALF_ANGLE_DEG.to_radians() })
                    .collect();
                let mut mesh = shapes::shell_cap(r_in, r_out, theta_max, &holes, 60, 120);
                texture.add(&mut mesh, r_in, &holes, i as u32);
                Indicator::new(format!("p-indicator-{i}"), mesh).expect("procedural shells have recoverable holes")
            })
            .collect();
        let hole_radius = r_in * HOLE_HALF_ANGLE_DEG.to_radians().sin();
        let indenters = FEATURES
            .iter()
            .map(|&feature| Indenter {
                name: format!("p-{}", feature.name()),
                mesh: indenter_mesh(r_in, hole_radius, feature),
            })
            .collect();
        ProceduralKit { indicators, indenters }
    }
}

#[derive(Clone, Copy)]
enum Texture {
    Smooth,
    Bumps,
    Ridges,
}

impl Texture {
    /// Adds inward features on the inner surface, away from the holes.
    fn add(self, mesh: &mut Mesh, r_in: f32, holes: &[ShellHole], seed: u32) {
        let clear = |d: Vec3| holes.iter().all(|h| d.angle_between(h.axis) > h.half_angle_rad + 0.25);
        match self {
            Texture::Smooth => {}
            Texture::Bumps => {
                for k in 0..10u32 {
                    let d = dir_deg(12.0 + 7.0 * ((k * 7 + seed) % 9) as f32, 36.0 * k as f32 + 11.0 * seed as f32);
                    if clear(d) {
                        // Embedded ball: protrudes 0.8 mm inside the shell.
                        let ball = shapes::sphere(1.6, 24);
                        mesh.append(&ball.transformed(&Affine3A::from_translation(d * (r_in + 0.8))));
                    }
                }
            }
            Texture::Ridges => {
                for k in 0..3 {
                    let d = dir_deg(25.0 + 15.0 * k as f32, 60.0 + 120.0 * k as f32 + 17.0 * seed as f32);
                    if clear(d) {
                        // A bar tangent to the shell, half buried.
                        let bar = shapes::box_mesh(vec3(10.0, 1.5, 1.6));
                        let tangent = d.cross(Vec3::Z).try_normalize().unwrap_or(Vec3::X);
                        let frame = Quat::from_mat3(&glam::Mat3::from_cols(tangent, d.cross(tangent), d));
                        mesh.append(&bar.transformed(&Affine3A::from_rotation_translation(frame, d * (r_in + 0.2))));
                    }
                }
            }
        }
    }
}

/// Shapes pressed by the procedural indenters.
#[derive(Clone, Copy, Debug)]
enum Feature {
    Sphere,
    SmallSphere,
    Cylinder,
    Box,
    Edge,
    Ring,
    Ridge,
    MultiBump,
    Cross,
    Cone,
    OffsetSphere,
    Flat,
}

const FEATURES: [Feature; 12] = [
    Feature::Sphere,
    Feature::SmallSphere,
    Feature::Cylinder,
    Feature::Box,
    Feature::Edge,
    Feature::Ring,
    Feature::Ridge,
    Feature::MultiBump,
    Feature::Cross,
    Feature::Cone,
    Feature::OffsetSphere,
    Feature::Flat,
];

impl Feature {
    fn name(self) -> &'static str {
        match self {
            Feature::Sphere => "sphere",
            Feature::SmallSphere => "small-sphere",
            Feature::Cylinder => "cylinder",
            Feature::Box => "box",
            Feature::Edge => "edge",
            Feature::Ring => "ring",
            Feature::Ridge => "ridge",
            Feature::MultiBump => "multi-bump",
            Feature::Cross => "cross",
            Feature::Cone => "cone",
            Feature::OffsetSphere => "offset-sphere",
            Feature::Flat => "flat",
        }
    }

    /// Closed solids standing on the plane `z = 0`, rising to their height along `+z`; each
    /// reaches 1 mm below the plane so that it is rooted in the cap.
    fn solids(self) -> Vec<Mesh> {
        let at = |m: Mesh, x: f32, y: f32, z: f32| m.transformed(&Affine3A::from_translation(vec3(x, y, z)));
        match self {
            Feature::Sphere => vec![at(shapes::sphere(4.0, 48), 0.0, 0.0, 2.0 - 4.0)],
            Feature::SmallSphere => vec![at(shapes::sphere(2.0, 32), 0.0, 0.0, 1.5 - 2.0)],
            Feature::Cylinder => vec![at(shapes::cylinder(3.5, 2.8, 48), 0.0, 0.0, -1.0)],
            Feature::Box => vec![at(shapes::box_mesh(vec3(7.0, 4.0, 2.5)), 0.0, 0.0, 0.25)],
            Feature::Edge => vec![at(shapes::wedge(16.0, 6.0, 3.0), 0.0, 0.0, -1.0)],
            Feature::Ring => vec![at(shapes::torus(5.0, 1.0, 48), 0.0, 0.0, 0.5)],
            Feature::Ridge => vec![at(shapes::box_mesh(vec3(18.0, 2.0, 2.2)), 0.0, 0.0, 0.1)],
            Feature::MultiBump => (0..4)
                .map(|k| {
                    let a = std::f32::consts::FRAC_PI_2 * k as f32;
                    at(shapes::sphere(1.5, 24), 5.0 * a.cos(), 5.0 * a.sin(), 1.2 - 1.5)
                })
                .collect(),
            Feature::Cross => vec![
                at(shapes::box_mesh(vec3(16.0, 1.6, 2.0)), 0.0, 0.0, 0.0),
                at(shapes::box_mesh(vec3(1.6, 16.0, 2.0)), 0.0, 0.0, 0.0),
            ],
            Feature::Cone => vec![shapes::revolve(&[(0.0, -1.0), (4.5, -1.0), (0.0, 2.5)], 48, false)],
            Feature::OffsetSphere => vec![at(shapes::sphere(3.0, 40), 5.0, 0.0, 1.8 - 3.0)],
            Feature::Flat => vec![],
        }
    }
}

/// An indenter in its own frame (`+z` inwards): a cap whose back is a bowl of radius `r_in`
/// about `(0, 0, d0)`, a stem that goes out through the hole, and the feature on the cap's front.
fn indenter_mesh(r_in: f32, hole_radius: f32, feature: Feature) -> Mesh {
    let d0 = r_in - SHELL_GAP_MM;
    let cap_theta = (CAP_RADIUS_MM / r_in).asin();
    // shell_cap is built about +z; turn it to face -z and move its centre to (0, 0, d0).
    let flip = Affine3A::from_translation(vec3(0.0, 0.0, d0)) * Affine3A::from_rotation_x(std::f32::consts::PI);
    let mut mesh = shapes::shell_cap(r_in - CAP_THICKNESS_MM, r_in, cap_theta, &[], 12, 72).transformed(&flip);
    let back = d0 - r_in;
    let stem = shapes::cylinder(0.6 * hole_radius, 6.5, 32);
    mesh.append(&stem.transformed(&Affine3A::from_translation(vec3(0.0, 0.0, back - 6.0))));
    let front = back + CAP_THICKNESS_MM;
    for solid in feature.solids() {
        mesh.append(&solid.transformed(&Affine3A::from_translation(vec3(0.0, 0.0, front))));
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kit_has_the_designed_holes() {
        let kit = ProceduralKit::new(25.0);
        let counts: Vec<usize> = kit.indicators.iter().map(|i| i.holes.len()).collect();
        assert_eq!(counts, vec![1, 1, 2, 2, 1, 2, 1, 2]);
        for ind in &kit.indicators {
            assert!((ind.radii.inner_mm - 25.75).abs() < 1e-3 && (ind.radii.outer_mm - 26.75).abs() < 1e-3);
        }
        // Indicator 1's hole was drilled at theta 45, phi 90.
        let err = kit.indicators[1].holes[0].axis.angle_between(dir_deg(45.0, 90.0)).to_degrees();
        assert!(err < 1.0, "hole axis off by {err} degrees");
        assert_eq!(kit.indenters.len(), 12);
    }
}
