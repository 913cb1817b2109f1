//! Minimal PLY triangle-mesh reading and writing (ground-truth meshes).
//!
//! Reads `ascii` and `binary_little_endian` files with a `vertex` element (`x, y, z` of any
//! scalar type; other properties skipped) and a `face` element whose list property
//! (`vertex_indices` or `vertex_index`) holds triangles or polygons (fan-triangulated).
//! Other elements are skipped. Writes `binary_little_endian` with `float x, y, z` and
//! `list uchar uint vertex_indices`.

use std::path::Path;

use glam::Vec3;

use crate::error::{DataError, Result};

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles (counter-clockwise seen from outside for closed meshes this crate writes).
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }

    /// Signed volume (positive for a closed, outward-oriented mesh).
    pub fn volume(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                a.dot(b.cross(c)) as f64 / 6.0
            })
            .sum::<f64>() as f32
    }
}

/// Writes `mesh` as binary little-endian PLY, atomically.
pub fn write_ply(path: &Path, mesh: &TriMesh) -> Result<()> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by gtsr-data\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        mesh.positions.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    out.reserve(mesh.positions.len() * 12 + mesh.triangles.len() * 13);
    for p in &mesh.positions {
        for v in p.to_array() {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&i.to_le_bytes());
        }
    }
    crate::image_io::write_atomic(path, &out)
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
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
    fn read_le(self, b: &[u8]) -> f64 {
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Scalar::U32 => u32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Scalar::F32 => f32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            Scalar::F64 => f64::from_le_bytes(b[..8].try_into().unwrap()),
        }
    }
}

#[derive(Debug)]
enum Prop {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
}

/// Reads a PLY triangle mesh (see the module documentation for what is supported).
pub fn read_ply(path: &Path) -> Result<TriMesh> {
    let data = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let bad = |m: String| DataError::malformed(path, m);
    let end = data
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| bad("no end_header".into()))?;
    let header = std::str::from_utf8(&data[..end]).map_err(|_| bad("header is not text".into()))?;
    let mut body = end + 10;
    while body < data.len() && (data[body] == b'\r' || data[body] == b' ') {
        body += 1;
    }
    if body < data.len() && data[body] == b'\n' {
        body += 1;
    }
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(bad("does not start with 'ply'".into()));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, ..] => format = Some(f.to_string()),
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| bad(format!("bad element count '{count}'")))?,
                props: Vec::new(),
            }),
            ["property", "list", ct, it, name] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| bad("property before element".into()))?;
                let (c, i) = (Scalar::parse(ct), Scalar::parse(it));
                match (c, i) {
                    (Some(c), Some(i)) => e.props.push(Prop::List(name.to_string(), c, i)),
                    _ => return Err(bad(format!("unknown list types '{ct} {it}'"))),
                }
            }
            ["property", ty, name] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| bad("property before element".into()))?;
                let s = Scalar::parse(ty).ok_or_else(|| bad(format!("unknown type '{ty}'")))?;
                e.props.push(Prop::Scalar(name.to_string(), s));
            }
            _ => {}
        }
    }
    let ascii = match format.as_deref() {
        Some("ascii") => true,
        Some("binary_little_endian") => false,
        Some(f) => return Err(bad(format!("unsupported format '{f}'"))),
        None => return Err(bad("no format line".into())),
    };
    let mut mesh = TriMesh::default();
    let body = &data[body..];
    let mut pos = 0usize;
    let mut tokens = if ascii {
        Some(
            std::str::from_utf8(body)
                .map_err(|_| bad("ascii body is not text".into()))?
                .split_ascii_whitespace(),
        )
    } else {
        None
    };
    let mut next = |ty: Scalar| -> Result<f64> {
        if let Some(tok) = tokens.as_mut() {
            let s = tok
                .next()
                .ok_or_else(|| bad("truncated ascii body".into()))?;
            s.parse::<f64>()
                .map_err(|_| bad(format!("cannot parse number '{s}'")))
        } else {
            let n = ty.size();
            if pos + n > body.len() {
                return Err(bad(format!("truncated binary body at byte {pos}")));
            }
            let v = ty.read_le(&body[pos..pos + n]);
            pos += n;
            Ok(v)
        }
    };
    for e in &elements {
        let is_vertex = e.name == "vertex";
        let is_face = e.name == "face";
        for _ in 0..e.count {
            let mut xyz = [0.0f32; 3];
            for p in &e.props {
                match p {
                    Prop::Scalar(name, ty) => {
                        let v = next(*ty)?;
                        if is_vertex {
                            match name.as_str() {
                                "x" => xyz[0] = v as f32,
                                "y" => xyz[1] = v as f32,
                                "z" => xyz[2] = v as f32,
                                _ => {}
                            }
                        }
                    }
                    Prop::List(name, ct, it) => {
                        let n = next(*ct)? as usize;
                        let mut idx = Vec::with_capacity(n);
                        for _ in 0..n {
                            idx.push(next(*it)? as u32);
                        }
                        if is_face && (name == "vertex_indices" || name == "vertex_index") {
                            for k in 1..n.saturating_sub(1) {
                                mesh.triangles.push([idx[0], idx[k], idx[k + 1]]);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                mesh.positions.push(Vec3::from_array(xyz));
            }
        }
    }
    let nv = mesh.positions.len() as u32;
    if let Some(t) = mesh.triangles.iter().find(|t| t.iter().any(|&i| i >= nv)) {
        return Err(bad(format!(
            "face {t:?} refers to a vertex beyond the {nv} vertices"
        )));
    }
    Ok(mesh)
}
