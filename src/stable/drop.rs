//! Drop tests in rapier3d: rigid bodies in uniformly random orientations
//! fall onto a static half-space (z = 0, so nothing tunnels through it) and
//! are simulated until each is at rest or a time cap is reached.
//!
//! [`DROPS_PER_WORLD`] drops share one world, side by side, colliding only
//! with the ground. Which drops share a world is fixed by their indices
//! ([`world_members`]), and a world starts fresh, so a drop's result depends
//! only on its world's inputs (body, parameters, the members' random
//! orientations), never on which worker ran it or what that worker simulated
//! before: results are identical for any thread count, sharding and
//! resumption.

use glam::{DQuat, DVec2, DVec3, Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rapier3d::prelude::*;
use sha2::{Digest, Sha256};

use crate::mesh::mass::MassProperties;

/// Simulation parameters of the drop tests. Lengths scale with the object's
/// bounding-box diagonal so one set of defaults serves a 5 cm screw and a
/// 30 cm bottle.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimParams {
    /// Time step in seconds. 1/240 s: the resting-pose frequencies converge
    /// there (1/480 s gives the same within the confidence intervals) and
    /// agree with pybullet's; at 1/60 s the poses are the same but their
    /// frequencies shift (e.g. 16 % vs 8 % for the upright duck).
    pub dt: f64,
    /// Simulated-time cap per drop (s) for an object of [`REFERENCE_DIAG`];
    /// drops not at rest by then are unsettled. Other sizes are
    /// time-scaled as a whole (see [`SimParams::for_size`]): a 1.6 m object
    /// gets 33 s.
    pub max_time: f64,
    /// Drop height: gap between the lowest hull point and the plane at
    /// release, in bounding diagonals (1.5 ≈ the pybullet peer's 0.3 m drop
    /// of a 0.15 m object). The free fall is computed in closed form.
    pub drop_height_diag: f64,
    /// At rest: linear speed below this many diagonals per second ...
    pub lin_tol_diag: f64,
    /// ... and angular speed below this (rad/s) ...
    pub ang_tol: f64,
    /// ... for this long (s). 0.05 s (12 steps at 240 Hz) gives the
    /// results of the 0.1 s used before in 12 fewer steps per drop
    /// (0.97-1.33× the drops/s on 25 meshes, the lego brick 1.11-1.23×).
    /// Of 25,000 paired drops on the 25 meshes of `../shared/data`
    /// (pybullet, YCB, robosuite), 32 (0.13 %) came to rest more than 5°
    /// from where the 0.1 s test left them: 30 by 5-18° (cans that rolled
    /// on, the bunny and the rock creeping a little) and 2 in another pose
    /// (56°, 78°). None more or fewer were settled, and every cluster
    /// stayed inside its 95 % interval. 0.033 s moved 93 (0.37 %), 3.4 %
    /// of a can's. The support-polygon test, not the calm time, is what
    /// keeps a body balanced on an edge from counting as resting.
    pub calm_time: f64,
    pub friction: f64,
    pub restitution: f64,
    /// Density in kg/m³ (uniform); only scales forces, not resting poses.
    pub density: f64,
    /// Solver iterations per step (rapier's default is 4).
    pub solver_iterations: usize,
    /// Contact prediction distance in bounding diagonals (rapier's default is
    /// 0.02 length units). Contacts closer than this are solved
    /// speculatively, so a body falling `v·dt` per step meets the plane on
    /// time instead of sinking in and being pushed out.
    pub prediction_diag: f64,
    /// Continuous collision detection on the dropped body. When off, rapier's
    /// automatic sweeps of fast bodies (`max_ccd_substeps`) are off too:
    /// against the half-space, whose speculative contacts already stop the
    /// body, they changed no drop (bit-identical on the 19 meshes of
    /// `../shared/data`), yet the thin support pieces of large faces
    /// (see `collider_shapes`) made the body count as fast at most steps, and
    /// sweeping every collider (recomputing its mass properties) took up to
    /// 40 % of a step.
    pub ccd: bool,
}

