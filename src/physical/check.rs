//! Checking a whole scene: every object against the planes and all other
//! objects, with the exact CPU twin (a scene has few objects; the GPU path
//! is for batches of hypotheses, see [`super::gpu`]).

use std::sync::Arc;

use glam::DVec3;

use super::contacts::{
    evaluate_detailed, Body, Detail, Environment, Evaluation, Obstacle, SampleClass, Verdict,
};
use super::friction::static_equilibrium;
use super::samples::{DEFAULT_SAMPLES, DEFAULT_SEED};
use super::scene::Scene;
use super::simulate::Displacement;
use super::sdf::{SdfGrid, DEFAULT_RESOLUTION};
use crate::error::Result;
use crate::mesh::mass::MassProperties;
use crate::mesh::Mesh;

/// Options of a scene check.
#[derive(Clone, Debug)]
pub struct CheckOptions {
    /// Surface samples per object.
    pub samples: usize,
    /// Seed of the surface sampling.
    pub seed: u64,
    /// ε in metres; `None`: per object from its sample spacing.
    pub epsilon: Option<f64>,
    /// SDF grid cells across each mesh's longest side.
    pub sdf_resolution: usize,
    /// Friction coefficient μ of the static-equilibrium check.
    pub friction: f64,
    /// Checked before each object is prepared and checked: a scene of
    /// hundreds of objects at a fine SDF takes minutes, and a caller (the
    /// Python binding on Ctrl-C) may want it to end.
    pub stop: crate::stop::Stop,
}

impl Default for CheckOptions {
    fn default() -> Self {
        CheckOptions {
            samples: DEFAULT_SAMPLES,
            seed: DEFAULT_SEED,
            epsilon: None,
            sdf_resolution: DEFAULT_RESOLUTION,
            friction: super::friction::DEFAULT_FRICTION,
            stop: Default::default(),
        }
    }
}

/// The check of one object.
#[derive(Clone, Debug)]
pub struct ObjectCheck {
    pub name: String,
    pub is_static: bool,
    pub epsilon: f64,
    /// Largest trilinear error bound of the grids it was checked against.
    pub grid_error_bound: f64,
    pub mass_kg: f64,
    pub com_world: DVec3,
    pub evaluation: Evaluation,
    /// Static equilibrium with friction (eq. 10-12) over all contacts, for
    /// feasible dynamic objects: `Some(true)` balanced, `Some(false)` not;
    /// `None` when not feasible, static, or undecided by the solver.
    pub friction_equilibrium: Option<bool>,
    pub detail: Detail,
    /// What computing the mesh's mass properties noticed (faces re-wound,
    /// an open mesh taken as its hull): the mass and centre rest on it.
    pub notes: Vec<String>,
}

impl ObjectCheck {
    /// The friction check and the support polygon disagree (typically an
    /// object leaning on another: contacts that are not on one plane).
    pub fn methods_disagree(&self) -> bool {
        self.friction_equilibrium
            .is_some_and(|f| f != self.evaluation.stable)
    }
}

/// Displacement under the simulation, as reported.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DisplacementRecord {
    /// After the last round: distance the origin moved (m) ...
    pub translation: f64,
    /// ... and rotation angle (degrees).
    pub rotation_deg: f64,
    /// After every round.
    pub series: Vec<Displacement>,
}

/// One object's check as reported (`plausible check --json`, the Python
/// `check`): the verdict and its reasons, flat.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CheckRecord<'a> {
    pub name: &'a str,
    pub verdict: &'static str,
    #[serde(rename = "static")]
    pub is_static: bool,
    pub intersecting: u32,
    pub contact: u32,
    pub supported: u32,
    pub min_distance: f64,
    pub stability_margin: Option<f64>,
    /// Static equilibrium with friction: true / false, null when not
    /// feasible, static or undecided.
    pub friction_equilibrium: Option<bool>,
    /// The friction check and the support polygon disagree.
    pub methods_disagree: bool,
    /// With the simulation (dynamic objects): displacement over time.
    pub displacement: Option<DisplacementRecord>,
    pub feasible: bool,
    pub stable: bool,
    pub epsilon: f64,
    pub grid_error_bound: f64,
    pub mass_kg: f64,
    pub centre_of_mass: [f64; 3],
    /// What computing the mesh's mass properties noticed.
    pub notes: &'a [String],
}

impl ObjectCheck {
    /// The check as reported, with the simulation's displacements when
    /// there are any.
    pub fn record(&self, sim: Option<&[Displacement]>) -> CheckRecord<'_> {
        let e = &self.evaluation;
        CheckRecord {
            name: &self.name,
            verdict: e.verdict.as_str(),
            is_static: self.is_static,
            intersecting: e.intersecting,
            contact: e.contact,
            supported: e.supported,
            min_distance: e.min_distance,
            stability_margin: e.stability_margin,
            friction_equilibrium: self.friction_equilibrium,
            methods_disagree: self.methods_disagree(),
            displacement: sim.and_then(|v| {
                v.last().map(|l| DisplacementRecord { translation: l.translation, rotation_deg: l.rotation_deg, series: v.to_vec() })
            }),
            feasible: e.feasible,
            stable: e.stable,
            epsilon: self.epsilon,
            grid_error_bound: self.grid_error_bound,
            mass_kg: self.mass_kg,
            centre_of_mass: self.com_world.to_array(),
            notes: &self.notes,
        }
    }
}

/// A scene's objects with their prepared bodies and grids (shared between
/// objects with the same mesh).
pub struct Prepared {
    pub bodies: Vec<Body>,
    pub grids: Vec<Arc<SdfGrid>>,
    pub mass: Vec<MassProperties>,
    /// Per object: what its mass properties' computation noticed.
    pub notes: Vec<Vec<String>>,
}

