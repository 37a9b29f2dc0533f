//! File-format dispatch: OBJ (tobj), glTF/GLB (gltf), PLY and STL (our own
//! small parsers, since BOP models are PLY and YCB scans are STL).
//!
//! OBJ polygons are triangulated by [`polygon`](super::polygon) (ear
//! clipping for concave ones), polylines (`l`) and points (`p`) are
//! dropped. glTF triangle lists, strips and fans are read from every node
//! instance of the scene; points and lines primitives have no surface and
//! are skipped. A glTF node graph is bounded (depth, instances, total
//! size) since a cycle or a tree of shared nodes would otherwise grow
//! without limit. Quantized glTF positions (KHR_mesh_quantization, as
//! gltfpack writes them) are read.

use std::path::Path;

use glam::{DMat4, DVec3};

use crate::error::{Error, Result};

use super::polygon;

/// Reads the positions and triangles of a mesh file in its own units.
/// All bodies / primitives in the file are merged into one mesh.
pub fn load_positions(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    if !path.exists() {
        return Err(Error::NotFound { path: path.to_path_buf() });
    }
    // Read whole by every parser: a device such as /dev/zero would be read
    // until memory runs out, and a file past the caps below holds more
    // triangles than are taken anyway.
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(malformed(path, "not a regular file"));
    }
    if meta.len() > MAX_MESH_FILE_BYTES {
        return Err(malformed(path, format!("{} bytes, more than the {} GiB a mesh file may have (decimate it first)", meta.len(), MAX_MESH_FILE_BYTES >> 30)));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "obj" => load_obj(path),
        "ply" => super::ply::load(path),
        "stl" => super::stl::load(path),
        "gltf" | "glb" => load_gltf(path),
        _ => Err(Error::UnsupportedFormat { path: path.to_path_buf(), ext }),
    }
}

/// Largest mesh file read (4 GiB): a binary PLY of the 20M triangles a
/// glTF scene may hold takes about 400 MB.
pub const MAX_MESH_FILE_BYTES: u64 = 4 << 30;

fn malformed(path: &Path, reason: impl ToString) -> Error {
    Error::MalformedMesh { path: path.to_path_buf(), reason: reason.to_string() }
}

/// OBJ through tobj, untriangulated: tobj fans polygons, which is wrong for
/// concave ones, so each face is triangulated here from its arity.
fn load_obj(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let opts = tobj::LoadOptions { triangulate: false, single_index: false, ignore_points: true, ignore_lines: true };
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let loaded = match without_lines_and_points(&bytes) {
        Some(filtered) => tobj::load_obj_buf(&mut &filtered[..], &opts, |_| Ok(Default::default())),
        None => tobj::load_obj(path, &opts),
    };
    let (models, _materials) = loaded.map_err(|e| malformed(path, e))?;
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let mut budget = polygon::EarClipBudget::default();
    for m in models {
        let base = vertices.len() as u64;
        let p = &m.mesh.positions;
        if p.len() % 3 != 0 {
            return Err(malformed(path, "position count is not a multiple of 3"));
        }
        // f64 already: tobj's `use_f64` feature keeps the file's digits.
        vertices.extend(p.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])));
        obj_faces(path, &m.mesh, base, &vertices, &mut triangles, &mut budget)?;
    }
    narrow(path, vertices, triangles)
}

/// Triangulates the faces of one tobj model, whose indices start at
/// `base` in `vertices`. Empty arities mean every face is a triangle.
fn obj_faces(path: &Path, mesh: &tobj::Mesh, base: u64, vertices: &[DVec3], out: &mut Vec<[u64; 3]>, budget: &mut polygon::EarClipBudget) -> Result<()> {
    let idx = &mesh.indices;
    let triangles_only = std::iter::repeat_n(3, if mesh.face_arities.is_empty() { idx.len() / 3 } else { 0 });
    let mut face = Vec::new();
    let mut start = 0;
    for n in mesh.face_arities.iter().copied().chain(triangles_only) {
        let corners = idx.get(start..start + n as usize).ok_or_else(|| malformed(path, "face arities exceed the indices"))?;
        face.clear();
        face.extend(corners.iter().map(|&i| i as u64 + base));
        polygon::triangulate(vertices, &face, out, budget);
        start += n as usize;
    }
    Ok(())
}