/// Object size (bounding diagonal, m) that [`SimParams::max_time`] is given for.
pub const REFERENCE_DIAG: f64 = 0.15;

/// Bounding diagonals (m) simulated at their own size. Time-scaled drops
/// ([`SimParams::for_size`]) gave the clusters of the 0.15 m drop at every
/// size tried from 3 mm to 10 m, but rapier works in `f32` with some
/// absolute tolerances: a tetrahedron of 14 µm settled in 120 of 128 drops,
/// of 0.14 µm 99, of 1.7 nm none (its inertia, about 1e-42 kg·m², is below
/// `f32`'s normal range), and of 17 km none either. Outside this range the
/// body is a copy scaled to [`REFERENCE_DIAG`] ([`simulation_scale`]):
/// resting poses are the same at any size, and heights are scaled back.
pub const SIMULATED_DIAG: std::ops::RangeInclusive<f64> = 1e-3..=100.0;

/// The factor the drop body is scaled by for an object of bounding diagonal
/// `diagonal`: 1 inside [`SIMULATED_DIAG`], else what makes it
/// [`REFERENCE_DIAG`] across.
pub fn simulation_scale(diagonal: f64) -> f64 {
    if SIMULATED_DIAG.contains(&diagonal) {
        1.0
    } else {
        REFERENCE_DIAG / diagonal
    }
}

/// How much slower than a [`REFERENCE_DIAG`] object one of bounding
/// diagonal `diagonal` moves under gravity: √(diagonal / 0.15 m) (Froude
/// similarity).
fn time_scale(diagonal: f64) -> f64 {
    (diagonal / REFERENCE_DIAG).sqrt()
}

impl SimParams {
    /// The parameters a drop of an object of bounding diagonal `diagonal`
    /// runs with: every time (step, calm time, cap) is multiplied by s =
    /// √(diagonal / 0.15 m) and every speed threshold divided by it (and
    /// rapier's contact springs' frequencies divided by s in
    /// [`empty_world`]). With gravity fixed and lengths already in
    /// diagonals, the drop is then the 0.15 m drop played faster or slower
    /// (Froude similarity), in as many steps, with the same resting poses:
    /// a rigid body's are the same at any size. With absolute times a small
    /// object rocked on its face for long (the rock `random_000.obj` at 1 cm:
    /// 81 % of drops settled within 10 s, 552 steps per drop; a 1 cm pencil
    /// 40 %; time-scaled 100 %, 176 and 88 steps), and a large one was taken
    /// to be at rest while still tipping, its angular speed under the
    /// absolute 0.05 rad/s (pybullet's `duck_vhacd.obj` at its own 2.5 m:
    /// clusters of 0.38 and 0.09 at 3° and 11° from its top facet; at 10 m
    /// none above 6 %). Time-scaled, it has the same clusters as at 0.15 m
    /// at every size tried from 3 mm to 10 m, in ~430 steps per drop (1,950
    /// drops/s at 10 m, 342 before).
    pub fn for_size(&self, diagonal: f64) -> SimParams {
        let s = time_scale(diagonal);
        SimParams {
            dt: self.dt * s,
            calm_time: self.calm_time * s,
            max_time: self.max_time * s,
            lin_tol_diag: self.lin_tol_diag / s,
            ang_tol: self.ang_tol / s,
            ..self.clone()
        }
    }
}

impl Default for SimParams {
    fn default() -> Self {
        SimParams {
            dt: 1.0 / 240.0,
            max_time: 10.0,
            drop_height_diag: 1.5,
            lin_tol_diag: 0.02,
            ang_tol: 0.05,
            calm_time: 0.05,
            friction: 0.5,
            restitution: 0.0,
            density: 1000.0,
            solver_iterations: 4,
            prediction_diag: 0.02,
            ccd: false,
        }
    }
}

