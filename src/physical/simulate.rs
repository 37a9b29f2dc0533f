//! Simulation-based plausibility (paper section 2.2, "Simulation-based
//! formulation"): place the scene in rapier, step a few steps, set the
//! velocities back to zero, repeat; a plausible static scene barely moves.
//! Resetting the velocities keeps an intersecting estimate from
//! "exploding": each round can only move objects by what a few steps of
//! gravity and contact resolution do.
//!
//! Colliders: planes are half-spaces (nothing tunnels through them), static
//! objects are their triangle meshes, dynamic objects the convex hull of
//! their vertices (exact for convex objects; VeREFINE also simulates hulls).
//! Mass properties come from the closed mesh (`mesh::mass`), not from the
//! collider, so a concave object keeps its true centre of mass.

use glam::{DQuat, DVec3, Quat, Vec3};
use rapier3d::prelude::{ColliderBuilder, PhysicsWorld, RigidBodyBuilder, SharedShape};
use serde::Serialize;

use super::scene::Scene;
use crate::pose::Pose;
use crate::error::{Error, Result};
use crate::mesh::mass::MassProperties;

/// Simulation settings. Defaults: the reference values of VeREFINE (dt
/// 1/60 s, 3 steps per round), 10 rounds (0.5 s of simulated time in all),
/// friction 0.5, 10 solver iterations.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SimSettings {
    pub dt: f64,
    /// Steps per round; velocities are reset to zero after each round.
    pub steps: usize,
    pub rounds: usize,
    pub friction: f64,
    pub solver_iterations: usize,
}

/// Most simulation steps (rounds × steps per round) one check runs.
pub const MAX_STEPS: usize = 1_000_000;

impl Default for SimSettings {
    fn default() -> Self {
        SimSettings {
            dt: 1.0 / 60.0,
            steps: 3,
            rounds: 10,
            friction: 0.5,
            solver_iterations: 10,
        }
    }
}

/// Displacement of one object after a round.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Displacement {
    /// Simulated time since the start (s).
    pub time_s: f64,
    /// Distance the model origin moved (m).
    pub translation: f64,
    /// Angle of the rotation since the start (degrees).
    pub rotation_deg: f64,
}

/// A scene in rapier, kept alive between rounds: the world, and each
/// object's body (`None` for static objects).
pub struct SimWorld {
    world: PhysicsWorld,
    handles: Vec<Option<rapier3d::prelude::RigidBodyHandle>>,
    steps: usize,
}

fn rapier_pose(p: &Pose) -> rapier3d::math::Pose {
    let q = DQuat::from_mat3(&p.r);
    rapier3d::math::Pose::from_parts(p.t.as_vec3(), Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize())
}

/// An object's colliders and mass, built once and placed in many worlds:
/// the hull of its vertices (when dynamic), its triangle mesh (when
/// static), and the closed mesh's mass properties.
#[derive(Clone)]
pub struct SimShapes {
    pub name: String,
    pub hull: SharedShape,
    pub trimesh: SharedShape,
    pub mass: MassProperties,
}

impl SimShapes {
    pub fn new(name: &str, mesh: &crate::mesh::Mesh) -> Result<SimShapes> {
        let verts: Vec<Vec3> = mesh.vertices.iter().map(|v| v.as_vec3()).collect();
        let trimesh = SharedShape::trimesh(verts.clone(), mesh.triangles.clone())
            .map_err(|e| Error::InvalidInput(format!("{name}: cannot build a collider: {e}")))?;
        let hull = hull_collider(name, &mesh.vertices)?;
        let (mass, _) = MassProperties::of_mesh(mesh)?;
        Ok(SimShapes { name: name.to_string(), hull, trimesh, mass })
    }
}

/// Vertices of the dynamic collider at most (rapier's contacts slow down on
/// hulls with hundreds of vertices) and the distance, as a fraction of the
/// hull's diagonal, that every mesh vertex lies within (0.15 mm on a 0.15 m
/// object).
const COLLIDER_POINTS: usize = 256;
const COLLIDER_TOLERANCE: f64 = 1e-3;

