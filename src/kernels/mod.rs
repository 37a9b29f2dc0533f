//! GPU kernels and their CPU twins, one host module per shader (as in
//! vello): `raster` (the compute rasterizer all visual kernels share, with
//! the twin `raster_ids`/`resolve`, buffers and wave dispatch), `render`,
//! `depth`, `score`, `plane_contacts` (the score kernel's fused plane
//! stage) and `contacts` (contact classification over plain scene data;
//! `physical::gpu` builds that data from a physical scene and finishes the
//! verdicts). `bvh` is the one CPU-only renderer (ray casting for meshes
//! with many triangles per pixel; no shader, so no twin to keep). Each
//! shader has its CPU twin beside it and owns its WGSL file's `#[repr(C)]`
//! structs, named as in the WGSL (checked field by field); the layouts several
//! kernels share ([`GpuPose`], [`ContactRecord`], [`GpuTriangle`],
//! [`RasterParams`]) live here. `physical` imports
//! `kernels`, never the reverse.
//!
//! The visual kernels rasterize in a compute shader (see `raster`): one
//! workgroup per hypothesis resolves visibility with `atomicMax` on a packed
//! `(quantized inverse depth, triangle id)` key, then recomputes exact depth
//! and the flat face normal from the winning triangle's plane. The score
//! kernel fuses that with the eq. 3-5 alignment and a workgroup reduction,
//! so only one record per hypothesis leaves the GPU.

pub mod bvh;
pub mod contacts;
pub mod depth;
pub mod plane_contacts;
pub mod raster;
pub mod raycast;
pub mod render;
pub mod score;

use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};

use crate::error::{Error, Result};
use crate::mesh::Mesh;
use crate::pose::Pose;

/// The WGSL shared by the visual kernels (bindings 0-3 and the rasterizer).
pub const RASTER_WGSL: &str = include_str!("../../shaders/raster.wgsl");

/// Most triangles a render mesh may have: triangle ids take at most 24 bits
/// of the 32-bit visibility key, leaving at least 8 bits of depth.
pub const MAX_TRIANGLES: usize = 1 << 24;

/// Most meshlets the GPU rasterizer takes (about 500,000 triangles:
/// meshlets hold up to 64), and most region pixels of the score and render
/// kernels. lavapipe silently ends a shader's loops after 65,535 iterations
/// in total per SIMD vector: each of a workgroup's 64 invocations steps
/// through every meshlet (one triangle each) and visits pixels/64 region
/// pixels (twice), so these caps bound those loops to about 25,000
/// iterations; drawing the pixels has its own budget
/// ([`raster::draw_budget`]). Larger meshes are ray-cast on the GPU
/// ([`raycast`]) or, for evaluation renders, drawn by the CPU twin; larger
/// regions are refused with an error; never silent zeros.
pub const MAX_GPU_MESHLETS: usize = 8192;
pub const MAX_GPU_PIXELS: usize = 1 << 20;

/// Refuses work that would exceed the rasterizing kernels' loop budget.
pub fn check_loop_budget(mesh: &RenderMesh, pixels: usize) -> Result<()> {
    if mesh.meshlets.len() > MAX_GPU_MESHLETS {
        return Err(Error::InvalidInput(format!(
            "the mesh has {} triangles in {} meshlets; the GPU kernels take at most {MAX_GPU_MESHLETS} meshlets of {MESHLET_TRIANGLES} triangles (software adapters stop long loops silently): decimate it (--lod), let the GPU ray-cast it (the auto renderer) or use the CPU twin",
            mesh.triangles.len(),
            mesh.meshlets.len()
        )));
    }
    check_pixel_budget(pixels)
}

/// Refuses what the GPU cannot score with the mesh's renderer
/// ([`RenderMesh::gpu_renderer`]) over a region of `pixels`: triangle or
/// meshlet tables taller than the adapter's textures, and the rasterizer's
/// loop budget (meshlets and pixels) or the ray caster's (pixels).
pub fn check_gpu_budget(ctx: &crate::gpu::Context, mesh: &RenderMesh, pixels: usize) -> Result<()> {
    raster::check_mesh_bindings(ctx, mesh)?;
    match mesh.gpu_renderer() {
        CpuRenderer::RayCast => check_pixel_budget(pixels),
        CpuRenderer::Raster => check_loop_budget(mesh, pixels),
    }
}