/// What one drop ended in.
#[derive(Clone, Debug, PartialEq)]
pub struct DropResult {
    pub index: u64,
    /// Came to rest before the time cap.
    pub settled: bool,
    /// Simulated steps (after the closed-form free fall).
    pub steps: u32,
    /// Final orientation, model to plane frame (w, x, y, z order in storage).
    pub rotation: DQuat,
    /// Final height of the model origin above the plane (m), consistent with
    /// `rotation` (`x_plane = R x_model + (·, ·, height)`).
    pub height: f64,
    /// Gravity direction in the model frame: `R⁻¹ (0, 0, -1)`.
    pub gravity_in_model: DVec3,
}

/// The rigid body dropped: collider shapes (all attached to one body) plus
/// mass properties from the mesh.
///
/// Everything is in the body frame: the model frame moved to the centre of
/// mass ([`DropBody::origin`]), the offset taken off in f64 before the
/// shapes go to rapier's f32. In the model frame a mesh far from its origin
/// (a box 10 km away) had its collider rounded to millimetres and its
/// contacts computed from the differences of large f32 numbers: 17 of 64
/// drops settled. The drops' results are mapped back to the model frame
/// ([`DropResult`]'s rotation and height are the model's).
#[derive(Clone)]
pub struct DropBody {
    /// Collider shapes, body frame.
    pub shapes: Vec<SharedShape>,
    /// Per shape: whether it is a support piece (else a hull part).
    pub is_piece: Vec<bool>,
    /// Vertices of the collider (body frame) used to place the body.
    pub support: Vec<DVec3>,
    /// Mass properties in the body frame (centre of mass at its origin).
    pub mass: MassProperties,
    /// Bounding diagonal in body units.
    pub diagonal: f64,
    /// Where the body frame's origin lies in the model frame (the centre of
    /// mass), in body units: `x_model = (x_body + origin) / scale`, same axes.
    pub origin: DVec3,
    /// Body units per model metre: 1, or the [`simulation_scale`] of an
    /// object too small or too large for rapier's `f32` at its own size.
    pub scale: f64,
}

impl DropBody {
    /// Model-frame pose of a body at rotation `q`, body-frame origin at `t`:
    /// the model origin lies at `t - q·origin`, computed in f64 and given
    /// in model metres.
    pub fn model_pose(&self, q: DQuat, t: DVec3) -> (DQuat, DVec3) {
        (q, (t - q * self.origin) / self.scale)
    }
}

/// Seed of drop `index`: SHA-256 over a domain tag, the mesh hash, the user's
/// seed and the index. Independent of threads and shards by construction.
pub fn drop_seed(mesh_sha256: &str, seed: u64, index: u64) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"plausible/stable-drop/v1\0");
    h.update(mesh_sha256.as_bytes());
    h.update(seed.to_le_bytes());
    h.update(index.to_le_bytes());
    h.finalize().into()
}

/// Uniformly random rotation (Shoemake 1992, subgroup algorithm).
pub fn random_rotation(rng: &mut impl Rng) -> DQuat {
    let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
    let tau = std::f64::consts::TAU;
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    DQuat::from_xyzw(
        a * (tau * u2).sin(),
        a * (tau * u2).cos(),
        b * (tau * u3).sin(),
        b * (tau * u3).cos(),
    )
    .normalize()
}

/// Drops simulated side by side in one world. rapier's contact solver works
/// on four constraints at a time (SIMD lanes), and constraints of one body
/// can never share a lane: a world of one drop left three lanes of four
/// empty and paid the per-step pipeline alone. Measured on the lego brick
/// (7 colliders, 2 threads, 2000 drops): one per world 2,450 drops/s, 8 per
/// world 3,100-3,500, 16 3,500-3,800, 32 4,100-4,200 (bodies that settle
/// leave their world, so a world runs as long as its slowest drop). More
/// per world means fewer worlds to spread over threads: a run of 1000 drops
/// has 32.
pub const DROPS_PER_WORLD: u64 = 32;

/// Distance between neighbouring drops of a world along x, in bounding
/// diagonals: bodies ignore each other (collision groups), so this only
/// keeps rapier's broad phase from pairing them while they lie still.
const SLOT_SPACING_DIAG: f64 = 3.0;

