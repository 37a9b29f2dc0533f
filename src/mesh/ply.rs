//! PLY reader: ASCII, binary little- and big-endian. Reads `x y z` of the
//! `vertex` element, the index lists of the `face` element (polygons are
//! triangulated by [`polygon`](super::polygon)) and of the `tristrips`
//! element (strips restarted by -1); every other element and property is
//! skipped.
//!
//! Nothing in the header is trusted to be small: an element count is
//! checked against the bytes left before its records are read, so a forged
//! count fails at once instead of looping or allocating.

use std::ops::Range;
use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

use super::polygon;

type Parsed<T> = std::result::Result<T, String>;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8, U8, I16, U16, I32, U32, F32, F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Debug)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Le,
    Be,
}

impl Element {
    /// Fewest bytes one record can take: binary, every scalar and every
    /// list's count (an empty list); ASCII, a one-character token per
    /// property and a separator after it.
    fn min_record_bytes(&self, format: Format) -> usize {
        match format {
            Format::Ascii => 2 * self.props.len(),
            _ => self.props.iter().map(|p| match p {
                Property::Scalar(_, t) | Property::List(_, t, _) => t.size(),
            }).sum(),
        }
    }

    /// Refuses a count the rest of the file cannot hold, before looping
    /// over it: `element junk 18446744073709551615` without properties
    /// would otherwise loop for ever, and a forged count would allocate.
    fn check_fits(&self, format: Format, left: usize) -> Parsed<()> {
        if self.count == 0 {
            return Ok(());
        }
        if self.props.is_empty() {
            return Err(format!("element '{}' has {} entries but no properties", self.name, self.count));
        }
        // The last ASCII token needs no separator after it.
        let need = (self.count as u128 * self.min_record_bytes(format) as u128)
            .saturating_sub((format == Format::Ascii) as u128);
        if need > left as u128 {
            return Err(format!(
                "unexpected end of data: element '{}' declares {} entries, more than the {left} bytes left can hold{MISMATCH}",
                self.name, self.count
            ));
        }
        Ok(())
    }
}

/// What an element contributes to the mesh.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// Positions: the indices of the `x`, `y`, `z` properties.
    Vertex([usize; 3]),
    /// Polygons: the index of the vertex-index list property.
    Faces(usize),
    /// Triangle strips, -1 restarting a strip: the index of the list.
    Strips(usize),
    Skipped,
}

impl Kind {
    fn of(el: &Element) -> Parsed<Kind> {
        let list = || {
            el.props.iter().position(|p| matches!(p, Property::List(n, _, _) if n == "vertex_indices" || n == "vertex_index"))
        };
        Ok(match el.name.as_str() {
            "vertex" => {
                let find = |n: &str| el.props.iter().position(|p| matches!(p, Property::Scalar(s, _) if s == n));
                match (find("x"), find("y"), find("z")) {
                    (Some(x), Some(y), Some(z)) => Kind::Vertex([x, y, z]),
                    _ if el.count == 0 => Kind::Skipped,
                    _ => return Err("vertex element lacks x, y or z".into()),
                }
            }
            "face" => list().map_or(Kind::Skipped, Kind::Faces),
            "tristrips" => list().map_or(Kind::Skipped, Kind::Strips),
            _ => Kind::Skipped,
        })
    }
}

/// Header: format, elements, and where the body starts.
struct Header {
    format: Format,
    elements: Vec<Element>,
    body: usize,
}

pub fn load(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes).map_err(|reason| Error::MalformedMesh { path: path.to_path_buf(), reason })
        .and_then(|(v, t)| super::load::narrow(path, v, t))
}

fn parse(bytes: &[u8]) -> Parsed<(Vec<DVec3>, Vec<[u64; 3]>)> {
    let header = parse_header(bytes)?;
    let mut r = Reader { data: &bytes[header.body..], pos: 0, format: header.format };
    let mut mesh = Faces::default();
    for el in &header.elements {
        el.check_fits(header.format, r.data.len() - r.pos.min(r.data.len()))?;
        read_element(el, &mut r, &mut mesh)?;
    }
    if !r.rest_is_blank() {
        return Err(format!("data goes on after the elements the header declares{MISMATCH}"));
    }
    Ok(mesh.finish())
}