/// Refuses regions larger than the GPU kernels' loop budget allows.
pub fn check_pixel_budget(pixels: usize) -> Result<()> {
    if pixels > MAX_GPU_PIXELS {
        return Err(Error::InvalidInput(format!(
            "the region has {pixels} pixels; the GPU kernels take at most {MAX_GPU_PIXELS} (1024x1024): use a lower resolution or the CPU twin"
        )));
    }
    Ok(())
}

/// Nothing nearer to the camera than this (m) is drawn: the rasterizer twin
/// clips triangles at this plane (`raster::clipped`), the ray casters
/// start their rays there, and the GPU rasterizers hand a hypothesis with a
/// triangle crossing it to the twin.
pub const NEAR_M: f32 = 1e-3;

/// Why the GPU rasterizers hand a hypothesis to the CPU twin (warnings):
/// its triangles overlap past the loop budget, or one crosses the near
/// plane (the twin clips it there: `raster::clipped`). The kernels report
/// both the same way.
pub(crate) const NOT_DRAWN_ON_GPU: &str = "not drawn by the GPU rasterizer (triangles overlapping past its loop budget, or one crossing the camera's near plane)";

/// "1 hypothesis", "2 hypotheses": counts in warnings.
pub(crate) fn hypotheses(n: usize) -> String {
    format!("{n} {}", if n == 1 { "hypothesis" } else { "hypotheses" })
}

/// One triangle as the GPU sees it: model-space corners and its plane
/// (`n · x = d`, unit outward normal).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuTriangle {
    pub v0: [f32; 4],
    pub v1: [f32; 4],
    pub v2: [f32; 4],
    pub plane: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuTriangle>() == 64);

/// Largest `|A Aᵀ - I|` entry of a pose's linear part still taken for a
/// rotation (the `f32` rows of an `f64` rotation are off by about 1e-7).
pub const RIGID_TOL: f32 = 1e-5;

/// What a pose's linear part `A` does to planes and rays. `A` is a rotation
/// wherever the library makes poses, but a results file under evaluation
/// may hold a slightly sheared or scaled one, which the BOP toolkit renders
/// as given: vertices move by `A`, plane normals by `A⁻ᵀ` (rows `q`), camera
/// rays into the model by `A⁻¹` (columns `q`), and the bounding sphere
/// grows by `stretch`, a bound on `A`'s largest singular value (Gershgorin
/// on `A Aᵀ`). With `A⁻ᵀ` taken as `A`, the depth of such a pose came from
/// tilted planes and its VSD differed from the toolkit's by up to 0.15.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual {
    pub q: [Vec3; 3],
    pub stretch: f32,
    /// Whether `A` is taken for a rotation (`q` are its rows, `stretch` 1).
    pub rigid: bool,
}

impl Dual {
    /// The camera centre in model coordinates, `-A⁻¹t`, for the pose's
    /// translation `t` (the twin of `camera_in_model` in raster.wgsl).
    #[inline]
    pub fn camera(&self, t: Vec3) -> Vec3 {
        -(self.q[0] * t.x + self.q[1] * t.y + self.q[2] * t.z)
    }
}

/// A pose as three rows of `[R | t]` (metres).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable, PartialEq)]
pub struct GpuPose {
    pub rows: [[f32; 4]; 3],
}
const _: () = assert!(std::mem::size_of::<GpuPose>() == 48);

impl From<&Pose> for GpuPose {
    fn from(p: &Pose) -> Self {
        let r = p.r.transpose().to_cols_array_2d(); // rows of R
        let mut rows = [[0.0f32; 4]; 3];
        for i in 0..3 {
            rows[i] = [r[i][0] as f32, r[i][1] as f32, r[i][2] as f32, p.t[i] as f32];
        }
        GpuPose { rows }
    }
}