/// A copy of an OBJ file without its `l` (polyline) and `p` (point) lines,
/// or `None` when it has none. tobj reads `l a b c` as a polygon, which
/// would add a triangle that is not in the model.
fn without_lines_and_points(bytes: &[u8]) -> Option<Vec<u8>> {
    let is_drop = |line: &[u8]| {
        let mut words = line.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty());
        matches!(words.next(), Some(b"l") | Some(b"p"))
    };
    if !bytes.split(|&b| b == b'\n').any(is_drop) {
        return None;
    }
    let mut out = Vec::with_capacity(bytes.len());
    for line in bytes.split_inclusive(|&b| b == b'\n').filter(|l| !is_drop(l)) {
        out.extend_from_slice(line);
    }
    Some(out)
}

/// Converts 64-bit indices to `u32`, rejecting any beyond the vertex count.
pub(super) fn narrow(
    path: &Path,
    vertices: Vec<DVec3>,
    triangles: Vec<[u64; 3]>,
) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let n = vertices.len();
    let mut out = Vec::with_capacity(triangles.len());
    for (face, t) in triangles.into_iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&i| i as usize >= n || i > u32::MAX as u64) {
            return Err(Error::IndexOutOfRange { path: path.to_path_buf(), face, index, count: n });
        }
        out.push([t[0] as u32, t[1] as u32, t[2] as u32]);
    }
    Ok((vertices, out))
}

/// Deepest glTF node nesting accepted: real scenes are a few levels deep,
/// a cycle (a node among its own descendants) is infinitely deep.
const MAX_NODE_DEPTH: usize = 64;
/// Most node and primitive instances a glTF scene may expand to: a chain
/// of nodes that each list the next one twice as children doubles at every
/// level, and every instance of a node repeats its primitives (points and
/// lines included, though they add nothing).
const MAX_NODE_VISITS: usize = 1_000_000;
/// Most vertices, and most triangles, all instances together may have;
/// checked before each primitive is read so memory stays bounded (about
/// 1 GB here; a few kilobytes of shared nodes could otherwise ask for
/// tens of gigabytes).
const MAX_GLTF_VERTICES: usize = 20_000_000;
const MAX_GLTF_TRIANGLES: usize = 20_000_000;

/// The merged geometry of a glTF scene.
#[derive(Default)]
struct GltfMesh {
    vertices: Vec<DVec3>,
    triangles: Vec<[u64; 3]>,
}

fn load_gltf(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let (doc, buffers) = read_gltf(path)?;
    let mut out = GltfMesh::default();
    let scene = doc.default_scene().or_else(|| doc.scenes().next());
    let mut stack: Vec<(gltf::Node, DMat4, usize)> = match &scene {
        Some(s) => s.nodes().map(|n| (n, DMat4::IDENTITY, 1)).collect(),
        None => doc.nodes().map(|n| (n, DMat4::IDENTITY, 1)).collect(),
    };
    let mut visits = 0;
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > MAX_NODE_DEPTH {
            return Err(malformed(path, format!(
                "node hierarchy deeper than {MAX_NODE_DEPTH} levels at node {} (a cycle?)", node.index()
            )));
        }
        // The node and each of its primitives count as one instance.
        visits += 1 + node.mesh().map_or(0, |m| m.primitives().len());
        if visits > MAX_NODE_VISITS {
            return Err(malformed(path, format!(
                "the scene expands to more than {MAX_NODE_VISITS} node and primitive instances (nodes shared by many parents?)"
            )));
        }
        let local = DMat4::from_cols_array_2d(&node.transform().matrix().map(|c| c.map(|x| x as f64)));
        let world = parent * local;
        stack.extend(node.children().map(|child| (child, world, depth + 1)));
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                add_primitive(path, &mesh, &prim, &buffers, world, &mut out)?;
            }
        }
    }
    narrow(path, out.vertices, out.triangles)
}

/// The one glTF extension that changes how geometry is read: positions
/// may be 8- or 16-bit integers (normalized or not), scaled back by the
/// node transforms. [`read_positions`] reads them; the gltf crate's
/// validation refuses the extension, so it is taken out of the required
/// list before validating.
const MESH_QUANTIZATION: &str = "KHR_mesh_quantization";

