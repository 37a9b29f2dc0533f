//! Refinement over the images of a BOP dataset: every estimate of an
//! object in an image is a hypothesis of it; each object is refined against
//! the image's depth inside its mask, and the refined estimates come back
//! with their visual-alignment score and the image's time.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;

use super::icp::ModelSurface;
use super::RefineParams;
use crate::bop::dataset::{Dataset, PoseMm, Scene};
use crate::bop::results::Estimate;
use crate::error::{Error, Result};
use crate::kernels::RenderMesh;
use crate::mesh::Mesh;
use crate::observation::{read_mask_png, DepthImage};
use crate::physical::simulate::{SimBody, SimShapes, SimWorld};
use crate::support_plane::{fit_support_plane, PlaneFitParams};
use crate::visual::Device;

/// Where the objects' masks come from.
#[derive(Clone, Debug)]
pub enum Masks {
    /// The dataset's own `mask_visib/` of the ground-truth instances
    /// (an oracle segmentation: the union over the object's instances).
    Oracle,
    /// A folder with `SSSSSS/IIIIII_OOOOOO.png` (scene, image, object id):
    /// another method's segmentation, one mask per object and image.
    Dir(PathBuf),
}

impl Masks {
    /// The mask files of the object's instances in an image (oracle: one
    /// per ground-truth instance; a folder: its one file, when present).
    fn paths(&self, scene: &Scene, im_id: u32, obj_id: u32) -> Vec<PathBuf> {
        match self {
            Masks::Oracle => scene
                .gt
                .get(&im_id)
                .map(|gt| {
                    gt.iter()
                        .enumerate()
                        .filter(|(_, g)| g.obj_id == obj_id)
                        .map(|(k, _)| scene.mask_visib_dir().join(format!("{im_id:06}_{k:06}.png")))
                        .collect()
                })
                .unwrap_or_default(),
            Masks::Dir(d) => {
                let p = Masks::dir_file(d, scene.id, im_id, obj_id);
                if p.exists() { vec![p] } else { vec![] }
            }
        }
    }

    /// The file of an object's mask in an image in a folder of masks.
    pub fn dir_file(dir: &Path, scene_id: u32, im_id: u32, obj_id: u32) -> PathBuf {
        dir.join(format!("{scene_id:06}")).join(format!("{im_id:06}_{obj_id:06}.png"))
    }

    /// Of the (scene, image, object) triples, those without a mask file
    /// (always none for the oracle, whose missing masks are unseen
    /// instances). Lets a run with a folder of masks under another naming
    /// be refused before any work instead of leaving every object as it was.
    pub fn missing<'a>(&self, wanted: impl IntoIterator<Item = &'a (u32, u32, u32)>) -> Vec<(u32, u32, u32)> {
        match self {
            Masks::Oracle => vec![],
            Masks::Dir(d) => wanted.into_iter().filter(|(s, i, o)| !Masks::dir_file(d, *s, *i, *o).exists()).copied().collect(),
        }
    }

    /// Each instance's own mask of the object in an image, empty when none.
    pub fn instances(&self, scene: &Scene, im_id: u32, obj_id: u32, width: u32, height: u32) -> Result<Vec<Vec<bool>>> {
        let masks: Vec<Vec<bool>> = self.paths(scene, im_id, obj_id).iter().map(|p| read_mask_png(p, width, height)).collect::<Result<_>>()?;
        // An empty mask is an instance not seen at all (BOP annotates fully
        // occluded ones): it has no mask to refine or estimate against.
        Ok(masks.into_iter().filter(|m| m.contains(&true)).collect())
    }

    /// The object's mask in an image (the union of its instances'), `None`
    /// when it has none (no ground-truth instance, or no file in the folder).
    fn read(&self, scene: &Scene, im_id: u32, obj_id: u32, width: u32, height: u32) -> Result<Option<Vec<bool>>> {
        let masks = self.instances(scene, im_id, obj_id, width, height)?;
        Ok((!masks.is_empty()).then(|| union(masks.iter().map(Vec::as_slice), (width * height) as usize)))
    }

    pub fn describe(&self) -> String {
        match self {
            Masks::Oracle => "the dataset's mask_visib (oracle segmentation)".into(),
            Masks::Dir(d) => format!("masks from {}", d.display()),
        }
    }
}

/// The pixels in any of `masks` (each `n` pixels).
pub fn union<'a>(masks: impl IntoIterator<Item = &'a [bool]>, n: usize) -> Vec<bool> {
    let mut all = vec![false; n];
    for m in masks {
        all.iter_mut().zip(m).for_each(|(a, b)| *a |= *b);
    }
    all
}