impl GpuPose {
    #[inline]
    pub fn rotate(&self, v: Vec3) -> Vec3 {
        let r = &self.rows;
        Vec3::new(
            r[0][0] * v.x + r[0][1] * v.y + r[0][2] * v.z,
            r[1][0] * v.x + r[1][1] * v.y + r[1][2] * v.z,
            r[2][0] * v.x + r[2][1] * v.y + r[2][2] * v.z,
        )
    }
    #[inline]
    pub fn transform(&self, v: Vec3) -> Vec3 {
        self.rotate(v) + self.translation()
    }
    /// `-A⁻¹t` (`-Rᵀt` for a rotation): the camera centre in model
    /// coordinates.
    #[inline]
    pub fn inverse_translation(&self) -> Vec3 {
        self.dual().camera(self.translation())
    }

    /// The rows of `A⁻ᵀ` for the linear part `A` and its largest stretch
    /// (see [`Dual`]); `A`'s own rows and 1 for a rotation. The twin of
    /// `dual` in raster.wgsl, operation for operation.
    pub fn dual(&self) -> Dual {
        let [a, b, c] = self.rows.map(|r| Vec3::new(r[0], r[1], r[2]));
        let g = [
            Vec3::new(a.dot(a), a.dot(b), a.dot(c)),
            Vec3::new(a.dot(b), b.dot(b), b.dot(c)),
            Vec3::new(a.dot(c), b.dot(c), c.dot(c)),
        ];
        let off = (g[0] - Vec3::X).abs().max((g[1] - Vec3::Y).abs()).max((g[2] - Vec3::Z).abs());
        if off.max_element() <= RIGID_TOL {
            return Dual { q: [a, b, c], stretch: 1.0, rigid: true };
        }
        let det = a.dot(b.cross(c));
        let rows = g.map(|r| r.abs().dot(Vec3::ONE));
        Dual { q: [b.cross(c) / det, c.cross(a) / det, a.cross(b) / det], stretch: rows[0].max(rows[1]).max(rows[2]).sqrt(), rigid: false }
    }
    #[inline]
    pub fn translation(&self) -> Vec3 {
        Vec3::new(self.rows[0][3], self.rows[1][3], self.rows[2][3])
    }
}

/// Per-hypothesis physical result (`ContactRecord` in `contacts.wgsl` and
/// `plane_contacts.wgsl`): shared by both kernels.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ContactRecord {
    pub intersecting: u32,
    pub contact: u32,
    pub supported: u32,
    pub min_delta: f32,
}
const _: () = assert!(std::mem::size_of::<ContactRecord>() == 16);

/// Uniform parameters of the visual kernels (`RasterParams` in
/// `shaders/raster.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct RasterParams {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
    pub n_hyp: u32,
    /// Meshlets of the mesh (the rasterizer's outer loop).
    pub n_meshlets: u32,
    pub id_bits: u32,
    pub cull: u32,
    pub radius: f32,
    pub tau: f32,
    pub alpha: f32,
    pub near: f32,
    /// Observed pixels of the whole region (score kernel).
    pub n_obs: u32,
    /// First hypothesis of this dispatch's wave.
    pub first: u32,
    /// Pixel-loop iterations one invocation may spend drawing a
    /// hypothesis ([`raster::draw_budget`]; set per dispatch).
    pub draw_budget: u32,
    /// Visibility slots of a wave (hypotheses a dispatch may draw at once).
    pub slots: u32,
    pub pad1: u32,
    pub pad2: u32,
}
const _: () = assert!(std::mem::size_of::<RasterParams>() == 80);

