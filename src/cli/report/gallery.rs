//! Side views of stable resting poses for the gallery, drawn with the
//! physical checker's own picture code (`physical::explain::draw_views_bare`),
//! so a cluster looks exactly as `check --explain` would draw it on a
//! table: surface samples by class, the plane's trace, the centre of mass.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use image::{imageops, RgbImage};
use plausible::mesh::{Mesh, MeshUnits};
use plausible::physical::contacts::{evaluate_detailed, Body, Environment};
use plausible::physical::explain::{draw_views_bare, Drawn};
use plausible::physical::Plane;
use plausible::pose::Pose;

/// Surface samples per drawn pose: dense enough that the silhouette reads
/// at thumbnail size.
const SAMPLES: usize = 4000;
/// Edge of a gallery picture, pixels.
pub const THUMB: u32 = 200;

/// A mesh ready to be drawn in its resting poses, or why it cannot be.
pub enum Drawable {
    Ready { body: Box<Body>, note: Option<String> },
    Missing(String),
}

/// The gallery of one report: each mesh prepared (loaded and sampled) once
/// however many export entries name it (it had been loaded again for
/// each), and the cards left to draw over all exports.
pub struct Gallery {
    /// Keyed by the mesh as written, its hash and the export's folder
    /// (where a relative mesh is looked for).
    bodies: HashMap<(String, String, PathBuf), Drawable>,
    pub left: usize,
}

impl Gallery {
    /// A gallery of at most `cards` cards.
    pub fn new(cards: usize) -> Gallery {
        Gallery { bodies: HashMap::new(), left: cards }
    }

    /// [`prepare`], once per mesh, hash and export folder.
    pub fn prepare(&mut self, mesh_path: &str, sha256: &str, export_file: &Path) -> &Drawable {
        let folder = export_file.parent().map(Path::to_path_buf).unwrap_or_default();
        self.bodies.entry((mesh_path.to_string(), sha256.to_string(), folder)).or_insert_with(|| prepare(mesh_path, sha256, export_file))
    }
}

/// Finds the export's mesh (as written, then beside the export file) and
/// samples it. The export's hash is of the geometry in metres: a file that
/// no longer matches it is still drawn, with a note saying so.
fn prepare(mesh_path: &str, sha256: &str, export_file: &Path) -> Drawable {
    if mesh_path.is_empty() {
        return Drawable::Missing("the export names no mesh file".into());
    }
    let Some(path) = locate(mesh_path, export_file) else {
        return Drawable::Missing(format!("mesh {mesh_path} not found (looked as written and beside the export)"));
    };
    let Some((mesh, matched)) = load_matching(&path, sha256) else {
        return Drawable::Missing(format!("mesh {} could not be loaded", path.display()));
    };
    let note =
        (!matched).then(|| format!("{} differs from the mesh of the run (hash mismatch): poses drawn on the current file", path.display()));
    match Body::new(&mesh, SAMPLES, 0, None) {
        Ok(body) => Drawable::Ready { body: Box::new(body), note },
        Err(e) => Drawable::Missing(format!("mesh {}: {e}", path.display())),
    }
}

/// The mesh path as written, else relative to the export's folder.
fn locate(mesh_path: &str, export_file: &Path) -> Option<PathBuf> {
    let p = PathBuf::from(mesh_path);
    if p.is_file() {
        return Some(p);
    }
    let beside = export_file.parent()?.join(&p);
    if beside.is_file() {
        return Some(beside);
    }
    let by_name = export_file.parent()?.join(p.file_name()?);
    by_name.is_file().then_some(by_name)
}

/// Loads the mesh in the units whose geometry has the export's hash (the
/// run may have used any of them); falls back to `auto` when none does.
fn load_matching(path: &Path, sha256: &str) -> Option<(Mesh, bool)> {
    let mut fallback = None;
    for units in [MeshUnits::Auto, MeshUnits::Metres, MeshUnits::Millimetres] {
        let Ok((mesh, _)) = Mesh::load(path, units) else { continue };
        if plausible::stable::mesh_sha256(&mesh) == sha256 {
            return Some((mesh, true));
        }
        fallback.get_or_insert(mesh);
    }
    fallback.map(|m| (m, false))
}

/// The side view (a `THUMB`-pixel square) of the body resting on the
/// plane z = 0 with the exported rotation and origin height, or `None`
/// when the rotation is not one.
pub fn side_view(body: &Body, r_model_to_plane: &[f64; 9], height: f64) -> Option<Vec<u8>> {
    let pose = Pose::from_row_major(*r_model_to_plane, [0.0, 0.0, height]);
    if !(pose.orthonormality_error() < 1e-3 && height.is_finite()) {
        return None;
    }
    let env = Environment {
        planes: vec![Plane { point: DVec3::ZERO, normal: DVec3::Z }],
        obstacles: Vec::new(),
        gravity: DVec3::new(0.0, 0.0, -9.81),
    };
    let (_, detail) = evaluate_detailed(body, &pose, &env);
    // The pose came to rest in the drop tests: its centre of mass is drawn
    // as stable (black) even where a few samples within ε of a curved
    // underside make the checker's support polygon degenerate.
    let views = draw_views_bare(&env.planes, env.gravity, &[Drawn { detail: &detail, is_static: false, stable: true, label: None }]);
    encode(&side_half(&views))
}

/// The right half of `draw_views_bare`' picture (the side view), shrunk.
fn side_half(views: &RgbImage) -> RgbImage {
    // One column past the middle: the separator line is not part of the view.
    let half = views.width() / 2 + 1;
    let side = imageops::crop_imm(views, half, 0, views.width() - half, views.height()).to_image();
    shrink_keeping_dots(&side, THUMB)
}

/// Shrinks to `size` × `size` keeping, in each block, its darkest pixel:
/// the views are thin dots and lines on white, which averaging filters
/// would wash out to near white.
fn shrink_keeping_dots(img: &RgbImage, size: u32) -> RgbImage {
    let (w, h) = img.dimensions();
    let luma = |p: &image::Rgb<u8>| 299 * u32::from(p[0]) + 587 * u32::from(p[1]) + 114 * u32::from(p[2]);
    RgbImage::from_fn(size, size, |x, y| {
        let (x0, x1) = (x * w / size, ((x + 1) * w / size).max(x * w / size + 1).min(w));
        let (y0, y1) = (y * h / size, ((y + 1) * h / size).max(y * h / size + 1).min(h));
        let block = (y0..y1).flat_map(|yy| (x0..x1).map(move |xx| (xx, yy)));
        block.map(|(xx, yy)| *img.get_pixel(xx, yy)).min_by_key(luma).unwrap_or(image::Rgb([255, 255, 255]))
    })
}

fn encode(img: &RgbImage) -> Option<Vec<u8>> {
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png).ok()?;
    Some(bytes)
}