/// The validated document and its buffers. Images are not read: only
/// geometry is used, and decoding a scene's textures would cost time and
/// memory for nothing. Buffers are read by [`read_buffers`], not the gltf
/// crate's importer, which reads `file:` URIs such as `/dev/zero` without
/// end and panics on a URI that percent-decodes to invalid UTF-8.
fn read_gltf(path: &Path) -> Result<(gltf::Document, Vec<gltf::buffer::Data>)> {
    let bytes = crate::io::read_capped(path, MAX_MESH_FILE_BYTES, "glTF file")?;
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| malformed(path, e))?;
    drop(bytes);
    let mut json = document.into_json();
    json.extensions_required.retain(|e| e != MESH_QUANTIZATION);
    let doc = gltf::Document::from_json(json).map_err(|e| malformed(path, e))?;
    let buffers = read_buffers(path, &doc, blob)?;
    Ok((doc, buffers))
}

/// Every buffer of `doc`: the GLB's binary chunk, a base64 `data:` URI, or
/// a file (relative to the glTF, or a `file:` URI) read through the capped
/// reader, all together at most [`MAX_MESH_FILE_BYTES`]. A buffer shorter
/// than its declared `byteLength` is an error.
fn read_buffers(path: &Path, doc: &gltf::Document, mut blob: Option<Vec<u8>>) -> Result<Vec<gltf::buffer::Data>> {
    use gltf::buffer::Source;
    let base = path.parent().unwrap_or(Path::new("."));
    let mut total = 0u64;
    let mut out = Vec::with_capacity(doc.buffers().len());
    for buffer in doc.buffers() {
        let what = || format!("buffer {}", buffer.index());
        let data = match buffer.source() {
            Source::Bin => blob.take().ok_or_else(|| malformed(path, format!("{}: refers to a GLB binary chunk there is none of", what())))?,
            Source::Uri(uri) if uri.starts_with("data:") => {
                gltf::buffer::Data::from_source(buffer.source(), None).map_err(|e| malformed(path, format!("{}: {e}", what())))?.0
            }
            Source::Uri(uri) => {
                let file = buffer_file(base, uri).map_err(|e| malformed(path, format!("{}: {e}", what())))?;
                if !file.is_file() {
                    let why = if file.exists() { "is not a regular file" } else { "does not exist" };
                    return Err(malformed(path, format!("{}: {} {why}", what(), file.display())));
                }
                let cap = MAX_MESH_FILE_BYTES.saturating_sub(total);
                crate::io::read_capped(&file, cap, "glTF buffer").map_err(|e| malformed(path, format!("{}: {e}", what())))?
            }
        };
        if data.len() < buffer.length() {
            return Err(malformed(path, format!("{}: holds {} bytes, fewer than its byteLength {}", what(), data.len(), buffer.length())));
        }
        total = total.saturating_add(data.len() as u64);
        if total > MAX_MESH_FILE_BYTES {
            return Err(malformed(path, format!("the buffers hold more than the {} GiB a mesh may have", MAX_MESH_FILE_BYTES >> 30)));
        }
        out.push(gltf::buffer::Data(data));
    }
    Ok(out)
}

/// The file a buffer URI names: `file:` URIs as they are, other URIs
/// percent-decoded and relative to the glTF's folder. Other schemes
/// (`http:`) are not fetched.
fn buffer_file(base: &Path, uri: &str) -> std::result::Result<std::path::PathBuf, String> {
    if let Some(rest) = uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        return Ok(rest.into());
    }
    if uri.contains(':') {
        return Err(format!("URI '{uri}' is neither a data: URI nor a file; only local files are read"));
    }
    let decoded = urlencoding::decode(uri).map_err(|_| format!("URI '{uri}' does not percent-decode to UTF-8"))?;
    Ok(base.join(&*decoded))
}

