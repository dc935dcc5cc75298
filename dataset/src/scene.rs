//! Scenes posed like the paper's rig: an indicator shell with up to two indenters seated in its
//! holes, the assembly turned about the sensor axis (B axis) and pressed down by the CNC's z travel.
//!
//! Frames. Meshes are loaded into the sensor frame's axes (Z-up, origin at the sphere's centre),
//! where the kit's shells are already centred. An indenter's own frame is the same after loading:
//! its `+z` axis points inwards (towards the centre once seated) and its cap's back is a bowl that
//! rests against the shell's inner surface.

pub use formats::dataset::{Placement, RigPose, SceneDescription};
use glam::{Affine3A, Quat, Vec3};

use crate::holes::{Hole, ShellRadii, find_holes};
use crate::mesh::Mesh;

#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("indicator {indicator}: {source}")]
    Holes { indicator: String, source: crate::holes::HoleError },
    #[error("indicator {indicator} has {holes} hole(s) but the scene seats {indenters} indenter(s)")]
    TooManyIndenters { indicator: String, holes: usize, indenters: usize },
    #[error(
        "indenter {indenter}: no part of it is wider than the {hole_radius_mm:.2} mm hole, so it cannot rest against the shell"
    )]
    CannotSeat { indenter: String, hole_radius_mm: f32 },
}

/// An indicator shell ready to take indenters: its mesh and recovered holes.
#[derive(Clone, Debug)]
pub struct Indicator {
    pub name: String,
    pub mesh: Mesh,
    pub radii: ShellRadii,
    pub holes: Vec<Hole>,
}

impl Indicator {
    pub fn new(name: impl Into<String>, mesh: Mesh) -> Result<Self, SceneError> {
        let name = name.into();
        let (radii, holes) =
            find_holes(&mesh).map_err(|source| SceneError::Holes { indicator: name.clone(), source })?;
        Ok(Indicator { name, mesh, radii, holes })
    }
}

/// An indenter and its seating distance for a given shell.
#[derive(Clone, Debug)]
pub struct Indenter {
    pub name: String,
    pub mesh: Mesh,
}

impl Indenter {
    /// Distance from the centre to the indenter's origin once its cap rests against a shell of
    /// inner radius `r_in`: the largest `D` for which every vertex wider than the hole stays
    /// inside the sphere, i.e. `min(z + sqrt(r_in^2 - rho^2))` over those vertices.
    pub fn seat_distance_mm(&self, r_in: f32, hole_radius_mm: f32) -> Result<f32, SceneError> {
        let d = self
            .mesh
            .vertices
            .iter()
            .filter_map(|v| {
                let rho = v.x.hypot(v.y);
                (rho > hole_radius_mm + 0.1 && rho < r_in).then(|| v.z + (r_in * r_in - rho * rho).sqrt())
            })
            .fold(f32::INFINITY, f32::min);
        if d.is_finite() { Ok(d) } else { Err(SceneError::CannotSeat { indenter: self.name.clone(), hole_radius_mm }) }
    }
}

/// A posed scene: its parts' meshes in the sensor frame.
#[derive(Clone, Debug)]
pub struct Scene {
    pub description: SceneDescription,
    pub parts: Vec<Mesh>,
}

impl Scene {
    /// Seats the indenters in the indicator's holes and poses the assembly.
    pub fn assemble(indicator: &Indicator, indenters: &[(&Indenter, f32)], pose: RigPose) -> Result<Scene, SceneError> {
        Scene::assemble_in(indicator, indenters, pose, Affine3A::IDENTITY)
    }