/// Reads the header line by line up to the line that is `end_header`
/// alone (a comment that mentions end_header does not end it); the body
/// starts after that line's newline.
fn parse_header(bytes: &[u8]) -> Parsed<Header> {
    let mut pos = 0;
    let mut format = None;
    let mut elements = Vec::new();
    let mut first = true;
    loop {
        if pos >= bytes.len() {
            return Err("no 'end_header' line".into());
        }
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |k| pos + k);
        let line = String::from_utf8_lossy(&bytes[pos..end]);
        pos = (end + 1).min(bytes.len());
        let words: Vec<&str> = line.split_whitespace().collect();
        if std::mem::take(&mut first) {
            if words != ["ply"] {
                return Err("missing 'ply' magic".into());
            }
        } else if words == ["end_header"] {
            break;
        } else {
            header_line(&words, &mut format, &mut elements)?;
        }
    }
    Ok(Header { format: format.ok_or("no 'format' line")?, elements, body: pos })
}

/// One header line other than the magic and `end_header`. The format's
/// version number is optional (`format ascii` alone is seen in the wild).
fn header_line(words: &[&str], format: &mut Option<Format>, elements: &mut Vec<Element>) -> Parsed<()> {
    let scalar = |t: &str| Scalar::parse(t).ok_or(format!("unknown type '{t}'"));
    match words {
        ["format", f] | ["format", f, _] => {
            *format = Some(match *f {
                "ascii" => Format::Ascii,
                "binary_little_endian" => Format::Le,
                "binary_big_endian" => Format::Be,
                _ => return Err(format!("unknown format '{f}'")),
            })
        }
        ["element", name, n] => elements.push(Element {
            name: name.to_string(),
            count: n.parse().map_err(|_| format!("bad element count '{n}'"))?,
            props: Vec::new(),
        }),
        ["property", "list", c, i, name] => {
            let p = Property::List(name.to_string(), scalar(c)?, scalar(i)?);
            elements.last_mut().ok_or("property before element")?.props.push(p);
        }
        ["property", t, name] => {
            let p = Property::Scalar(name.to_string(), scalar(t)?);
            elements.last_mut().ok_or("property before element")?.props.push(p);
        }
        _ => {} // comment, obj_info, blank
    }
    Ok(())
}

/// Reads every record of one element into `mesh`.
fn read_element(el: &Element, r: &mut Reader, mesh: &mut Faces) -> Parsed<()> {
    let kind = Kind::of(el)?;
    let mut list: Vec<f64> = Vec::new();
    for _ in 0..el.count {
        let mut p = [0.0f64; 3];
        list.clear();
        for (k, prop) in el.props.iter().enumerate() {
            match prop {
                Property::Scalar(_, t) => {
                    let v = r.read(*t)?;
                    if let Kind::Vertex(xyz) = kind {
                        (0..3).filter(|&a| xyz[a] == k).for_each(|a| p[a] = v);
                    }
                }
                Property::List(_, c, i) => {
                    let keep = matches!(kind, Kind::Faces(l) | Kind::Strips(l) if l == k);
                    for _ in 0..list_length(r.read(*c)?)? {
                        let v = r.read(*i)?;
                        if keep {
                            list.push(v);
                        }
                    }
                }
            }
        }
        match kind {
            Kind::Vertex(_) => mesh.vertices.push(DVec3::from_array(p)),
            Kind::Faces(_) => mesh.face(&list)?,
            Kind::Strips(_) => mesh.strips(&list)?,
            Kind::Skipped => {}
        }
    }
    Ok(())
}

/// A list's length, which must be a whole number (a float count type
/// could say 3.5).
fn list_length(n: f64) -> Parsed<usize> {
    if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
        return Err(format!("bad list length {n} (a whole number up to 1e6 is needed){MISMATCH}"));
    }
    Ok(n as usize)
}

/// A vertex index, which must be a whole non-negative number: a float
/// index type can hold `nan` or 2.9, which must not become 0 or 2.
fn vertex_index(v: f64) -> Parsed<u64> {
    if !v.is_finite() || v.fract() != 0.0 {
        return Err(format!("vertex index {v} is not a whole number{MISMATCH}"));
    }
    if v < 0.0 {
        return Err(format!("negative vertex index {v}{MISMATCH}"));
    }
    Ok(v as u64)
}

/// The mesh being read. Polygons of more than three corners are kept
/// aside and triangulated at the end, since their triangulation needs the
/// positions and the vertex element may come after the faces.
#[derive(Default)]
struct Faces {
    vertices: Vec<DVec3>,
    triangles: Vec<[u64; 3]>,
    /// Each polygon: how many triangles come before it, and its corners.
    polygons: Vec<(usize, Range<usize>)>,
    corners: Vec<u64>,
}