/// Appends one primitive, placed by `world`, to `out`. Triangle lists,
/// strips and fans are read; other modes (points, lines) are skipped. A
/// triangle primitive whose positions or indices cannot be read is an
/// error rather than a silently missing part.
fn add_primitive(
    path: &Path,
    mesh: &gltf::Mesh,
    prim: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    world: DMat4,
    out: &mut GltfMesh,
) -> Result<()> {
    use gltf::mesh::Mode;
    let mode = prim.mode();
    if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
        return Ok(());
    }
    let what = || format!("mesh {} primitive {}", mesh.index(), prim.index());
    let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
    let positions = prim.get(&gltf::Semantic::Positions).ok_or_else(|| malformed(path, format!("{}: has no POSITION", what())))?;
    let count = positions.count();
    let index_count = prim.indices().map_or(count, |a| a.count());
    check_size(path, out, mode, count, index_count)?;
    let pos = read_positions(&positions, get).map_err(|e| malformed(path, format!("{}: POSITION {e}", what())))?;
    let base = out.vertices.len() as u64;
    out.vertices.extend(pos.into_iter().map(|p| world.transform_point3(p)));
    let idx: Vec<u64> = match prim.indices() {
        None => (0..count as u64).collect(),
        Some(a) => read_indices(&a, get).map_err(|e| malformed(path, format!("{}: indices {e}", what())))?,
    };
    let tris = triangles_of(mode, &idx).map_err(|e| malformed(path, format!("{}: {e}", what())))?;
    let flip = world.determinant() < 0.0;
    out.triangles.extend(tris.map(|t| {
        let t = t.map(|i| i + base);
        if flip { [t[0], t[2], t[1]] } else { t }
    }));
    Ok(())
}

/// The positions of `a` as the model's coordinates: 32-bit floats, or
/// (KHR_mesh_quantization) 8- and 16-bit integers, normalized ones mapped
/// to [0, 1] or [-1, 1] as the extension defines; the node transforms then
/// scale them back. Any other type is an error rather than bytes read as
/// the wrong type.
fn read_positions<'s>(a: &gltf::Accessor, get: impl Clone + Fn(gltf::Buffer) -> Option<&'s [u8]>) -> std::result::Result<Vec<DVec3>, String> {
    use gltf::accessor::{DataType, Dimensions};
    if a.dimensions() != Dimensions::Vec3 {
        return Err(format!("is {:?}, not VEC3", a.dimensions()));
    }
    let n = a.normalized();
    match a.data_type() {
        DataType::F32 => read_vec3::<f32>(a, get, |x| x as f64),
        DataType::I8 => read_vec3::<i8>(a, get, |x| if n { (x as f64 / 127.0).max(-1.0) } else { x as f64 }),
        DataType::U8 => read_vec3::<u8>(a, get, |x| if n { x as f64 / 255.0 } else { x as f64 }),
        DataType::I16 => read_vec3::<i16>(a, get, |x| if n { (x as f64 / 32767.0).max(-1.0) } else { x as f64 }),
        DataType::U16 => read_vec3::<u16>(a, get, |x| if n { x as f64 / 65535.0 } else { x as f64 }),
        DataType::U32 => Err("has 32-bit integer components, which positions may not".into()),
    }
}

fn read_vec3<'s, T: gltf::accessor::Item + Copy>(
    a: &gltf::Accessor,
    get: impl Clone + Fn(gltf::Buffer) -> Option<&'s [u8]>,
    f: impl Fn(T) -> f64,
) -> std::result::Result<Vec<DVec3>, String> {
    check_readable(a, std::mem::size_of::<[T; 3]>())?;
    let iter = gltf::accessor::Iter::<[T; 3]>::new(a.clone(), get).ok_or("reaches past its buffer")?;
    Ok(iter.map(|[x, y, z]| DVec3::new(f(x), f(y), f(z))).collect())
}

/// The indices of `a`: unsigned 8-, 16- or 32-bit scalars (the gltf
/// crate's own reader panics on any other type).
fn read_indices<'s>(a: &gltf::Accessor, get: impl Clone + Fn(gltf::Buffer) -> Option<&'s [u8]>) -> std::result::Result<Vec<u64>, String> {
    use gltf::accessor::{DataType, Dimensions, Iter};
    if a.dimensions() != Dimensions::Scalar {
        return Err(format!("are {:?}, not SCALAR", a.dimensions()));
    }
    check_readable(a, a.data_type().size())?;
    let past = || "reach past their buffer".to_string();
    Ok(match a.data_type() {
        DataType::U8 => Iter::<u8>::new(a.clone(), get).ok_or_else(past)?.map(u64::from).collect(),
        DataType::U16 => Iter::<u16>::new(a.clone(), get).ok_or_else(past)?.map(u64::from).collect(),
        DataType::U32 => Iter::<u32>::new(a.clone(), get).ok_or_else(past)?.map(u64::from).collect(),
        t => return Err(format!("are {t:?}, not unsigned 8-, 16- or 32-bit integers")),
    })
}

