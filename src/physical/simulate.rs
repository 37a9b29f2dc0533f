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
use crate::error::{Error, Result};
use crate::mesh::mass::MassProperties;

/// Simulation settings. Defaults: the reference values of VeREFINE (dt
/// 1/60 s, 3 steps per round), 10 rounds (0.5 s of simulated time in all),
/// friction 0.5, 10 solver iterations.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimSettings {
    pub dt: f64,
    /// Steps per round; velocities are reset to zero after each round.
    pub steps: usize,
    pub rounds: usize,
    pub friction: f64,
    pub solver_iterations: usize,
}

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

/// Per object (in scene order): the displacement after every round, or
/// `None` for static objects.
pub fn displacement(
    scene: &Scene,
    settings: &SimSettings,
) -> Result<Vec<Option<Vec<Displacement>>>> {
    if !(settings.dt > 0.0 && settings.dt.is_finite())
        || settings.steps == 0
        || settings.rounds == 0
    {
        return Err(Error::InvalidInput(
            "simulation needs dt > 0, steps ≥ 1 and rounds ≥ 1".into(),
        ));
    }
    let mut world = PhysicsWorld::new();
    world.gravity = scene.gravity.as_vec3();
    let diag = scene.objects.iter().map(|o| o.mesh.diagonal()).sum::<f64>()
        / scene.objects.len().max(1) as f64;
    let ip = &mut world.integration_parameters;
    ip.dt = settings.dt as f32;
    ip.length_unit = diag.max(1e-3) as f32;
    ip.num_solver_iterations = settings.solver_iterations.max(1);
    let mu = settings.friction as f32;
    for p in &scene.planes {
        world.colliders.insert(
            ColliderBuilder::new(SharedShape::halfspace(p.normal.as_vec3()))
                .translation(p.point.as_vec3())
                .friction(mu),
        );
    }
    let mut handles = Vec::new();
    for o in &scene.objects {
        let q = DQuat::from_mat3(&o.pose.r);
        let pose = rapier3d::math::Pose::from_parts(
            o.pose.t.as_vec3(),
            Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize(),
        );
        let verts: Vec<Vec3> = o.mesh.vertices.iter().map(|v| v.as_vec3()).collect();
        if o.is_static {
            let shape = SharedShape::trimesh(verts, o.mesh.triangles.clone()).map_err(|e| {
                Error::InvalidInput(format!("{}: cannot build a collider: {e}", o.name))
            })?;
            let h = world.insert_body(RigidBodyBuilder::fixed().pose(pose));
            world.colliders.insert_with_parent(
                ColliderBuilder::new(shape).friction(mu),
                h,
                &mut world.bodies,
            );
            handles.push(None);
        } else {
            let shape = SharedShape::convex_hull(&verts).ok_or_else(|| {
                Error::InvalidInput(format!(
                    "{}: the convex hull of the mesh is degenerate",
                    o.name
                ))
            })?;
            let (m, _) = MassProperties::of_mesh(&o.mesh)?;
            let mprops = m.to_rapier(o.density);
            let h = world.insert_body(
                RigidBodyBuilder::dynamic()
                    .pose(pose)
                    .additional_mass_properties(mprops)
                    .can_sleep(false),
            );
            world.colliders.insert_with_parent(
                ColliderBuilder::new(shape).density(0.0).friction(mu),
                h,
                &mut world.bodies,
            );
            handles.push(Some(h));
        }
    }
    let mut out: Vec<Option<Vec<Displacement>>> =
        handles.iter().map(|h| h.map(|_| Vec::new())).collect();
    for round in 0..settings.rounds {
        for _ in 0..settings.steps {
            world.step();
        }
        let time_s = ((round + 1) * settings.steps) as f64 * settings.dt;
        for (i, h) in handles.iter().enumerate() {
            let Some(h) = h else { continue };
            let Some(b) = world.bodies.get_mut(*h) else {
                continue;
            };
            let p = b.position();
            let t = DVec3::new(
                p.translation.x as f64,
                p.translation.y as f64,
                p.translation.z as f64,
            );
            let r = p.rotation;
            let q = DQuat::from_xyzw(r.x as f64, r.y as f64, r.z as f64, r.w as f64).normalize();
            let q0 = DQuat::from_mat3(&scene.objects[i].pose.r);
            let angle = q0.angle_between(q).to_degrees();
            if let Some(v) = out[i].as_mut() {
                v.push(Displacement {
                    time_s,
                    translation: (t - scene.objects[i].pose.t).length(),
                    rotation_deg: angle,
                });
            }
            b.set_linvel(Vec3::ZERO, true);
            b.set_angvel(Vec3::ZERO, true);
        }
    }
    Ok(out)
}