    /// [`Scene::assemble`] on a rig whose frame is `mount` in the sensor's (a sensor sitting
    /// off the CAD in its mount: [`crate::rig::RigOffsets::mount`]).
    pub fn assemble_in(
        indicator: &Indicator,
        indenters: &[(&Indenter, f32)],
        pose: RigPose,
        mount: Affine3A,
    ) -> Result<Scene, SceneError> {
        if indenters.len() > indicator.holes.len() {
            return Err(SceneError::TooManyIndenters {
                indicator: indicator.name.clone(),
                holes: indicator.holes.len(),
                indenters: indenters.len(),
            });
        }
        let rig = mount * rig_transform(pose);
        let mut parts = vec![indicator.mesh.transformed(&rig)];
        let mut placements = Vec::new();
        for (hole_index, &(indenter, angle_deg)) in indenters.iter().enumerate() {
            let hole = indicator.holes[hole_index];
            let seat = seat_pose(indenter, indicator.radii.inner_mm, hole, angle_deg)?;
            parts.push(indenter.mesh.transformed(&(rig * seat)));
            placements.push(Placement { indenter: indenter.name.clone(), hole: hole_index, angle_deg });
        }
        let description = SceneDescription { indicator: indicator.name.clone(), placements, pose };
        Ok(Scene { description, parts })
    }

    pub fn part_refs(&self) -> Vec<&Mesh> {
        self.parts.iter().collect()
    }
}

/// The rig's transform of the seated assembly (see [`RigPose`]): tilt A about `x`, then C
/// about `y`, then turn B about the sensor axis, then press down by the z travel.
pub fn rig_transform(pose: RigPose) -> Affine3A {
    Affine3A::from_translation(Vec3::new(0.0, 0.0, -pose.z_travel_mm))
        * Affine3A::from_rotation_z(pose.b_axis_deg.to_radians())
        * Affine3A::from_rotation_y(pose.c_axis_deg.to_radians())
        * Affine3A::from_rotation_x(pose.a_axis_deg.to_radians())
}