/// One meshlet as the GPU sees it (`GpuMeshlet` in raster.wgsl): up to
/// [`MESHLET_TRIANGLES`] neighbouring triangles, stored contiguously from
/// `first`, with a bounding sphere (model space, metres) and meshoptimizer's
/// normal cone. The rasterizer tests a whole meshlet against the region and
/// for back faces before it sets up any of its triangles.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct GpuMeshlet {
    /// Centre and radius of the bounding sphere.
    pub sphere: [f32; 4],
    /// Cone axis and cutoff: the meshlet faces away from a camera at `c`
    /// when `dot(centre - c, axis) >= cutoff * |centre - c| + radius`
    /// (meshoptimizer's test; a cutoff above 1 never culls).
    pub cone: [f32; 4],
    pub first: u32,
    pub count: u32,
    /// The meshlet's vertices in [`RenderMesh::meshlet_vertices`] (the CPU
    /// twin transforms each once per meshlet; the GPU reads corners).
    pub first_vertex: u32,
    pub vertex_count: u32,
}
const _: () = assert!(std::mem::size_of::<GpuMeshlet>() == 48);

/// Most triangles of a meshlet: the rasterizer's workgroup takes one
/// meshlet per step, one triangle per invocation.
pub const MESHLET_TRIANGLES: usize = 64;
// score_lanes.wgsl keeps a meshlet's groups of four triangles as the bits of a u32.
const _: () = assert!(MESHLET_TRIANGLES <= 128);
/// Most vertices of a meshlet (meshoptimizer allows 256): three per
/// triangle, so meshlets fill up even on meshes whose faces share no
/// vertices.
const MESHLET_VERTICES: usize = 192;

/// A mesh prepared for rendering: f32 triangles with planes grouped into
/// meshlets, its bounding radius about the model origin, and whether back
/// faces may be culled (only for meshes that bound a solid,
/// [`Mesh::bounds_solid`]: through an open mesh's holes you see inside).
#[derive(Clone, Debug)]
pub struct RenderMesh {
    /// Triangles in meshlet order (triangle ids index this).
    pub triangles: Vec<GpuTriangle>,
    pub meshlets: Vec<GpuMeshlet>,
    /// f32 vertices (welded): each meshlet's vertices are
    /// `vertices[meshlet_vertices[first_vertex..][..vertex_count]]`, and
    /// `corners[t]` are triangle `t`'s corners among its meshlet's vertices.
    /// The CPU twin transforms and projects each meshlet vertex once per
    /// pose; the values are the same f32 numbers as in `triangles`.
    pub vertices: Vec<Vec3>,
    pub meshlet_vertices: Vec<u32>,
    pub corners: Vec<[u8; 3]>,
    pub radius: f32,
    pub cull_back_faces: bool,
    /// Which CPU renderer draws it (the GPU always rasterizes).
    pub renderer: RendererChoice,
    /// The ray caster's BVH, built on first use and shared by clones.
    ray_caster: std::sync::Arc<std::sync::OnceLock<Option<bvh::RayCaster>>>,
}

/// The CPU renderer of a mesh: the rasterizer (the GPU kernel's twin) or
/// the BVH ray caster ([`bvh`]), or `Auto`: the ray caster where it is
/// measured faster (see [`RenderMesh::cpu_renderer`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RendererChoice {
    #[default]
    Auto,
    Raster,
    RayCast,
}

impl std::str::FromStr for RendererChoice {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(RendererChoice::Auto),
            "raster" => Ok(RendererChoice::Raster),
            "bvh" | "raycast" => Ok(RendererChoice::RayCast),
            _ => Err(Error::InvalidInput(format!("unknown renderer {s:?}: expected auto, raster or bvh"))),
        }
    }
}

/// The renderer [`RenderMesh::cpu_renderer`] or
/// [`RenderMesh::gpu_renderer`] picked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CpuRenderer {
    Raster,
    RayCast,
}

impl std::fmt::Display for CpuRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            CpuRenderer::Raster => "raster",
            CpuRenderer::RayCast => "bvh",
        })
    }
}