/// The support plane fitted to the depth outside every object's mask.
pub fn support_plane<'a>(depth: &DepthImage, masks: impl IntoIterator<Item = &'a [bool]>, p: &PlaneFitParams) -> Result<crate::physical::Plane> {
    let outside = union(masks, depth.depth.len());
    Ok(fit_support_plane(depth, Some(&outside), p)?.plane)
}

/// An object's meshes for refinement: the render mesh (scoring) and its
/// surface samples (ICP), in metres.
pub struct Model {
    pub render: RenderMesh,
    /// With `--lod N` (a fixed triangle count, the same for every view):
    /// the simplified mesh the visual score renders, built once here.
    pub scoring: Option<RenderMesh>,
    /// With `--lod auto`: the levels simplified so far, per pixel size.
    pub auto_lod: crate::visual::AutoLodCache,
    pub surface: ModelSurface,
    /// The mesh (metres), and its colliders and mass for the simulation.
    pub mesh: std::sync::Arc<Mesh>,
    pub shapes: SimShapes,
}

impl Model {
    /// The render mesh, surface samples and the mesh itself.
    pub fn new(mesh: Mesh, p: &RefineParams) -> Result<Model> {
        let scoring = match p.lod {
            crate::mesh::lod::LodChoice::Faces(n) => Some(RenderMesh::new(&crate::mesh::lod::with_faces(&mesh, n)?.mesh)?),
            _ => None,
        };
        Ok(Model {
            render: RenderMesh::new(&mesh)?,
            scoring,
            auto_lod: Default::default(),
            surface: ModelSurface::sample(&mesh, p.samples, p.seed)?,
            shapes: SimShapes::new(&mesh.source.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "object".into()), &mesh)?,
            mesh: std::sync::Arc::new(mesh),
        })
    }
}

/// The simulation PIR steps in: the object (dynamic, index 0) on the
/// support plane (camera frame, gravity against its normal) among the
/// other objects at their current estimates (static, as their convex hulls:
/// see [`SimBody::static_hull`]).
pub fn physics_world(plane: &crate::physical::Plane, body: &Model, others: &[(&Model, crate::pose::Pose)], p: &RefineParams) -> Result<SimWorld> {
    let mut bodies = vec![SimBody {
        shapes: &body.shapes,
        pose: crate::pose::Pose::new(glam::DMat3::IDENTITY, plane.point + plane.normal),
        density: Some(crate::physical::scene::DEFAULT_DENSITY),
        static_hull: false,
    }];
    bodies.extend(others.iter().map(|(m, pose)| SimBody { shapes: &m.shapes, pose: *pose, density: None, static_hull: true }));
    SimWorld::from_bodies(std::slice::from_ref(plane), -9.81 * plane.normal, &bodies, body.mesh.diagonal(), &p.sim)
}

/// Loads the models of `obj_ids`.
pub fn load_models(ds: &Dataset, obj_ids: &[u32], p: &RefineParams) -> Result<HashMap<u32, Model>> {
    obj_ids.par_iter().map(|&id| Ok((id, Model::new(ds.model_mesh(id)?, p)?))).collect()
}

/// The estimates of one image.
#[derive(Clone, Debug)]
pub struct ImageJob {
    pub scene_id: u32,
    pub im_id: u32,
    pub estimates: Vec<Estimate>,
}

/// Groups estimates by image, images in (scene, image) order, estimates in
/// file order.
pub fn image_jobs(estimates: &[Estimate]) -> Vec<ImageJob> {
    let mut by: BTreeMap<(u32, u32), Vec<Estimate>> = BTreeMap::new();
    for e in estimates {
        by.entry((e.scene_id, e.im_id)).or_default().push(*e);
    }
    by.into_iter().map(|((scene_id, im_id), estimates)| ImageJob { scene_id, im_id, estimates }).collect()
}

/// What refining one image did.
#[derive(Clone, Copy, Debug, Default)]
pub struct ImageStats {
    pub objects: usize,
    /// Objects left as they were (no mask, or too few observed points).
    pub unrefined: usize,
    pub steps: usize,
    pub kept: usize,
    pub seconds: f64,
    /// Where the time went.
    pub times: super::RefineTimes,
}

impl std::ops::AddAssign for ImageStats {
    /// Totals over images.
    fn add_assign(&mut self, o: Self) {
        self.objects += o.objects;
        self.unrefined += o.unrefined;
        self.steps += o.steps;
        self.kept += o.kept;
        self.seconds += o.seconds;
        self.times += o.times;
    }
}

/// An image's depth in metres with its intrinsics.
pub fn depth_image(scene: &Scene, im_id: u32) -> Result<DepthImage> {
    // A lens camera is said before the depth is looked for (HOT3D has none).
    scene.pinhole_k(im_id)?;
    let mm = scene.read_depth(im_id)?;
    let intrinsics = scene.intrinsics(im_id, mm.width, mm.height)?;
    Ok(DepthImage { intrinsics, depth: mm.mm.iter().map(|v| v * 1e-3).collect() })
}