/// Refuses what the gltf crate's reader would panic on rather than
/// report: an empty accessor or sparse part (the spec requires counts of
/// at least 1; the reader computes `count - 1`), and a buffer view whose
/// byteStride is shorter than the `element` bytes it holds (validation
/// allows any stride of 4 to 252; the reader asserts each element fits).
fn check_readable(a: &gltf::Accessor, element: usize) -> std::result::Result<(), String> {
    if a.count() == 0 {
        return Err("has count 0".into());
    }
    let stride_ok = |view: Option<gltf::buffer::View>, size: usize| match view.and_then(|v| v.stride()) {
        Some(stride) if stride < size => Err(format!("has a byteStride of {stride}, shorter than its {size}-byte elements")),
        _ => Ok(()),
    };
    stride_ok(a.view(), element)?;
    if let Some(sparse) = a.sparse() {
        if sparse.count() == 0 {
            return Err("has a sparse part of count 0".into());
        }
        stride_ok(Some(sparse.indices().view()), sparse.indices().index_type().size())?;
        stride_ok(Some(sparse.values().view()), element)?;
    }
    Ok(())
}

/// Refuses a primitive of `vertices` positions and `indices` indices that
/// would take the scene past [`MAX_GLTF_VERTICES`] or
/// [`MAX_GLTF_TRIANGLES`], before it is read.
fn check_size(path: &Path, out: &GltfMesh, mode: gltf::mesh::Mode, vertices: usize, indices: usize) -> Result<()> {
    let triangles = match mode {
        gltf::mesh::Mode::Triangles => indices / 3,
        _ => indices.saturating_sub(2),
    };
    if out.vertices.len().saturating_add(vertices) > MAX_GLTF_VERTICES
        || out.triangles.len().saturating_add(triangles) > MAX_GLTF_TRIANGLES
    {
        return Err(malformed(path, format!(
            "the scene has more than {MAX_GLTF_VERTICES} vertices or {MAX_GLTF_TRIANGLES} triangles \
             over all its node instances"
        )));
    }
    Ok(())
}