impl RenderMesh {
    pub fn new(mesh: &Mesh) -> Result<RenderMesh> {
        if mesh.triangles.len() > MAX_TRIANGLES {
            return Err(Error::InvalidInput(format!(
                "mesh has {} triangles; at most {MAX_TRIANGLES} can be rendered (decimate it first)",
                mesh.triangles.len()
            )));
        }
        // Welded, so meshlets follow the surface's connectivity (per-face
        // vertices, as in STL, would hide it).
        let mut welded = mesh.clone();
        welded.weld();
        // Back faces are culled when the mesh bounds a solid, after faces
        // wound against their neighbours are turned round.
        let cull_back_faces = welded.orient();
        let vertices: Vec<Vec3> = welded.vertices.iter().map(|v| v.as_vec3()).collect();
        let built = build_meshlets(&welded, &vertices, cull_back_faces);
        let v4 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32, 0.0];
        let triangles = built
            .order
            .iter()
            .map(|&[a, b, c]| {
                let [a, b, c] = [a, b, c].map(|i| welded.vertices[i as usize]);
                let n = (b - a).cross(c - a).normalize_or_zero();
                GpuTriangle { v0: v4(a), v1: v4(b), v2: v4(c), plane: [n.x as f32, n.y as f32, n.z as f32, n.dot(a) as f32] }
            })
            .collect();
        Ok(RenderMesh {
            triangles,
            meshlets: built.meshlets,
            vertices,
            meshlet_vertices: built.vertices,
            corners: built.corners,
            radius: (mesh.radius_about_origin() * 1.0001) as f32,
            cull_back_faces,
            renderer: RendererChoice::Auto,
            ray_caster: Default::default(),
        })
    }

    /// The CPU renderer for a hypothesis whose rectangle (the projection
    /// of the bounding sphere, clipped to the region) has `pixels` pixels.
    /// `Auto` ray-casts when the mesh has more than
    /// [`RAY_CAST_TRIANGLES_PER_PIXEL`] triangles per pixel of it (the
    /// rasterizer's cost grows with triangles, the ray caster's with
    /// pixels) and its BVH is shallow enough to traverse.
    pub fn cpu_renderer(&self, pixels: usize) -> CpuRenderer {
        let wanted = match self.renderer {
            RendererChoice::Raster => false,
            RendererChoice::RayCast => true,
            RendererChoice::Auto => self.triangles.len() as f64 > RAY_CAST_TRIANGLES_PER_PIXEL * pixels as f64,
        };
        if wanted && self.ray_caster().is_some() { CpuRenderer::RayCast } else { CpuRenderer::Raster }
    }

    /// The GPU renderer: the rasterizer
    /// (`raster.wgsl`), or the BVH ray caster (`raycast.wgsl`) when asked
    /// for or, with `Auto`, when the mesh has more meshlets than the
    /// rasterizer takes ([`MAX_GPU_MESHLETS`], about 500,000 triangles);
    /// the ray caster needs a BVH shallow enough to traverse. On lavapipe
    /// the rasterizer was faster at every size it takes (the LM-O can
    /// from 1,000 to 182,664 triangles at 128x128: 6,402 to 427 hyp/s
    /// against 294 to 119), so `Auto` ray-casts only past its budget (no
    /// hardware GPU has been lent to measure a crossover there).
    pub fn gpu_renderer(&self) -> CpuRenderer {
        let wanted = match self.renderer {
            RendererChoice::Raster => false,
            RendererChoice::RayCast => true,
            RendererChoice::Auto => self.meshlets.len() > MAX_GPU_MESHLETS,
        };
        if wanted && self.ray_caster().is_some() { CpuRenderer::RayCast } else { CpuRenderer::Raster }
    }

    /// The ray caster, its BVH built on first use (`None` when the tree is
    /// too deep to traverse safely).
    pub fn ray_caster(&self) -> Option<&bvh::RayCaster> {
        self.ray_caster.get_or_init(|| bvh::RayCaster::new(self)).as_ref()
    }

    /// Bits of the visibility key used for the triangle id.
    pub fn id_bits(&self) -> u32 {
        (usize::BITS - self.triangles.len().saturating_sub(1).leading_zeros()).max(1)
    }
}

/// Meshlets of a welded mesh: the triangles (global vertex ids) in meshlet
/// order, the meshlet records, their vertex lists and each triangle's
/// corners among its meshlet's vertices.
struct Built {
    order: Vec<[u32; 3]>,
    meshlets: Vec<GpuMeshlet>,
    vertices: Vec<u32>,
    corners: Vec<[u8; 3]>,
}