/// The drops that share drop `index`'s world in a run of `drops` drops.
pub fn world_members(index: u64, drops: u64) -> std::ops::Range<u64> {
    let first = index - index % DROPS_PER_WORLD;
    first..first.saturating_add(DROPS_PER_WORLD).min(drops).max(first + 1)
}

/// Runs the drops `members` (one world, see [`world_members`]) for the
/// body; results in index order.
pub fn simulate_world(
    body: &DropBody,
    params: &SimParams,
    mesh_sha256: &str,
    seed: u64,
    members: std::ops::Range<u64>,
) -> Vec<DropResult> {
    run_world(body, params, mesh_sha256, seed, members, None)
}

/// Where a world's time went (seconds): building it, rapier's steps, and
/// the rest tests (velocity thresholds and the support polygon).
#[derive(Clone, Copy, Debug, Default)]
pub struct DropTimes {
    pub setup: f64,
    pub step: f64,
    pub rest_test: f64,
}

impl std::ops::AddAssign for DropTimes {
    fn add_assign(&mut self, o: Self) {
        self.setup += o.setup;
        self.step += o.step;
        self.rest_test += o.rest_test;
    }
}

/// [`simulate_world`] with its time split by stage (the same results). The
/// clock is read twice per step, so only benchmarks ask for it.
pub fn simulate_world_timed(
    body: &DropBody,
    params: &SimParams,
    mesh_sha256: &str,
    seed: u64,
    members: std::ops::Range<u64>,
) -> (Vec<DropResult>, DropTimes) {
    let mut times = DropTimes::default();
    let r = run_world(body, params, mesh_sha256, seed, members, Some(&mut times));
    (r, times)
}

/// How drop `index` starts: orientation, height of the body-frame origin
/// (the centre of mass) and downward speed.
///
/// The body is released at rest, so until it first touches the plane it
/// only translates: that free fall is done in closed form, and the
/// simulation starts a small gap above the plane (two steps of travel at
/// impact speed) with the exact free-fall velocity. Saves about 50 of the
/// ~500 steps of a drop at 240 Hz.
fn release(body: &DropBody, params: &SimParams, mesh_sha256: &str, seed: u64, index: u64) -> (DQuat, f64, f64) {
    let mut rng = ChaCha8Rng::from_seed(drop_seed(mesh_sha256, seed, index));
    let q0 = random_rotation(&mut rng);
    let lowest = body
        .support
        .iter()
        .map(|p| (q0 * *p).z)
        .fold(f64::INFINITY, f64::min);
    let g = 9.81;
    let h0 = (params.drop_height_diag * body.diagonal).max(0.0);
    let v_impact = (2.0 * g * h0).sqrt();
    let gap = (0.02 * body.diagonal)
        .max(2.0 * v_impact * params.dt)
        .min(h0);
    let v0 = (2.0 * g * (h0 - gap)).sqrt();
    (q0, gap - lowest, v0)
}

/// One drop in a world: its body and how far it has come.
struct Slot {
    index: u64,
    /// Its release orientation, for the record of a body rapier lost.
    q0: DQuat,
    handle: RigidBodyHandle,
    /// The body's support pieces (switched on and off by
    /// [`update_pieces`]).
    pieces: Vec<ColliderHandle>,
    /// Consecutive still steps.
    calm: u32,
    result: Option<DropResult>,
}

/// One world's drops, its stages timed into `times` when given.
fn run_world(
    body: &DropBody,
    params: &SimParams,
    mesh_sha256: &str,
    seed: u64,
    members: std::ops::Range<u64>,
    mut times: Option<&mut DropTimes>,
) -> Vec<DropResult> {
    let t_setup = times.is_some().then(std::time::Instant::now);
    let params = &params.for_size(body.diagonal);
    let mut world = empty_world(body, params);
    let mut slots: Vec<Slot> = members
        .enumerate()
        .map(|(j, index)| {
            let (q0, z0, v0) = release(body, params, mesh_sha256, seed, index);
            let x = j as f64 * SLOT_SPACING_DIAG * body.diagonal;
            let (handle, pieces) = insert_drop(&mut world, body, params, q0, DVec3::new(x, 0.0, z0), v0);
            Slot { index, q0, handle, pieces, calm: 0, result: None }
        })
        .collect();
    if let (Some(t), Some(start)) = (times.as_deref_mut(), t_setup) {
        t.setup += start.elapsed().as_secs_f64();
    }
    run_until_settled(&mut world, &mut slots, body, params, times);
    slots.into_iter().filter_map(|s| s.result).collect()
}