/// The dynamic collider of a mesh: its exact convex hull
/// ([`crate::stable::hull::Hull`]), simplified to [`COLLIDER_POINTS`], as
/// rapier's convex polyhedron. Not parry's hull of all vertices: in `f32`
/// on many coplanar points (a machined ring) it silently left a fifth of
/// the volume out; on the few simplified points it is sound.
pub fn hull_collider(name: &str, vertices: &[DVec3]) -> Result<SharedShape> {
    let (full, _) = crate::stable::hull::Hull::of_mesh_vertices(name, vertices)?;
    let hull = full.simplified(COLLIDER_POINTS, COLLIDER_TOLERANCE * full.diagonal())?;
    let pts: Vec<Vec3> = hull.vertices.iter().map(|v| v.as_vec3()).collect();
    SharedShape::convex_hull(&pts).ok_or_else(|| Error::InvalidInput(format!("{name}: the convex hull of the mesh is degenerate")))
}

/// One object placed in a world: its shapes, pose (model to world), and
/// density when dynamic (`None`: static).
pub struct SimBody<'a> {
    pub shapes: &'a SimShapes,
    pub pose: Pose,
    pub density: Option<f64>,
    /// A static body collides as its convex hull instead of its triangle
    /// mesh: far cheaper when another body starts deep inside it (a wrong
    /// estimate can overlap a placed object by centimetres, and rapier then
    /// generates contacts against hundreds of triangles per step), at the
    /// price of filling its concavities.
    pub static_hull: bool,
}

impl SimWorld {
    /// Places the scene: planes as half-spaces, static objects as triangle
    /// meshes, dynamic ones as the hull of their vertices with the closed
    /// mesh's mass properties.
    pub fn new(scene: &Scene, settings: &SimSettings) -> Result<SimWorld> {
        let shapes: Vec<SimShapes> = scene.objects.iter().map(|o| SimShapes::new(&o.name, &o.mesh)).collect::<Result<_>>()?;
        let bodies: Vec<SimBody> = scene
            .objects
            .iter()
            .zip(&shapes)
            .map(|(o, shapes)| SimBody { shapes, pose: o.pose, density: (!o.is_static).then_some(o.density), static_hull: false })
            .collect();
        let diag = scene.objects.iter().map(|o| o.mesh.diagonal()).sum::<f64>() / scene.objects.len().max(1) as f64;
        SimWorld::from_bodies(&scene.planes, scene.gravity, &bodies, diag, settings)
    }

    /// A world of prebuilt bodies (see [`SimShapes`]); `length_unit` (m) is
    /// the objects' typical size, which rapier scales its tolerances by.
    pub fn from_bodies(planes: &[super::Plane], gravity: DVec3, bodies: &[SimBody], length_unit: f64, settings: &SimSettings) -> Result<SimWorld> {
        // A step over 0.1 s lets a falling object pass through a table in
        // one step, and a million steps is hours: neither is a check.
        if !(settings.dt > 0.0 && settings.dt <= 0.1) || !(1..=MAX_STEPS).contains(&(settings.steps.saturating_mul(settings.rounds))) {
            return Err(Error::InvalidInput(format!(
                "simulation needs a time step in (0, 0.1] s (got {}) and 1 to {MAX_STEPS} steps in all (got {} rounds of {})",
                settings.dt, settings.rounds, settings.steps
            )));
        }
        let mut world = PhysicsWorld::new();
        world.gravity = gravity.as_vec3();
        let ip = &mut world.integration_parameters;
        ip.dt = settings.dt as f32;
        ip.length_unit = length_unit.max(1e-3) as f32;
        ip.num_solver_iterations = settings.solver_iterations.max(1);
        let mu = settings.friction as f32;
        for p in planes {
            world.colliders.insert(ColliderBuilder::new(SharedShape::halfspace(p.normal.as_vec3())).translation(p.point.as_vec3()).friction(mu));
        }
        let mut handles = Vec::new();
        for b in bodies {
            let pose = rapier_pose(&b.pose);
            match b.density {
                None => {
                    let h = world.insert_body(RigidBodyBuilder::fixed().pose(pose));
                    let shape = if b.static_hull { &b.shapes.hull } else { &b.shapes.trimesh };
                    world.colliders.insert_with_parent(ColliderBuilder::new(shape.clone()).friction(mu), h, &mut world.bodies);
                    handles.push(None);
                }
                Some(density) => {
                    let mprops = b.shapes.mass.to_rapier(density);
                    let h = world.insert_body(RigidBodyBuilder::dynamic().pose(pose).additional_mass_properties(mprops).can_sleep(false));
                    world.colliders.insert_with_parent(ColliderBuilder::new(b.shapes.hull.clone()).density(0.0).friction(mu), h, &mut world.bodies);
                    handles.push(Some(h));
                }
            }
        }
        Ok(SimWorld { world, handles, steps: settings.steps })
    }