/// One refined (or estimated) image.
pub struct ImageResult<S> {
    /// The estimates with their new poses and scores (input order), the
    /// image's wall time as `time`.
    pub estimates: Vec<Estimate>,
    pub stats: S,
    /// The refinement's picture ([`super::explain::refinement_picture`]),
    /// when asked for.
    pub picture: Option<image::RgbImage>,
}

/// Refines the estimates of one image in support order
/// ([`super::scene::refine_scene`]); `explain` also draws the refinement.
pub fn refine_image(
    scene: &Scene,
    job: &ImageJob,
    models: &HashMap<u32, Model>,
    device: &Device,
    masks: &Masks,
    p: &RefineParams,
    explain: bool,
) -> Result<ImageResult<ImageStats>> {
    let t0 = Instant::now();
    let depth = depth_image(scene, job.im_id)?;
    let (width, height) = (depth.intrinsics.width, depth.intrinsics.height);
    let mut objs: Vec<u32> = job.estimates.iter().map(|e| e.obj_id).collect();
    objs.sort_unstable();
    objs.dedup();
    for obj in &objs {
        if !models.contains_key(obj) {
            return Err(Error::InvalidInput(format!("object {obj} has no model in the dataset")));
        }
    }
    let object_masks: Vec<Option<Vec<bool>>> =
        objs.iter().map(|&obj| masks.read(scene, job.im_id, obj, width, height)).collect::<Result<_>>()?;
    // The support plane, fitted outside every object's mask, for PIR.
    let plane = if p.method.simulates(p.physics) {
        support_plane(&depth, object_masks.iter().flatten().map(Vec::as_slice), &PlaneFitParams::default()).ok()
    } else {
        None
    };
    // Each object's estimates are its hypotheses; its best-scored one
    // stands for it among the others until it is refined.
    let (mut ids, mut objects) = (Vec::new(), Vec::new());
    for (&obj, mask) in objs.iter().zip(&object_masks) {
        let Some(mask) = mask.as_deref().filter(|m| m.iter().any(|&v| v)) else { continue };
        let mine: Vec<&Estimate> = job.estimates.iter().filter(|e| e.obj_id == obj).collect();
        let lead = (0..mine.len()).max_by(|&a, &b| mine[a].score.total_cmp(&mine[b].score).then(b.cmp(&a))).unwrap_or(0);
        let hypotheses = mine.iter().map(|e| e.pose.to_rigid_pose()).collect();
        ids.push(obj);
        objects.push(super::scene::SceneObject { model: &models[&obj], mask, hypotheses, lead });
    }
    let scene_out = super::scene::refine_scene(device, &depth, plane.as_ref(), &objects, usize::MAX, p)?;
    let mut stats = ImageStats { objects: objs.len(), unrefined: objs.len() - ids.len(), times: scene_out.times, ..Default::default() };
    let mut out = job.estimates.clone();
    // An object without a usable view (no mask pixel, or too few observed
    // points) keeps its pose and scores 0, as a pose against no observed
    // pixel does (eq. 3): its input score is on another method's scale,
    // and the column must rank every row alike.
    let viewed: Vec<u32> = ids.iter().zip(&scene_out.objects).filter(|(_, r)| r.is_some()).map(|(&o, _)| o).collect();
    for e in out.iter_mut().filter(|e| !viewed.contains(&e.obj_id)) {
        e.score = 0.0;
    }
    for (obj, refined) in ids.iter().zip(&scene_out.objects) {
        let Some(refined) = refined else {
            stats.unrefined += 1;
            continue;
        };
        if refined.iter().all(|r| r.steps == 0) {
            stats.unrefined += 1;
        }
        for (e, r) in out.iter_mut().filter(|e| e.obj_id == *obj).zip(refined) {
            e.pose = PoseMm { r: r.pose.r, t: r.pose.t * 1e3 };
            e.score = r.score;
            stats.steps += r.steps;
            stats.kept += r.kept;
        }
    }
    stats.seconds = t0.elapsed().as_secs_f64();
    for e in &mut out {
        e.time = stats.seconds;
        e.line = 0;
    }
    // Hypotheses refined to the very same pose are one estimate.
    crate::bop::results::drop_repeated_poses(&mut out);
    // Drawn after the clock stops: pictures are not the method's time.
    let picture = explain.then(|| super::explain::scene_picture(&depth, &objects, &scene_out, plane.as_ref(), p)).transpose()?;
    Ok(ImageResult { estimates: out, stats, picture })
}