/// Collision groups: the ground meets the bodies, the bodies only the
/// ground.
fn groups(ground: bool) -> InteractionGroups {
    let (me, other) = if ground { (Group::GROUP_1, Group::GROUP_2) } else { (Group::GROUP_2, Group::GROUP_1) };
    InteractionGroups::new(me, other, InteractionTestMode::And)
}

/// A world with the ground half-space and no body yet, for `body` whose
/// `params` are already [`SimParams::for_size`].
fn empty_world(body: &DropBody, params: &SimParams) -> PhysicsWorld {
    let mut world = PhysicsWorld::new();
    world.gravity = Vec3::new(0.0, 0.0, -9.81);
    let ip = &mut world.integration_parameters;
    ip.dt = params.dt as f32;
    ip.length_unit = body.diagonal as f32;
    ip.num_solver_iterations = params.solver_iterations.max(1);
    // normalized_prediction_distance is in units of length_unit (= diagonal).
    ip.normalized_prediction_distance = params.prediction_diag as f32;
    // rapier's contact springs have absolute natural frequencies (30 Hz,
    // 60 Hz against the ground); a body time-scaled by SimParams::for_size
    // gets them scaled by the same factor (stiffer when small, softer when
    // large), so it meets the contact as a 0.15 m object does.
    let stiffen = (1.0 / time_scale(body.diagonal)) as f32;
    ip.contact_softness.natural_frequency *= stiffen;
    ip.static_contact_softness.natural_frequency *= stiffen;
    if !params.ccd {
        ip.max_ccd_substeps = 0;
    }
    world.colliders.insert(
        ColliderBuilder::new(SharedShape::halfspace(Vec3::Z))
            .friction(params.friction as f32)
            .restitution(params.restitution as f32)
            .collision_groups(groups(true)),
    );
    world
}

/// Adds one dropped body at `at` with orientation `q0`, falling at `v0`;
/// returns it and its support pieces (switched off: drops start above the
/// ground).
fn insert_drop(
    world: &mut PhysicsWorld,
    body: &DropBody,
    params: &SimParams,
    q0: DQuat,
    at: DVec3,
    v0: f64,
) -> (RigidBodyHandle, Vec<ColliderHandle>) {
    let mprops = body.mass.to_rapier(params.density);
    let rb = RigidBodyBuilder::dynamic()
        .pose(Pose::from_parts(
            at.as_vec3(),
            Quat::from_xyzw(q0.x as f32, q0.y as f32, q0.z as f32, q0.w as f32).normalize(),
        ))
        .linvel(Vec3::new(0.0, 0.0, -v0 as f32))
        .additional_mass_properties(mprops)
        .can_sleep(false)
        .ccd_enabled(params.ccd);
    let handle = world.insert_body(rb);
    let mut pieces = Vec::new();
    for (shape, &piece) in body.shapes.iter().zip(&body.is_piece) {
        let collider = ColliderBuilder::new(shape.clone())
            .density(0.0)
            .friction(params.friction as f32)
            .restitution(params.restitution as f32)
            .collision_groups(groups(false))
            .enabled(!piece);
        let c = world.colliders.insert_with_parent(collider, handle, &mut world.bodies);
        if piece {
            pieces.push(c);
        }
    }
    (handle, pieces)
}

/// How near the ground (in bounding diagonals) a support piece's lowest
/// corner must come for the piece to take part in collisions: far more
/// than the contact prediction distance plus a step's motion.
const PIECE_REACH_DIAG: f64 = 0.1;

