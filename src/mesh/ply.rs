//! PLY reader: ASCII, binary little- and big-endian. Reads `x y z` of the
//! `vertex` element and the index list of the `face` element (polygons are
//! fanned into triangles); every other element and property is skipped.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

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

pub fn load(path: &Path) -> Result<(Vec<DVec3>, Vec<[u32; 3]>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes).map_err(|reason| Error::MalformedMesh { path: path.to_path_buf(), reason })
        .and_then(|(v, t)| super::load::narrow(path, v, t))
}

fn parse(bytes: &[u8]) -> std::result::Result<(Vec<DVec3>, Vec<[u64; 3]>), String> {
    let end = find(bytes, b"end_header").ok_or("no 'end_header' line")?;
    let mut body = end + b"end_header".len();
    // The header ends with "\n" (or "\r\n").
    while body < bytes.len() && (bytes[body] == b'\r' || bytes[body] == b' ') {
        body += 1;
    }
    if body < bytes.len() && bytes[body] == b'\n' {
        body += 1;
    }
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("missing 'ply' magic".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => {
                format = Some(match *f {
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
                let c = Scalar::parse(c).ok_or(format!("unknown type '{c}'"))?;
                let i = Scalar::parse(i).ok_or(format!("unknown type '{i}'"))?;
                elements.last_mut().ok_or("property before element")?.props.push(Property::List(name.to_string(), c, i));
            }
            ["property", t, name] => {
                let t = Scalar::parse(t).ok_or(format!("unknown type '{t}'"))?;
                elements.last_mut().ok_or("property before element")?.props.push(Property::Scalar(name.to_string(), t));
            }
            _ => {} // comment, obj_info, blank
        }
    }
    let format = format.ok_or("no 'format' line")?;
    let mut r = Reader { data: &bytes[body..], pos: 0, format };
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for el in &elements {
        let xyz: Vec<Option<usize>> = ["x", "y", "z"]
            .iter()
            .map(|n| el.props.iter().position(|p| matches!(p, Property::Scalar(s, _) if s == n)))
            .collect();
        for _ in 0..el.count {
            let mut p = [0.0f64; 3];
            let mut face: Vec<u64> = Vec::new();
            for (k, prop) in el.props.iter().enumerate() {
                match prop {
                    Property::Scalar(_, t) => {
                        let v = r.read(*t)?;
                        if el.name == "vertex" {
                            for a in 0..3 {
                                if xyz[a] == Some(k) {
                                    p[a] = v;
                                }
                            }
                        }
                    }
                    Property::List(name, c, i) => {
                        let n = r.read(*c)?;
                        if !(0.0..=1e6).contains(&n) {
                            return Err(format!("bad list length {n}{MISMATCH}"));
                        }
                        let keep = el.name == "face" && (name == "vertex_indices" || name == "vertex_index");
                        for _ in 0..n as usize {
                            let v = r.read(*i)?;
                            if keep {
                                if v < 0.0 {
                                    return Err(format!("negative vertex index {v}{MISMATCH}"));
                                }
                                face.push(v as u64);
                            }
                        }
                    }
                }
            }
            if el.name == "vertex" {
                if xyz.iter().any(Option::is_none) {
                    return Err("vertex element lacks x, y or z".into());
                }
                vertices.push(DVec3::from_array(p));
            } else if face.len() >= 3 {
                for k in 1..face.len() - 1 {
                    triangles.push([face[0], face[k], face[k + 1]]);
                }
            }
        }
    }
    if !r.rest_is_blank() {
        return Err(format!("data goes on after the elements the header declares{MISMATCH}"));
    }
    Ok((vertices, triangles))
}

/// Said where the body cannot be what the header describes.
const MISMATCH: &str = " (does the data match the header's element counts and types?)";

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

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