/// Groups triangles into meshlets with meshoptimizer (`meshopt`, the
/// reference implementation), weighting normal-cone tightness so whole
/// meshlets can be culled as back faces; bounds come from meshoptimizer
/// too. Meshes that are not closed get a cutoff of 2, which never culls.
fn build_meshlets(mesh: &Mesh, vertices: &[Vec3], closed: bool) -> Built {
    let (indices, origin) = split_busy_vertices(&mesh.triangles, vertices.len());
    let positions: Vec<[f32; 3]> = origin.iter().map(|&v| vertices[v as usize].to_array()).collect();
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&positions), 12, 0).expect("12-byte f32 positions");
    let ml = meshopt::build_meshlets(&indices, &adapter, MESHLET_VERTICES, MESHLET_TRIANGLES, 0.5);
    let mut out = Built { order: Vec::with_capacity(mesh.triangles.len()), meshlets: Vec::with_capacity(ml.len()), vertices: Vec::new(), corners: Vec::new() };
    for m in ml.iter() {
        let b = meshopt::compute_meshlet_bounds(m, &adapter);
        let cutoff = if closed { b.cone_cutoff } else { 2.0 };
        out.meshlets.push(GpuMeshlet {
            sphere: [b.center[0], b.center[1], b.center[2], b.radius],
            cone: [b.cone_axis[0], b.cone_axis[1], b.cone_axis[2], cutoff],
            first: out.order.len() as u32,
            count: (m.triangles.len() / 3) as u32,
            first_vertex: out.vertices.len() as u32,
            vertex_count: m.vertices.len() as u32,
        });
        for c in m.triangles.chunks_exact(3) {
            out.order.push([c[0], c[1], c[2]].map(|i| origin[m.vertices[i as usize] as usize]));
            out.corners.push([c[0], c[1], c[2]]);
        }
        out.vertices.extend(m.vertices.iter().map(|&v| origin[v as usize]));
    }
    out
}

/// Triangles one vertex may share when meshlets are built; the rest get
/// copies of it.
const MAX_VERTEX_TRIANGLES: usize = 64;

/// The index list for meshoptimizer, where a vertex shared by more than
/// [`MAX_VERTEX_TRIANGLES`] triangles is split into copies that share at
/// most that many each, and `origin`, each (copied) vertex's index in
/// `triangles`. Its meshlet builder rescans a vertex's triangles whenever
/// one of them is taken, so a fan's hub (a cone's apex, a disc's centre)
/// made it quadratic: a cone of 80k triangles took 20 s to load. Meshes
/// without such vertices are handed over unchanged, so their meshlets are
/// what they were.
fn split_busy_vertices(triangles: &[[u32; 3]], n_vertices: usize) -> (Vec<u32>, Vec<u32>) {
    let mut uses = vec![0usize; n_vertices];
    for &v in triangles.iter().flatten() {
        uses[v as usize] += 1;
    }
    let mut origin: Vec<u32> = (0..n_vertices as u32).collect();
    if uses.iter().all(|&u| u <= MAX_VERTEX_TRIANGLES) {
        return (triangles.iter().flatten().copied().collect(), origin);
    }
    // The copy a busy vertex's next triangle goes to, and how many it has.
    let mut current: Vec<(u32, usize)> = (0..n_vertices as u32).map(|v| (v, 0)).collect();
    let mut indices = Vec::with_capacity(3 * triangles.len());
    for &v in triangles.iter().flatten() {
        let (copy, n) = &mut current[v as usize];
        if *n == MAX_VERTEX_TRIANGLES {
            *copy = origin.len() as u32;
            *n = 0;
            origin.push(v);
        }
        *n += 1;
        indices.push(*copy);
    }
    (indices, origin)
}