/// The journal beside a results file written image by image: one line
/// `scene_id im_id rows` per image, appended once the image's rows are on
/// disk. A kill can cut an image's rows short (a write of several pages is
/// not atomic), and refinement may keep fewer rows than it was given (two
/// hypotheses refined to one pose are one estimate), so only the journal
/// tells a finished image from a cut one.
pub fn journal_path(out: &Path) -> PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(".done");
    PathBuf::from(name)
}

/// The journal's image counts, the last line of an image winning; `None`
/// without a journal (an output from before journals, or none yet). A line
/// cut by a kill is ignored.
fn read_journal(path: &Path) -> Result<Option<HashMap<(u32, u32), usize>>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::io(path, e)),
    };
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    let mut counts = HashMap::new();
    for (i, line) in complete.lines().enumerate() {
        let f: Vec<u64> = line.split_whitespace().filter_map(|v| v.parse().ok()).collect();
        match f[..] {
            [s, im, n] if s <= u32::MAX as u64 && im <= u32::MAX as u64 => counts.insert((s as u32, im as u32), n as usize),
            _ => return Err(Error::InvalidInput(format!("{}: line {}: not 'scene_id im_id rows' (a journal this command wrote?)", path.display(), i + 1))),
        };
    }
    Ok(Some(counts))
}

/// Appends one finished image to the journal (see [`journal_path`]).
pub fn journal_line(scene_id: u32, im_id: u32, rows: usize) -> String {
    format!("{scene_id} {im_id} {rows}\n")
}

/// Images of `expected` already complete in a (partial) output file, for
/// resuming. An image is complete when the journal ([`journal_path`]) lists
/// it with as many rows as the file holds; without a journal (an older
/// output), when the file holds as many as `expected` says (its count in
/// the input). Rows of incomplete images are removed (the file is
/// rewritten atomically) and those images run again; rows of images outside
/// `expected` (another --images, --scenes or --shard written to the same
/// file) are kept as they are when complete. The journal is rewritten to
/// match what is kept. A missing file, or one that is not a regular file,
/// is an empty set.
pub fn resume_from(path: &Path, expected: &HashMap<(u32, u32), usize>) -> Result<std::collections::BTreeSet<(u32, u32)>> {
    // Only a regular file can be resumed (reading /dev/full or a FIFO would
    // never end); anything else is written to as it is.
    let journal = journal_path(path);
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        if journal.is_file() {
            std::fs::remove_file(&journal).map_err(|e| Error::io(&journal, e))?;
        }
        return Ok(Default::default());
    }
    let listed = read_journal(&journal)?;
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    let mut rows: Vec<((u32, u32), &str)> = Vec::new();
    for (i, line) in complete.lines().enumerate() {
        if i == 0 && line.starts_with("scene_id") || line.trim().is_empty() {
            continue;
        }
        let e = crate::bop::results::parse_line(line)
            .map_err(|r| Error::InvalidInput(format!("{}: line {}: {r} (not a results file this command wrote?)", path.display(), i + 1)))?;
        rows.push(((e.scene_id, e.im_id), line));
    }
    let mut count: BTreeMap<(u32, u32), usize> = BTreeMap::new();
    for (k, _) in &rows {
        *count.entry(*k).or_default() += 1;
    }
    let finished = |k: &(u32, u32), n: usize| match &listed {
        Some(j) => j.get(k) == Some(&n),
        None => expected.get(k).is_none_or(|&want| want == n),
    };
    let done: std::collections::BTreeSet<(u32, u32)> =
        expected.keys().filter(|k| finished(k, count.get(*k).copied().unwrap_or(0))).copied().collect();
    let kept_images: BTreeMap<(u32, u32), usize> = count.into_iter().filter(|(k, n)| finished(k, *n)).collect();
    let kept: Vec<&str> = rows.iter().filter(|(k, _)| kept_images.contains_key(k)).map(|(_, l)| *l).collect();
    if kept.len() != rows.len() || complete.len() != text.len() {
        crate::io::write_atomically(path, |w| {
            use std::io::Write;
            writeln!(w, "{}", crate::bop::results::HEADER)?;
            kept.iter().try_for_each(|l| writeln!(w, "{l}"))
        })?;
    }
    // Images finished without a row (no mask) stay finished.
    let empty = done.iter().filter(|k| !kept_images.contains_key(*k)).map(|k| (*k, 0));
    let entries: Vec<((u32, u32), usize)> = kept_images.iter().map(|(k, n)| (*k, *n)).chain(empty).collect();
    crate::io::write_atomically(&journal, |w| {
        use std::io::Write;
        entries.iter().try_for_each(|((s, im), n)| w.write_all(journal_line(*s, *im, *n).as_bytes()))
    })?;
    Ok(done)
}