    /// Moves dynamic object `i` to `pose`, at rest.
    pub fn set_pose(&mut self, i: usize, pose: &Pose) {
        if let Some(b) = self.handles[i].and_then(|h| self.world.bodies.get_mut(h)) {
            b.set_position(rapier_pose(pose), true);
            b.set_linvel(Vec3::ZERO, true);
            b.set_angvel(Vec3::ZERO, true);
        }
    }

    /// One round: `steps` steps, then every velocity back to zero.
    pub fn round(&mut self) {
        for _ in 0..self.steps {
            self.world.step();
        }
        for h in self.handles.iter().flatten() {
            if let Some(b) = self.world.bodies.get_mut(*h) {
                b.set_linvel(Vec3::ZERO, true);
                b.set_angvel(Vec3::ZERO, true);
            }
        }
    }

    /// The pose of dynamic object `i` (`None` for a static one).
    pub fn pose(&self, i: usize) -> Option<Pose> {
        let b = self.world.bodies.get(self.handles[i]?)?;
        let p = b.position();
        let r = p.rotation;
        let q = DQuat::from_xyzw(r.x as f64, r.y as f64, r.z as f64, r.w as f64).normalize();
        Some(Pose::new(glam::DMat3::from_quat(q), DVec3::new(p.translation.x as f64, p.translation.y as f64, p.translation.z as f64)))
    }
}

/// Per object (in scene order): the displacement after every round, or
/// `None` for static objects.
pub fn displacement(scene: &Scene, settings: &SimSettings) -> Result<Vec<Option<Vec<Displacement>>>> {
    displacement_until(scene, settings, &crate::stop::Stop::default())
}

/// [`displacement`], ending with [`crate::Error::Stopped`] at the next
/// round once `stop` is requested (a long simulation from the Python
/// binding, on Ctrl-C).
pub fn displacement_until(scene: &Scene, settings: &SimSettings, stop: &crate::stop::Stop) -> Result<Vec<Option<Vec<Displacement>>>> {
    let _span = tracing::trace_span!("simulate", rounds = settings.rounds).entered();
    let mut sim = SimWorld::new(scene, settings)?;
    let mut out: Vec<Option<Vec<Displacement>>> = sim.handles.iter().map(|h| h.map(|_| Vec::new())).collect();
    for round in 0..settings.rounds {
        stop.check()?;
        sim.round();
        let time_s = ((round + 1) * settings.steps) as f64 * settings.dt;
        for (i, o) in scene.objects.iter().enumerate() {
            let (Some(p), Some(v)) = (sim.pose(i), out[i].as_mut()) else { continue };
            let angle = DQuat::from_mat3(&o.pose.r).angle_between(DQuat::from_mat3(&p.r)).to_degrees();
            v.push(Displacement { time_s, translation: (p.t - o.pose.t).length(), rotation_deg: angle });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A machined ring in millimetres: thousands of points on circles at
    /// three heights (coplanar and cocircular; parry's f32 hull of all
    /// points finds no hull here, and lost a fifth of pybullet's
    /// `diff_ring.stl`). The collider keeps the ring's hull volume, two
    /// frusta of radius 52.9 -> 53.9 -> 52.9 mm.
    #[test]
    fn ring_collider_keeps_the_hull_volume() {
        let s = 52.88;
        let mut pts = Vec::new();
        for (z, r) in [(0.0, 1.0), (0.0, 0.8), (0.1, 1.02), (0.2, 1.0), (0.2, 0.8)] {
            for k in 0..3000 {
                let a = k as f64 * std::f64::consts::TAU / 3000.0;
                pts.push(DVec3::new(r * a.cos(), r * a.sin(), z) * s - DVec3::Z * 25.0);
            }
        }
        let shape = hull_collider("ring", &pts).unwrap();
        let volume = shape.mass_properties(1.0).mass() as f64;
        let area = |r: f64| std::f64::consts::PI * r * r;
        let exact = s.powi(3) * 2.0 * 0.1 / 3.0 * (area(1.0) + area(1.02) + (area(1.0) * area(1.02)).sqrt());
        assert!((volume / exact - 1.0).abs() < 5e-3, "{volume} vs {exact}");
    }
}