/// Triangles per pixel of a hypothesis' rectangle above which `Auto`
/// ray-casts on the CPU: the measured crossover was 45-50 at 128x128 and
/// 640x480 regions alike (LM-O can subdivided to 45k-2.9M triangles, see
/// the README's design notes).
pub const RAY_CAST_TRIANGLES_PER_PIXEL: f64 = 40.0;

/// Every WGSL source as the pipelines compile it: `(name, source)`.
pub fn shader_sources() -> Vec<(&'static str, String)> {
    vec![
        ("render", render::render_wgsl()),
        ("score", score::SCORE_WGSL.to_string()),
        ("score_lanes", score::SCORE_LANES_WGSL.to_string()),
        ("raycast", raycast::RAYCAST_WGSL.to_string()),
        ("depth", depth::depth_wgsl()),
        ("contacts", contacts::CONTACTS_WGSL.to_string()),
        ("plane_contacts", plane_contacts::SCORE_PHYSICS_WGSL.to_string()),
    ]
}

/// Test helper: WGSL struct layouts as naga computes them, compared with
/// the Rust `#[repr(C)]` structs field by field, and one validation setting
/// for every shader.
#[cfg(test)]
pub(crate) mod wgsl_layout {
    /// The capabilities every shader is validated with: none beyond core
    /// WGSL, what every adapter (lavapipe, downlevel GL) offers; only the
    /// lanes score kernel, used where the device has them, takes subgroup
    /// operations in compute shaders.
    pub const CAPABILITIES: naga::valid::Capabilities = naga::valid::Capabilities::empty();