/// One mesh's body, grid, mass properties and their notes, shared by the
/// objects that use it.
type MeshPrepared = (Arc<Mesh>, Body, Arc<SdfGrid>, MassProperties, Vec<String>);

/// Samples, mass properties and grids for every object.
pub fn prepare(scene: &Scene, opts: &CheckOptions) -> Result<Prepared> {
    let _span = tracing::trace_span!("prepare", objects = scene.objects.len()).entered();
    let mut done: Vec<MeshPrepared> = Vec::new();
    let (mut bodies, mut grids, mut mass, mut notes) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for o in &scene.objects {
        opts.stop.check()?;
        let found = done.iter().find(|(m, ..)| Arc::ptr_eq(m, &o.mesh));
        let (b, g, mp, n) = match found {
            Some((_, b, g, mp, n)) => (b.clone(), g.clone(), mp.clone(), n.clone()),
            None => {
                // A mesh's error names the object (a scene may hold dozens).
                let named = |e: crate::Error| crate::Error::InvalidInput(format!("object '{}' ({}): {e}", o.name, o.mesh_path.display()));
                let b = Body::new(&o.mesh, opts.samples, opts.seed, opts.epsilon).map_err(named)?;
                let g = Arc::new(SdfGrid::bake(&o.mesh, opts.sdf_resolution).map_err(named)?);
                let (mp, n) = MassProperties::of_mesh(&o.mesh).map_err(named)?;
                done.push((o.mesh.clone(), b.clone(), g.clone(), mp.clone(), n.clone()));
                (b, g, mp, n)
            }
        };
        bodies.push(b);
        grids.push(g);
        mass.push(mp);
        notes.push(n);
    }
    Ok(Prepared {
        bodies,
        grids,
        mass,
        notes,
    })
}

/// The environment of object `i`: the planes and every other object.
pub fn environment_of(scene: &Scene, prep: &Prepared, i: usize) -> Environment {
    Environment {
        planes: scene.planes.clone(),
        obstacles: scene
            .objects
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(j, o)| Obstacle {
                sdf: prep.grids[j].clone(),
                pose: o.pose,
            })
            .collect(),
        gravity: scene.gravity,
    }
}

/// The depth (δ < −ε, m) of object `i`'s centre of mass inside another
/// object, when it lies inside its own: surface samples alone miss two
/// objects in one place (each sample lies on the other's surface, δ ≈ 0, as
/// for a duplicated detection), while a centre inside both means their
/// volumes overlap by more than ε all round it. A centre outside its own
/// object (a mug's, a ring's) says nothing and is skipped.
fn interior_overlap(prep: &Prepared, i: usize, pose: &crate::pose::Pose, env: &Environment, eps: f64) -> Option<f64> {
    let com = prep.mass[i].com;
    if prep.grids[i].exact(com).delta >= -eps {
        return None;
    }
    let x = pose.transform_point(com);
    env.obstacles
        .iter()
        .map(|o| o.sdf.exact(o.pose.r.transpose() * (x - o.pose.t)).delta)
        .filter(|d| *d < -eps)
        .reduce(f64::min)
}

/// Checks every object of the scene. Static objects are held in place:
/// their verdict is intersecting or plausible.
pub fn check_scene(scene: &Scene, opts: &CheckOptions) -> Result<Vec<ObjectCheck>> {
    let prep = prepare(scene, opts)?;
    let mut out = Vec::new();
    for (i, o) in scene.objects.iter().enumerate() {
        // One span per object (a scene has a handful), not per sample.
        let _span = tracing::trace_span!("check_object", object = %o.name).entered();
        opts.stop.check()?;
        let env = environment_of(scene, &prep, i);
        let body = &prep.bodies[i];
        env.check_epsilon(body.epsilon)?;
        let (mut e, detail) = evaluate_detailed(body, &o.pose, &env);
        if let Some(delta) = interior_overlap(&prep, i, &o.pose, &env, body.epsilon) {
            e.intersecting += 1;
            e.min_distance = e.min_distance.min(delta);
            e.feasible = false;
            e.stable = false;
            e.verdict = Verdict::Intersecting;
        }
        if o.is_static {
            e.verdict = if e.intersecting > 0 {
                Verdict::Intersecting
            } else {
                Verdict::Plausible
            };
        }
        let com_world = o.pose.transform_point(prep.mass[i].com);
        let friction_equilibrium = if e.feasible && !o.is_static {
            if !(opts.friction.is_finite() && opts.friction >= 0.0) {
                return Err(crate::Error::InvalidInput(format!(
                    "friction coefficient must be ≥ 0, got {}",
                    opts.friction
                )));
            }
            let (mut pts, mut normals) = (Vec::new(), Vec::new());
            for (j, c) in detail.classes.iter().enumerate() {
                if matches!(c, SampleClass::Contact | SampleClass::Supported) {
                    pts.push(detail.world[j]);
                    normals.push(detail.normal[j]);
                }
            }
            static_equilibrium(
                &pts,
                &normals,
                com_world,
                scene.gravity,
                opts.friction,
                o.mesh.diagonal(),
            )
        } else {
            None
        };
        out.push(ObjectCheck {
            name: o.name.clone(),
            is_static: o.is_static,
            epsilon: body.epsilon,
            grid_error_bound: env.error_bound(),
            mass_kg: prep.mass[i].mass(o.density),
            com_world,
            evaluation: e,
            friction_equilibrium,
            detail,
            notes: prep.notes[i].clone(),
        });
    }
    Ok(out)
}