/// The triangles of a triangle list, strip or fan, as glTF defines them:
/// strip triangle k is `k, k+1, k+2` with every other one turned round to
/// keep the winding, fan triangle k is `0, k+1, k+2`. Strip triangles that
/// repeat a vertex (joins between strips) are left out.
fn triangles_of(mode: gltf::mesh::Mode, idx: &[u64]) -> std::result::Result<Box<dyn Iterator<Item = [u64; 3]> + '_>, String> {
    use gltf::mesh::Mode;
    let n = idx.len().saturating_sub(2);
    Ok(match mode {
        Mode::Triangles if !idx.len().is_multiple_of(3) => return Err("index count is not a multiple of 3".into()),
        Mode::Triangles => Box::new(idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]])),
        Mode::TriangleStrip => Box::new(
            (0..n)
                .map(move |k| if k % 2 == 0 { [idx[k], idx[k + 1], idx[k + 2]] } else { [idx[k], idx[k + 2], idx[k + 1]] })
                .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]),
        ),
        Mode::TriangleFan => Box::new((0..n).map(move |k| [idx[0], idx[k + 1], idx[k + 2]])),
        _ => Box::new(std::iter::empty()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    fn err(r: Result<(Vec<DVec3>, Vec<[u32; 3]>)>) -> String {
        r.map(|_| ()).unwrap_err().to_string()
    }

    const SQUARE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn obj_polylines_and_points_are_not_faces() {
        let d = tempfile::tempdir().unwrap();
        let p = write(d.path(), "l.obj", &format!("{SQUARE_OBJ}f 1 2 3\nl 1 2 3 4\n  p 1 2 3\nl 2 4\n"));
        assert_eq!(load_obj(&p).unwrap().1, vec![[0, 1, 2]]);
        let p = write(d.path(), "lonly.obj", &format!("{SQUARE_OBJ}l 1 2 3\n"));
        assert!(load_obj(&p).unwrap().1.is_empty());
    }

    #[test]
    fn obj_concave_faces_are_ear_clipped_convex_ones_fanned_and_positions_are_f64() {
        let d = tempfile::tempdir().unwrap();
        // An L from the corner next to its reflex one, then a quad.
        let p = write(d.path(), "l.obj", "v 1 2 0\nv 0 2 0\nv 0 0 0\nv 2 0 0\nv 2 1 0\nv 1 1 0.1\nf 1 2 3 4 5 6\nf 1 2 3 6\n");
        let (v, t) = load_obj(&p).unwrap();
        assert_eq!(t.len(), 4 + 2);
        assert_eq!(t[4..], [[0, 1, 2], [0, 2, 5]]);
        let fanned: Vec<[u32; 3]> = (1..5).map(|k| [0, k, k + 1]).collect();
        assert_ne!(t[..4], fanned[..]);
        assert_eq!(v[5].z, 0.1, "positions are read as f64");
    }

    /// Standard base64 of `data`, for embedding a buffer in a data URI.
    fn base64(data: &[u8]) -> String {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for c in data.chunks(3) {
            let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
            (0..4).for_each(|k| out.push(if k <= c.len() { A[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' }));
        }
        out
    }

    /// A glTF of the unit square's four corners (accessor 0) and the index
    /// list 0 1 3 2 (accessor 1), accessor 2 too long for its data, with the
    /// given nodes and primitives.
    fn gltf(dir: &Path, nodes: &str, primitives: &str) -> std::path::PathBuf {
        let mut bin = Vec::new();
        [[0f32, 0., 0.], [1., 0., 0.], [1., 1., 0.], [0., 1., 0.]].iter().flatten().for_each(|c| bin.extend(c.to_le_bytes()));
        [0u16, 1, 3, 2].iter().for_each(|i| bin.extend(i.to_le_bytes()));
        let text = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":{nodes},
            "meshes":[{{"primitives":{primitives}}}],
            "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":8}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5123,"count":4,"type":"SCALAR"}},
                         {{"bufferView":0,"componentType":5126,"count":1000,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}]}}"#,
            bin.len(),
            base64(&bin)
        );
        write(dir, "t.gltf", &text)
    }

    #[test]
    fn gltf_cycles_and_exponential_node_sharing_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let prim = r#"[{"attributes":{"POSITION":0},"mode":6}]"#;
        let e = err(load_gltf(&gltf(d.path(), r#"[{"mesh":0,"children":[0]}]"#, prim)));
        assert!(e.contains("deeper than 64") && e.contains("cycle"), "{e}");
        let chain: Vec<String> = (0..40).map(|i| format!(r#"{{"children":[{0},{0}]}}"#, i + 1)).collect();
        let nodes = format!(r#"[{},{{"mesh":0}}]"#, chain.join(","));
        let e = err(load_gltf(&gltf(d.path(), &nodes, prim)));
        assert!(e.contains("primitive instances"), "{e}");
        // A shared node within the bounds is instanced at each use.
        let (_, t) = load_gltf(&gltf(d.path(), r#"[{"children":[1,1]},{"mesh":0}]"#, prim)).unwrap();
        assert_eq!(t.len(), 4);
    }

    #[test]
    fn gltf_size_is_capped_before_reading() {
        let out = GltfMesh { vertices: vec![DVec3::ZERO; 10], triangles: vec![[0; 3]; 10] };
        let p = Path::new("t.gltf");
        assert!(check_size(p, &out, gltf::mesh::Mode::Triangles, 10, 30).is_ok());
        let e = check_size(p, &out, gltf::mesh::Mode::Triangles, MAX_GLTF_VERTICES, 3).unwrap_err().to_string();
        assert!(e.contains("more than") && e.contains("t.gltf"), "{e}");
        assert!(check_size(p, &out, gltf::mesh::Mode::TriangleStrip, 4, MAX_GLTF_TRIANGLES).is_err());
    }

    #[test]
    fn gltf_strips_and_fans_are_triangles() {
        let d = tempfile::tempdir().unwrap();
        let node = r#"[{"mesh":0}]"#;
        // Strip 0 1 3 2 and the fan over 0 1 2 3 both make the square, wound +z.
        let strip = r#"[{"attributes":{"POSITION":0},"indices":1,"mode":5}]"#;
        assert_eq!(load_gltf(&gltf(d.path(), node, strip)).unwrap().1, vec![[0, 1, 3], [1, 2, 3]]);
        let fan = r#"[{"attributes":{"POSITION":0},"mode":6}]"#;
        assert_eq!(load_gltf(&gltf(d.path(), node, fan)).unwrap().1, vec![[0, 1, 2], [0, 2, 3]]);
        // Mixed with a list and with points (skipped): the strip is kept.
        let mixed = r#"[{"attributes":{"POSITION":0},"mode":0},{"attributes":{"POSITION":0},"indices":1,"mode":5},
                        {"attributes":{"POSITION":0},"indices":1,"mode":4}]"#;
        let e = err(load_gltf(&gltf(d.path(), node, mixed)));
        assert!(e.contains("mesh 0 primitive 2") && e.contains("multiple of 3"), "{e}");
        let mixed = r#"[{"attributes":{"POSITION":0},"mode":0},{"attributes":{"POSITION":0},"indices":1,"mode":5},
                        {"attributes":{"POSITION":0},"mode":6}]"#;
        assert_eq!(load_gltf(&gltf(d.path(), node, mixed)).unwrap().1, vec![[0, 1, 3], [1, 2, 3], [4, 5, 6], [4, 6, 7]]);
    }

    #[test]
    fn gltf_unreadable_positions_name_the_primitive() {
        let d = tempfile::tempdir().unwrap();
        // Accessor 2 reads past the end of its buffer view.
        let prims = r#"[{"attributes":{"POSITION":0},"mode":6},{"attributes":{"POSITION":2}}]"#;
        let e = err(load_gltf(&gltf(d.path(), r#"[{"mesh":0}]"#, prims)));
        assert!(e.contains("mesh 0 primitive 1") && e.contains("POSITION reaches past its buffer") && e.contains("t.gltf"), "{e}");
    }

    /// A glTF of one tetrahedron: `positions` (one VEC3 accessor of
    /// `component_type`, 4-byte aligned elements of `stride` bytes),
    /// u16 indices unless `float_indices`, `node` (JSON) holding mesh 0,
    /// the buffer at `uri` (None: embedded) and `extra` top-level JSON.
    fn tetra_gltf(dir: &Path, positions: &[u8], stride: usize, component_type: u32, normalized: bool, node: &str, uri: Option<&str>, extra: &str) -> std::path::PathBuf {
        let faces = [0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];
        let mut bin = positions.to_vec();
        faces.iter().for_each(|i| bin.extend(i.to_le_bytes()));
        let uri = uri.map_or_else(|| format!("data:application/octet-stream;base64,{}", base64(&bin)), str::to_string);
        let text = format!(
            r#"{{"asset":{{"version":"2.0"}},{extra}"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{node}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
            "buffers":[{{"byteLength":{},"uri":"{uri}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{},"byteStride":{stride}}},{{"buffer":0,"byteOffset":{},"byteLength":24}}],
            "accessors":[{{"bufferView":0,"componentType":{component_type},"normalized":{normalized},"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}},
                         {{"bufferView":1,"componentType":5123,"count":12,"type":"SCALAR"}}]}}"#,
            bin.len(),
            positions.len(),
            positions.len()
        );
        write(dir, "q.gltf", &text)
    }

    const TETRA: [[f64; 3]; 4] = [[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]];

    #[test]
    fn gltf_quantized_positions_are_read_and_scaled_by_the_node() {
        let d = tempfile::tempdir().unwrap();
        let ext = r#""extensionsUsed":["KHR_mesh_quantization"],"extensionsRequired":["KHR_mesh_quantization"],"#;
        // gltfpack's layout: normalized u16 in [0, 1], scaled back to 0.2 m by the node.
        let node = r#"{"mesh":0,"scale":[0.2,0.2,0.2],"translation":[0.1,0,0]}"#;
        let mut bin = Vec::new();
        TETRA.iter().for_each(|p| {
            p.iter().for_each(|&c| bin.extend(((c * 65535.0) as u16).to_le_bytes()));
            bin.extend([0, 0]);
        });
        let (v, t) = load_gltf(&tetra_gltf(d.path(), &bin, 8, 5123, true, node, None, ext)).unwrap();
        assert_eq!(t.len(), 4);
        for (got, want) in v.iter().zip(TETRA) {
            let want = DVec3::from(want) * 0.2 + DVec3::new(0.1, 0.0, 0.0);
            assert!(got.distance(want) < 1e-7, "{got} vs {want}");
        }
        // Signed normalized bytes: -128 clamps to -1 as the extension says.
        let bin: Vec<u8> = [[-128i8, 0, 0], [127, 0, 0], [0, 127, 0], [0, 0, 127]].iter().flat_map(|p| [p[0] as u8, p[1] as u8, p[2] as u8, 0]).collect();
        let (v, _) = load_gltf(&tetra_gltf(d.path(), &bin, 4, 5120, true, r#"{"mesh":0}"#, None, ext)).unwrap();
        assert_eq!(v[0], DVec3::new(-1.0, 0.0, 0.0));
        assert_eq!(v[1], DVec3::new(1.0, 0.0, 0.0));
        // Plain (not normalized) shorts are their integer values.
        let mut bin = Vec::new();
        TETRA.iter().for_each(|p| {
            p.iter().for_each(|&c| bin.extend(((c * 100.0) as i16).to_le_bytes()));
            bin.extend([0, 0]);
        });
        let (v, _) = load_gltf(&tetra_gltf(d.path(), &bin, 8, 5122, false, r#"{"mesh":0}"#, None, ext)).unwrap();
        assert_eq!(v[3], DVec3::new(0.0, 0.0, 100.0));
        // u32 positions are not a glTF position type.
        let e = err(load_gltf(&tetra_gltf(d.path(), &[0; 48], 12, 5125, false, r#"{"mesh":0}"#, None, ext)));
        assert!(e.contains("32-bit integer"), "{e}");
    }

    #[test]
    fn gltf_hostile_buffers_and_indices_are_errors_not_panics_or_endless_reads() {
        let d = tempfile::tempdir().unwrap();
        let mut floats = Vec::new();
        TETRA.iter().flatten().for_each(|&c| floats.extend((c as f32).to_le_bytes()));
        let node = r#"{"mesh":0}"#;
        let p = tetra_gltf(d.path(), &floats, 12, 5126, false, node, None, "");
        assert_eq!(load_gltf(&p).unwrap().1.len(), 4);
        // Float indices: the gltf crate's reader hits unreachable!().
        let text = std::fs::read_to_string(&p).unwrap().replace(r#""componentType":5123"#, r#""componentType":5126"#);
        let e = err(load_gltf(&write(d.path(), "fi.gltf", &text)));
        assert!(e.contains("indices are F32"), "{e}");
        // A byteStride shorter than a position: the crate's reader asserts.
        let e = err(load_gltf(&tetra_gltf(d.path(), &floats, 4, 5126, false, node, None, "")));
        assert!(e.contains("byteStride of 4, shorter than its 12-byte elements"), "{e}");
        // A URI that percent-decodes to invalid UTF-8 (its importer unwraps).
        let e = err(load_gltf(&tetra_gltf(d.path(), &floats, 12, 5126, false, node, Some("%FF.bin"), "")));
        assert!(e.contains("percent-decode"), "{e}");
        // A device is not a buffer file (its importer read /dev/zero for ever).
        let e = err(load_gltf(&tetra_gltf(d.path(), &floats, 12, 5126, false, node, Some("file:///dev/zero"), "")));
        assert!(e.contains("not a regular file"), "{e}");
        let e = err(load_gltf(&tetra_gltf(d.path(), &floats, 12, 5126, false, node, Some("http://example.com/a.bin"), "")));
        assert!(e.contains("only local files"), "{e}");
        // A relative file buffer is read; one too short for its byteLength is refused.
        let mut bin = floats.clone();
        [0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3].iter().for_each(|i| bin.extend(i.to_le_bytes()));
        std::fs::write(d.path().join("a b.bin"), &bin).unwrap();
        assert_eq!(load_gltf(&tetra_gltf(d.path(), &floats, 12, 5126, false, node, Some("a%20b.bin"), "")).unwrap().1.len(), 4);
        std::fs::write(d.path().join("a b.bin"), &bin[..40]).unwrap();
        let e = err(load_gltf(&tetra_gltf(d.path(), &floats, 12, 5126, false, node, Some("a%20b.bin"), "")));
        assert!(e.contains("fewer than its byteLength"), "{e}");
    }
}