impl Faces {
    /// One polygon of the `face` element.
    fn face(&mut self, list: &[f64]) -> Parsed<()> {
        match list.len() {
            3 => self.triangles.push([vertex_index(list[0])?, vertex_index(list[1])?, vertex_index(list[2])?]),
            n if n > 3 => {
                let start = self.corners.len();
                for &v in list {
                    self.corners.push(vertex_index(v)?);
                }
                self.polygons.push((self.triangles.len(), start..self.corners.len()));
            }
            _ => list.iter().try_for_each(|&v| vertex_index(v).map(drop))?,
        }
        Ok(())
    }

    /// One record of the `tristrips` element: strips separated by -1.
    fn strips(&mut self, list: &[f64]) -> Parsed<()> {
        let mut strip = Vec::new();
        for &v in list.iter().chain([-1.0].iter()) {
            if v == -1.0 {
                self.strip(&strip);
                strip.clear();
            } else {
                strip.push(vertex_index(v)?);
            }
        }
        Ok(())
    }

    /// A triangle strip: triangle k is `s[k] s[k+1] s[k+2]`, with every
    /// other one turned round so all wind the same way; triangles that
    /// repeat a vertex (used to stitch strips together) are skipped.
    fn strip(&mut self, s: &[u64]) {
        for k in 0..s.len().saturating_sub(2) {
            let t = if k % 2 == 0 { [s[k], s[k + 1], s[k + 2]] } else { [s[k + 1], s[k], s[k + 2]] };
            if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                self.triangles.push(t);
            }
        }
    }

    /// Positions and triangles, polygons triangulated in their place.
    fn finish(self) -> (Vec<DVec3>, Vec<[u64; 3]>) {
        if self.polygons.is_empty() {
            return (self.vertices, self.triangles);
        }
        let mut out = Vec::with_capacity(self.triangles.len() + self.corners.len());
        let mut done = 0;
        let mut budget = polygon::EarClipBudget::default();
        for (before, corners) in self.polygons {
            out.extend_from_slice(&self.triangles[done..before]);
            done = before;
            polygon::triangulate(&self.vertices, &self.corners[corners], &mut out, &mut budget);
        }
        out.extend_from_slice(&self.triangles[done..]);
        (self.vertices, out)
    }
}

/// Said where the body cannot be what the header describes.
const MISMATCH: &str = " (does the data match the header's element counts and types?)";

struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    format: Format,
}