/// Switches on the support pieces of the slots' bodies whose lowest corner
/// is within `reach` of the ground, and off the others. A piece switched
/// off could not have touched the ground this step (it is convex, so its
/// lowest point is a corner), so the contacts are those of the whole
/// collider; the pieces away from the ground (most of them, most of the
/// time) just stop costing narrow-phase pairs (lego brick: 12-32 % more
/// drops/s).
fn update_pieces(world: &mut PhysicsWorld, slots: &mut [Slot], reach: f32) {
    for slot in slots.iter_mut().filter(|s| s.result.is_none() && !s.pieces.is_empty()) {
        let Some(b) = world.bodies.get(slot.handle) else { continue };
        let pose = *b.position();
        for &c in &slot.pieces {
            let Some(col) = world.colliders.get_mut(c) else { continue };
            let Some(poly) = col.shape().as_convex_polyhedron() else { continue };
            let at = pose * col.position_wrt_parent().copied().unwrap_or_default();
            let low = poly.points().iter().map(|p| (at * *p).z).fold(f32::INFINITY, f32::min);
            let want = low < reach;
            if want != col.is_enabled() {
                col.set_enabled(want);
            }
        }
    }
}

/// The result of a drop whose body is `b` after `steps` steps, in the
/// model frame.
fn outcome(index: u64, settled: bool, steps: u32, b: &RigidBody, body: &DropBody) -> DropResult {
    let (q, t) = body_pose(b);
    let (rotation, t) = body.model_pose(q, t);
    DropResult {
        index,
        settled,
        steps,
        rotation,
        height: t.z,
        gravity_in_model: (rotation.inverse() * DVec3::NEG_Z).normalize(),
    }
}

/// Steps until every body has been still for `calm_time` in a statically
/// stable pose (it then leaves the world), or the (size-scaled) time cap,
/// which leaves the rest unsettled.
fn run_until_settled(world: &mut PhysicsWorld, slots: &mut [Slot], body: &DropBody, params: &SimParams, mut times: Option<&mut DropTimes>) {
    let max_steps = (params.max_time / params.dt).ceil().max(1.0) as u32;
    let calm_needed = (params.calm_time / params.dt).ceil().max(1.0) as u32;
    let lin_tol = (params.lin_tol_diag * body.diagonal) as f32;
    let ang_tol = params.ang_tol as f32;
    // Seconds since the last lap, when timing.
    let mut clock = times.is_some().then(std::time::Instant::now);
    let mut lap = || {
        clock.as_mut().map_or(0.0, |c| {
            let now = std::time::Instant::now();
            let dt = (now - *c).as_secs_f64();
            *c = now;
            dt
        })
    };
    let mut steps = 0;
    let reach = (PIECE_REACH_DIAG * body.diagonal) as f32;
    while steps < max_steps && slots.iter().any(|s| s.result.is_none()) {
        update_pieces(world, slots, reach);
        world.step();
        steps += 1;
        let dt = lap();
        if let Some(t) = times.as_deref_mut() {
            t.step += dt;
        }
        for slot in slots.iter_mut().filter(|s| s.result.is_none()) {
            let Some(b) = world.bodies.get(slot.handle) else { continue };
            if still_and_supported(slot, b, body, calm_needed, (lin_tol, ang_tol)) {
                slot.result = Some(outcome(slot.index, true, steps, b, body));
                world.remove_body(slot.handle);
            }
        }
        let dt = lap();
        if let Some(t) = times.as_deref_mut() {
            t.rest_test += dt;
        }
    }
    for slot in slots.iter_mut().filter(|s| s.result.is_none()) {
        slot.result = Some(match world.bodies.get(slot.handle) {
            Some(b) => outcome(slot.index, false, steps, b, body),
            None => DropResult {
                index: slot.index,
                settled: false,
                steps,
                rotation: slot.q0,
                height: f64::NAN,
                gravity_in_model: (slot.q0.inverse() * DVec3::NEG_Z).normalize(),
            },
        });
    }
}