    /// Parses and validates `src` (panicking with naga's message).
    pub fn module(name: &str, src: &str) -> naga::Module {
        let module = naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        let mut validator = if name == "score_lanes" {
            let mut v = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), CAPABILITIES | naga::valid::Capabilities::SUBGROUP);
            v.subgroup_stages(naga::valid::ShaderStages::COMPUTE).subgroup_operations(naga::valid::SubgroupOperationSet::all());
            v
        } else {
            naga::valid::Validator::new(naga::valid::ValidationFlags::all(), CAPABILITIES)
        };
        validator.validate(&module).unwrap_or_else(|e| panic!("{name}: {e:?}"));
        module
    }

    /// Asserts that WGSL struct `name` in `src` has `size` bytes and its
    /// members the byte offsets in `fields` (WGSL member name → the Rust
    /// field's `offset_of!`), every member listed.
    pub fn assert_layout(src: &str, name: &str, size: usize, fields: &[(&str, usize)]) {
        let module = naga::front::wgsl::parse_str(src).unwrap();
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        let (h, ty) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)).unwrap_or_else(|| panic!("no struct {name}"));
        assert_eq!(layouter[h].size as usize, size, "size of {name}");
        let naga::TypeInner::Struct { members, .. } = &ty.inner else { panic!("{name} is not a struct") };
        assert_eq!(members.len(), fields.len(), "{name}: every member must be checked");
        for m in members {
            let member = m.name.as_deref().unwrap_or_default();
            let want = fields.iter().find(|(f, _)| *f == member).unwrap_or_else(|| panic!("{name}.{member} not checked")).1;
            assert_eq!(m.offset as usize, want, "offset of {name}.{member}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fan's hub is split into copies of at most MAX_VERTEX_TRIANGLES
    /// triangles each, mapped back to itself; a mesh without busy vertices
    /// is handed over as it is.
    #[test]
    fn busy_vertices_are_split_for_meshlets() {
        let fan: Vec<[u32; 3]> = (0..200u32).map(|k| [0, 1 + k, 2 + k]).collect();
        let (indices, origin) = split_busy_vertices(&fan, 202);
        let mut uses = vec![0usize; origin.len()];
        for (&i, &v) in indices.iter().zip(fan.iter().flatten()) {
            assert_eq!(origin[i as usize], v);
            uses[i as usize] += 1;
        }
        assert!(uses.iter().all(|&u| u <= MAX_VERTEX_TRIANGLES));
        assert_eq!(origin.len(), 202 + 200usize.div_ceil(MAX_VERTEX_TRIANGLES) - 1);
        let strip: Vec<[u32; 3]> = (0..200u32).map(|k| [k, k + 1, k + 2]).collect();
        let (indices, origin) = split_busy_vertices(&strip, 202);
        assert_eq!(indices, strip.iter().flatten().copied().collect::<Vec<_>>());
        assert_eq!(origin.len(), 202);
    }

    /// naga parses and validates every composed shader (what wgpu does at
    /// pipeline creation), so a broken kernel fails here without a GPU.
    #[test]
    fn every_wgsl_file_validates() {
        let mut covered = std::collections::HashSet::new();
        for (name, src) in shader_sources() {
            wgsl_layout::module(name, &src);
            covered.insert(name);
        }
        // Every shader file is part of some composed module.
        for entry in std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/shaders")).unwrap() {
            let file = entry.unwrap().file_name().into_string().unwrap();
            let stem = file.trim_end_matches(".wgsl");
            assert!(stem == "raster" || covered.contains(stem), "shaders/{file} is not validated");
        }
    }

    /// Constants the rasterizer's WGSL and its twin must agree on.
    #[test]
    fn raster_constants_match_the_host() {
        let module = wgsl_layout::module("score", score::SCORE_WGSL);
        let value = |name: &str| -> naga::Literal {
            let (_, c) = module.constants.iter().find(|(_, c)| c.name.as_deref() == Some(name)).unwrap_or_else(|| panic!("no const {name}"));
            match module.global_expressions[c.init] {
                naga::Expression::Literal(l) => l,
                ref e => panic!("{name}: {e:?}"),
            }
        };
        assert_eq!(value("RIGID_TOL"), naga::Literal::F32(RIGID_TOL));
        assert_eq!(value("TRI_ROW"), naga::Literal::U32(raster::TRI_ROW as u32));
        assert_eq!(value("MESHLET_ROW"), naga::Literal::U32(raster::MESHLET_ROW as u32));
    }

    /// Sizes and field offsets of every struct the visual kernels share
    /// with the host.
    #[test]
    fn visual_structs_match_the_wgsl_field_by_field() {
        use std::mem::{offset_of, size_of};
        let src = plane_contacts::SCORE_PHYSICS_WGSL;
        macro_rules! same {
            ($t:ty, $($f:ident),+) => { &[$((stringify!($f), offset_of!($t, $f))),+] };
        }
        wgsl_layout::assert_layout(src, "RasterParams", size_of::<RasterParams>(), same!(RasterParams, fx, fy, cx, cy, width, height, n_hyp, n_meshlets, id_bits, cull, radius, tau, alpha, near, n_obs, first, draw_budget, slots, pad1, pad2));
        wgsl_layout::assert_layout(src, "GpuMeshlet", size_of::<GpuMeshlet>(), same!(GpuMeshlet, sphere, cone, first, count, first_vertex, vertex_count));
        wgsl_layout::assert_layout(src, "GpuTriangle", size_of::<GpuTriangle>(), same!(GpuTriangle, v0, v1, v2, plane));
        let rows = offset_of!(GpuPose, rows);
        wgsl_layout::assert_layout(src, "GpuPose", size_of::<GpuPose>(), &[("r0", rows), ("r1", rows + 16), ("r2", rows + 32)]);
        wgsl_layout::assert_layout(src, "ScoreRecord", size_of::<score::ScoreRecord>(), same!(score::ScoreRecord, score, mean_ad, mean_an, valid, rendered, observed, front, behind));
        use plane_contacts::PlaneParams;
        wgsl_layout::assert_layout(src, "PlaneParams", size_of::<PlaneParams>(), same!(PlaneParams, plane, n_samples, words, eps, pad));
        wgsl_layout::assert_layout(src, "ContactRecord", size_of::<ContactRecord>(), same!(ContactRecord, intersecting, contact, supported, min_delta));
        let depth = depth::depth_wgsl();
        wgsl_layout::assert_layout(&depth, "Tile", size_of::<depth::Tile>(), same!(depth::Tile, x0, y0, x1, y1, offset, pad0, pad1, pad2));
    }
}