impl Reader<'_> {
    /// Whether only whitespace (or, in a binary file, zero padding) is left.
    fn rest_is_blank(&self) -> bool {
        let rest = &self.data[self.pos.min(self.data.len())..];
        rest.iter().all(|b| b.is_ascii_whitespace() || (self.format != Format::Ascii && *b == 0))
    }

    fn read(&mut self, t: Scalar) -> std::result::Result<f64, String> {
        if self.format == Format::Ascii {
            while self.pos < self.data.len() && self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            let start = self.pos;
            while self.pos < self.data.len() && !self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            if start == self.pos {
                return Err("unexpected end of data".into());
            }
            let s = std::str::from_utf8(&self.data[start..self.pos]).map_err(|_| "non-text number")?;
            return s.parse::<f64>().map_err(|_| format!("bad number '{s}'"));
        }
        let n = t.size();
        let b = self.data.get(self.pos..self.pos + n).ok_or("unexpected end of data")?;
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == Format::Be {
            a[..n].reverse();
        }
        Ok(match t {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_agree() {
        let ascii = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 255\n1 0 0 0\n0 1 0 7\n3 0 1 2\n";
        let (v, t) = parse(ascii).unwrap();
        assert_eq!(v.len(), 3);
        assert_eq!(t, vec![[0, 1, 2]]);
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        for p in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
            for c in p {
                bin.extend(c.to_le_bytes());
            }
        }
        bin.push(3);
        for i in [0i32, 1, 2] {
            bin.extend(i.to_le_bytes());
        }
        let (v2, t2) = parse(&bin).unwrap();
        assert_eq!(v, v2);
        assert_eq!(t, t2);
    }

    const HEAD: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n";
    const SQUARE: &str = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n";

    #[test]
    fn counts_the_data_cannot_hold_are_refused_before_reading() {
        let junk = format!("{HEAD}element junk 18446744073709551615\nend_header\n{SQUARE}");
        let e = parse(junk.as_bytes()).unwrap_err();
        assert!(e.contains("'junk'") && e.contains("no properties"), "{e}");
        let ascii = "ply\nformat ascii 1.0\nelement vertex 2147483648\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n";
        assert!(parse(ascii.as_bytes()).unwrap_err().contains("bytes left"));
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1000000000000\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
        bin.extend([0u8; 36 + 13]);
        let e = parse(&bin).unwrap_err();
        assert!(e.contains("'face'") && e.contains("bytes left"), "{e}");
        // An element without properties and no entries is harmless.
        let empty = format!("{HEAD}element junk 0\nend_header\n{SQUARE}");
        assert_eq!(parse(empty.as_bytes()).unwrap().0.len(), 4);
    }

    #[test]
    fn only_an_end_header_line_ends_the_header() {
        let text = HEAD.replace("1.0\n", "1.0\ncomment written before end_header was\n")
            + &format!("element face 1\nproperty list uchar int vertex_indices\nend_header \r\n{SQUARE}3 0 1 2\n");
        let (v, t) = parse(text.as_bytes()).unwrap();
        assert_eq!((v.len(), t), (4, vec![[0, 1, 2]]));
    }

    #[test]
    fn list_counts_and_indices_must_be_whole_numbers() {
        let face = |list: &str, types: &str| {
            format!("{HEAD}element face 1\nproperty list {types} vertex_indices\nend_header\n{SQUARE}{list}\n")
        };
        for (list, types, want) in [
            ("3 0 1 nan", "uchar float", "NaN is not a whole number"),
            ("3 0 1 2.9", "uchar float", "2.9 is not a whole number"),
            ("3.5 0 1 2", "float int", "bad list length 3.5"),
            ("3 0 -1 2", "uchar int", "negative vertex index"),
        ] {
            let e = parse(face(list, types).as_bytes()).unwrap_err();
            assert!(e.contains(want), "{list}: {e}");
        }
        assert!(parse(face("3 0 1 2.0", "uchar float").as_bytes()).is_ok());
        let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar float vertex_indices\nend_header\n".to_vec();
        bin.extend([0u8; 36]);
        bin.push(3);
        [0f32, 1.0, 0.7].iter().for_each(|i| bin.extend(i.to_le_bytes()));
        assert!(parse(&bin).unwrap_err().contains("not a whole number"));
    }

    #[test]
    fn format_without_version_is_read() {
        let text = HEAD.replace("ascii 1.0", "ascii")
            + &format!("element face 1\nproperty list uchar int vertex_indices\nend_header\n{SQUARE}3 0 1 2\n");
        assert_eq!(parse(text.as_bytes()).unwrap().1, vec![[0, 1, 2]]);
    }

    #[test]
    fn tristrips_alternate_winding_restart_at_minus_one_and_skip_degenerates() {
        let text = format!("{HEAD}element tristrips 1\nproperty list int int vertex_indices\nend_header\n{SQUARE}11 0 1 3 2 -1 0 1 2 2 3 -1\n");
        let (_, t) = parse(text.as_bytes()).unwrap();
        // 0 1 3 2 is the square as two triangles wound alike; 0 1 2 2 3
        // adds one triangle and two degenerate ones.
        assert_eq!(t, vec![[0, 1, 3], [3, 1, 2], [0, 1, 2]]);
    }

    #[test]
    fn concave_faces_are_ear_clipped_in_place_and_convex_ones_fanned() {
        // An L (6 corners, from one next to its reflex corner, where the fan
        // would cover the notch), a convex quad's fan, and a
        // triangle, with the faces before the vertices.
        let text = "ply\nformat ascii 1.0\nelement face 3\nproperty list uchar int vertex_indices\n\
                    element vertex 8\nproperty float x\nproperty float y\nproperty float z\nend_header\n\
                    6 5 6 0 1 2 4\n4 0 1 2 3\n3 0 1 2\n0 0 0\n2 0 0\n2 1 0\n1 1 0\n1 1 0\n1 2 0\n0 2 0\n0 0 0\n";
        let (v, t) = parse(text.as_bytes()).unwrap();
        assert_eq!(t.len(), 4 + 2 + 1);
        assert_eq!(t[4..], [[0, 1, 2], [0, 2, 3], [0, 1, 2]]);
        let signed = |f: &[u64; 3]| {
            let [a, b, c] = f.map(|i| v[i as usize]);
            0.5 * (b - a).cross(c - a).z
        };
        let area: f64 = t[..4].iter().map(signed).sum();
        assert!((area - 3.0).abs() < 1e-9, "{t:?}");
        assert!(t[..4].iter().all(|f| signed(f) > 0.0), "{t:?}");
    }

    #[test]
    fn truncated_binary_is_an_error() {
        let bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0";
        assert!(parse(bin).unwrap_err().contains("end of data"));
    }

    #[test]
    fn data_past_the_declared_elements_is_an_error() {
        let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        assert!(parse(format!("{head}\n  \n").as_bytes()).is_ok());
        let e = parse(format!("{head}3 2 1 0\n").as_bytes()).unwrap_err();
        assert!(e.contains("goes on after") && e.contains("element counts"), "{e}");
    }
}