/// Indenter frame -> shell frame: turn about its own axis, point `+z` inwards along the hole,
/// and slide out until the cap rests against the shell.
pub fn seat_pose(indenter: &Indenter, r_in: f32, hole: Hole, angle_deg: f32) -> Result<Affine3A, SceneError> {
    let distance = indenter.seat_distance_mm(r_in, hole.radius_mm)?;
    let align = Quat::from_rotation_arc(Vec3::Z, -hole.axis.normalize());
    Ok(Affine3A::from_rotation_translation(
        align * Quat::from_rotation_z(angle_deg.to_radians()),
        hole.axis.normalize() * distance,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes;

    #[test]
    fn seated_cap_rests_on_the_inner_surface() {
        let kit = crate::procedural::ProceduralKit::new(25.0);
        let indicator = &kit.indicators[0];
        let indenter = &kit.indenters[0];
        let pose = RigPose { b_axis_deg: 0.0, z_travel_mm: 0.0, ..RigPose::default() };
        let scene = Scene::assemble(indicator, &[(indenter, 30.0)], pose).unwrap();
        let seated = &scene.parts[1];
        let r_in = indicator.radii.inner_mm;
        let hole = indicator.holes[0];
        // No vertex wider than the hole goes beyond the shell's inner surface, and some touch it.
        let mut touching = 0;
        for v in &seated.vertices {
            if v.reject_from(hole.axis).length() > hole.radius_mm + 0.2 {
                assert!(v.length() <= r_in + 1e-3, "{} beyond {r_in}", v.length());
                touching += (v.length() > r_in - 1e-3) as usize;
            }
        }
        assert!(touching > 0);
    }

    #[test]
    fn b_axis_and_z_travel_move_the_assembly() {
        let kit = crate::procedural::ProceduralKit::new(25.0);
        let (indicator, indenter) = (&kit.indicators[0], &kit.indenters[1]);
        let at = |b, z| {
            Scene::assemble(
                indicator,
                &[(indenter, 0.0)],
                RigPose { b_axis_deg: b, z_travel_mm: z, ..RigPose::default() },
            )
            .unwrap()
        };
        let (a, turned, pressed) = (at(0.0, 0.0), at(90.0, 0.0), at(0.0, 1.5));
        for ((p, q), r) in a.parts[1].vertices.iter().zip(&turned.parts[1].vertices).zip(&pressed.parts[1].vertices) {
            let rotated = Quat::from_rotation_z(90f32.to_radians()) * *p;
            assert!(rotated.distance(*q) < 1e-4);
            assert!((*p - Vec3::Z * 1.5).distance(*r) < 1e-4);
        }
    }

    /// Quarter turns written out by hand: Rx(90) (x, y, z) -> (x, -z, y), Ry(90) -> (z, y, -x),
    /// Rz(90) -> (-y, x, z).
    fn rx90(v: Vec3) -> Vec3 {
        Vec3::new(v.x, -v.z, v.y)
    }
    fn ry90(v: Vec3) -> Vec3 {
        Vec3::new(v.z, v.y, -v.x)
    }
    fn rz90(v: Vec3) -> Vec3 {
        Vec3::new(-v.y, v.x, v.z)
    }

    /// A shell turned about each axis of the rig: the centre of its hole's rim lands where the
    /// rotations, applied A, then C, then B, put it; z travel moves it straight down.
    #[test]
    fn a_b_and_c_turn_the_hole_where_the_rig_would() {
        let kit = crate::procedural::ProceduralKit::new(25.0);
        let indicator = &kit.indicators[0];
        let hole = indicator.holes[0];
        // The rim: vertices on the inner surface around the hole's axis.
        let rim: Vec<usize> = (0..indicator.mesh.vertices.len())
            .filter(|&i| {
                let v = indicator.mesh.vertices[i];
                (v.length() - indicator.radii.inner_mm).abs() < 0.05
                    && v.normalize().angle_between(hole.axis) < (hole.radius_mm / indicator.radii.inner_mm) * 1.05
            })
            .collect();
        assert!(rim.len() > 8, "the hole has a rim");
        let centre = |pose: RigPose| {
            let scene = Scene::assemble(indicator, &[], pose).unwrap();
            rim.iter().map(|&i| scene.parts[0].vertices[i]).sum::<Vec3>() / rim.len() as f32
        };
        let rest = centre(RigPose::default());
        let pose = |a, b, c, z| RigPose { a_axis_deg: a, b_axis_deg: b, c_axis_deg: c, z_travel_mm: z };
        let cases: [(RigPose, Vec3); 6] = [
            (pose(90.0, 0.0, 0.0, 0.0), rx90(rest)),
            (pose(0.0, 0.0, 90.0, 0.0), ry90(rest)),
            (pose(0.0, 90.0, 0.0, 0.0), rz90(rest)),
            // A first, then C: the order matters.
            (pose(90.0, 0.0, 90.0, 0.0), ry90(rx90(rest))),
            (pose(90.0, 90.0, 90.0, 0.0), rz90(ry90(rx90(rest)))),
            (pose(90.0, 0.0, 0.0, 1.5), rx90(rest) - Vec3::Z * 1.5),
        ];
        for (p, want) in cases {
            let got = centre(p);
            assert!(got.distance(want) < 1e-3, "{p:?}: hole centre at {got}, expected {want}");
        }
        assert!(ry90(rx90(rest)).distance(rx90(ry90(rest))) > 1.0, "the case tells the orders apart");
    }

    #[test]
    fn too_many_indenters_or_unseatable_ones_are_errors() {
        let kit = crate::procedural::ProceduralKit::new(25.0);
        let one_hole = kit.indicators.iter().find(|i| i.holes.len() == 1).unwrap();
        let ind = &kit.indenters[0];
        let pose = RigPose { b_axis_deg: 0.0, z_travel_mm: 0.0, ..RigPose::default() };
        let e = Scene::assemble(one_hole, &[(ind, 0.0), (ind, 0.0)], pose).unwrap_err().to_string();
        assert!(e.contains("1 hole(s)"), "{e}");
        let pin = Indenter { name: "pin".into(), mesh: shapes::cylinder(1.0, 5.0, 16) };
        let e = Scene::assemble(one_hole, &[(&pin, 0.0)], pose).unwrap_err().to_string();
        assert!(e.contains("pin") && e.contains("cannot rest"), "{e}");
    }
}