/// The rest test of one body after a step: it has been still (speeds below
/// `tol` = (linear, angular)) for `calm_needed` steps in a statically
/// stable pose (centre of mass above the support polygon), not balanced on
/// an edge that has not started to tip yet. Counts the still steps in the
/// slot.
fn still_and_supported(slot: &mut Slot, b: &RigidBody, body: &DropBody, calm_needed: u32, tol: (f32, f32)) -> bool {
    if b.linvel().length() >= tol.0 || b.angvel().length() >= tol.1 {
        slot.calm = 0;
        return false;
    }
    slot.calm += 1;
    if slot.calm < calm_needed {
        return false;
    }
    let (q, t) = body_pose(b);
    let supported = supported(body, q, t);
    if !supported {
        slot.calm = 0;
    }
    supported
}

/// A rigid body's pose in f64.
fn body_pose(b: &rapier3d::dynamics::RigidBody) -> (DQuat, DVec3) {
    let p = b.position();
    let r = p.rotation;
    let q = DQuat::from_xyzw(r.x as f64, r.y as f64, r.z as f64, r.w as f64).normalize();
    (q, DVec3::new(p.translation.x as f64, p.translation.y as f64, p.translation.z as f64))
}

/// Whether the body at rotation `q`, body-frame origin at `t` is statically stable
/// on the plane: the collider vertices within 1 % of the diagonal of the
/// lowest one form the support polygon, and the centre of mass must project
/// inside it by a small margin (0.1 % of the diagonal).
pub fn supported(body: &DropBody, q: DQuat, t: DVec3) -> bool {
    let world: Vec<DVec3> = body.support.iter().map(|p| q * *p + t).collect();
    let low = world.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
    let tol = 0.01 * body.diagonal;
    let pts: Vec<DVec2> = world.iter().filter(|p| p.z <= low + tol).map(|p| p.truncate()).collect();
    let com = q * body.mass.com + t;
    point_in_hull_2d(&pts, com.truncate(), 1e-3 * body.diagonal)
}

/// Whether `p` lies inside the 2D convex hull of `pts` by more than
/// `margin`: the support module's hull and signed margin (the one
/// point-in-polygon test of the crate). Fewer than three hull corners (an
/// edge or a vertex) never contain a point.
fn point_in_hull_2d(pts: &[DVec2], p: DVec2, margin: f64) -> bool {
    let hull = crate::physical::support::convex_hull(pts);
    crate::physical::support::signed_margin(&hull, p).is_some_and(|m| hull.len() >= 3 && m > margin)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn support_polygon_test() {
        let v = |x: f64, y: f64| DVec2::new(x, y);
        let sq = [v(0.0, 0.0), v(1.0, 0.0), v(1.0, 1.0), v(0.0, 1.0), v(0.5, 0.5)];
        assert!(point_in_hull_2d(&sq, v(0.5, 0.5), 0.01));
        assert!(!point_in_hull_2d(&sq, v(1.2, 0.5), 0.01));
        assert!(!point_in_hull_2d(&sq, v(0.995, 0.5), 0.01));
        let edge = [v(0.0, 0.0), v(1.0, 0.0)];
        assert!(!point_in_hull_2d(&edge, v(0.5, 0.0), 0.0));
    }

    #[test]
    fn seeds_differ_per_index_and_rotations_are_unit() {
        assert_ne!(drop_seed("a", 0, 0), drop_seed("a", 0, 1));
        assert_ne!(drop_seed("a", 0, 0), drop_seed("a", 1, 0));
        let mut rng = ChaCha8Rng::from_seed(drop_seed("a", 0, 0));
        let mut mean = DVec3::ZERO;
        for _ in 0..4000 {
            let q = random_rotation(&mut rng);
            assert!((q.length() - 1.0).abs() < 1e-12);
            mean += q * DVec3::Z;
        }
        // Uniform rotations send a fixed axis uniformly over the sphere.
        assert!((mean / 4000.0).length() < 0.05);
    }
}
