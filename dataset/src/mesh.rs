//! Triangle meshes in millimetres: STL (binary and ASCII) and OBJ loading, checks, transforms.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Affine3A, Vec3};

/// Which axis of a file points "up" (away from the sensor's base, towards the dome's top).
///
/// The sensor frame is Z-up; the DenseTact kit's STL files are Y-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum UpAxis {
    /// `y` is the height axis (the kit's convention): `(x, y, z) -> (x, -z, y)`.
    #[default]
    Y,
    /// `z` is already the height axis.
    Z,
}

impl UpAxis {
    /// Proper rotation (determinant +1) from the file's axes to the sensor frame.
    pub fn to_sensor(self, p: Vec3) -> Vec3 {
        match self {
            UpAxis::Y => Vec3::new(p.x, -p.z, p.y),
            UpAxis::Z => p,
        }
    }
}

/// How to read a mesh file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadOptions {
    pub up: UpAxis,
    /// Multiplies coordinates to get millimetres (1000 for a file in metres).
    pub scale_to_mm: f32,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { up: UpAxis::Y, scale_to_mm: 1.0 }
    }
}

/// Meshes smaller than this (largest side, mm) are taken to be in metres by mistake.
pub const MIN_EXTENT_MM: f32 = 0.5;
/// Meshes larger than this (largest side, mm) cannot be pressed into a fingertip sensor.
pub const MAX_EXTENT_MM: f32 = 2000.0;

#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error(
        "{path}: truncated binary STL: header announces {triangles} triangles ({expected} bytes) but the file has {actual} bytes"
    )]
    Truncated { path: PathBuf, triangles: u64, expected: u64, actual: u64 },
    #[error("{path}: line {line}: {message}")]
    Parse { path: PathBuf, line: usize, message: String },
    #[error("{path}: triangle {triangle} has a non-finite coordinate (NaN or infinity)")]
    NonFinite { path: PathBuf, triangle: usize },
    #[error("{path}: the mesh has no triangles")]
    Empty { path: PathBuf },
    #[error("{path}: the mesh is {extent_mm} mm across: {hint}")]
    AbsurdSize { path: PathBuf, extent_mm: f32, hint: &'static str },
    #[error("{path}: unsupported mesh format (expected .stl or .obj)")]
    Format { path: PathBuf },
}

/// An indexed triangle mesh. Vertices are welded: triangles that share an edge share its two
/// vertex indices and bit-identical coordinates, which keeps ray casting watertight.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Builds a welded mesh from a triangle soup.
    pub fn from_soup(soup: impl IntoIterator<Item = [Vec3; 3]>) -> Mesh {
        let mut index: HashMap<[u32; 3], u32> = HashMap::new();
        let mut mesh = Mesh::default();
        for tri in soup {
            let ids = tri.map(|p| {
                // -0.0 and 0.0 are the same point.
                let p = p + Vec3::ZERO;
                *index.entry(p.to_array().map(f32::to_bits)).or_insert_with(|| {
                    mesh.vertices.push(p);
                    mesh.vertices.len() as u32 - 1
                })
            });
            mesh.triangles.push(ids);
        }
        mesh
    }

    /// Loads an STL or OBJ file (by extension), converts to the sensor frame and checks it.
    pub fn load(path: &Path, opts: LoadOptions) -> Result<Mesh, MeshError> {
        // The format first: a wrong file is refused as such before it is read.
        mesh_format(path)?;
        let bytes = std::fs::read(path).map_err(|e| MeshError::Io { path: path.into(), source: e })?;
        Mesh::parse(path, &bytes, opts)
    }

    /// [`load`](Self::load) on a file's bytes; `path` gives the format (by extension) and names
    /// the file in errors.
    pub fn parse(path: &Path, bytes: &[u8], opts: LoadOptions) -> Result<Mesh, MeshError> {
        let soup = match mesh_format(path)? {
            MeshFormat::Stl => parse_stl(path, bytes)?,
            MeshFormat::Obj => parse_obj(path, bytes)?,
        };
        Mesh::from_checked_soup(path, soup, opts)
    }

    /// Checks a triangle soup in file coordinates, then scales, rotates and welds it.
    pub fn from_checked_soup(path: &Path, soup: Vec<[Vec3; 3]>, opts: LoadOptions) -> Result<Mesh, MeshError> {
        if soup.is_empty() {
            return Err(MeshError::Empty { path: path.into() });
        }
        if let Some(triangle) = soup.iter().position(|t| t.iter().any(|p| !p.is_finite())) {
            return Err(MeshError::NonFinite { path: path.into(), triangle });
        }
        let mesh = Mesh::from_soup(soup.into_iter().map(|t| t.map(|p| opts.up.to_sensor(p * opts.scale_to_mm))));
        let (lo, hi) = mesh.bounds();
        let extent_mm = (hi - lo).max_element();
        if extent_mm < MIN_EXTENT_MM {
            let hint = "too small for millimetres; if the file is in metres, scale it by 1000";
            return Err(MeshError::AbsurdSize { path: path.into(), extent_mm, hint });
        }
        if extent_mm > MAX_EXTENT_MM {
            let hint = "too large for a fingertip sensor; check the file's units (mm expected)";
            return Err(MeshError::AbsurdSize { path: path.into(), extent_mm, hint });
        }
        Ok(mesh)
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.vertices
            .iter()
            .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), &p| (lo.min(p), hi.max(p)))
    }

    /// Applies a rigid transform in place. Welding is preserved: each vertex moves once.
    pub fn transform(&mut self, pose: &Affine3A) {
        for v in &mut self.vertices {
            *v = pose.transform_point3(*v);
        }
    }

    pub fn transformed(&self, pose: &Affine3A) -> Mesh {
        let mut m = self.clone();
        m.transform(pose);
        m
    }

    /// Appends another mesh's triangles (vertex indices offset).
    pub fn append(&mut self, other: &Mesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
    }

    pub fn triangle(&self, i: usize) -> [Vec3; 3] {
        self.triangles[i].map(|v| self.vertices[v as usize])
    }

    /// The mesh as Wavefront OBJ text (positions and 1-based triangle indices).
    pub fn to_obj(&self) -> String {
        use std::fmt::Write;
        let mut out = String::with_capacity(self.vertices.len() * 40 + self.triangles.len() * 24);
        for v in &self.vertices {
            let _ = writeln!(out, "v {} {} {}", v.x, v.y, v.z);
        }
        for [a, b, c] in &self.triangles {
            let _ = writeln!(out, "f {} {} {}", a + 1, b + 1, c + 1);
        }
        out
    }

    /// The mesh as ASCII STL text.
    pub fn to_ascii_stl(&self) -> String {
        use std::fmt::Write;
        let mut out = String::from("solid mesh\n");
        for i in 0..self.triangles.len() {
            let [a, b, c] = self.triangle(i);
            let n = (b - a).cross(c - a).normalize_or_zero();
            let _ = writeln!(out, " facet normal {} {} {}\n  outer loop", n.x, n.y, n.z);
            for p in [a, b, c] {
                let _ = writeln!(out, "   vertex {} {} {}", p.x, p.y, p.z);
            }
            out.push_str("  endloop\n endfacet\n");
        }
        out.push_str("endsolid mesh\n");
        out
    }

    /// Writes a binary STL (used for tests and for exporting procedural kit parts).
    pub fn to_binary_stl(&self) -> Vec<u8> {
        let mut out = vec![0u8; 80];
        out[..5].copy_from_slice(b"solid"); // as the kit's files do: the header lies.
        out.extend_from_slice(&(self.triangles.len() as u32).to_le_bytes());
        for i in 0..self.triangles.len() {
            let [a, b, c] = self.triangle(i);
            let n = (b - a).cross(c - a).normalize_or_zero();
            for p in [n, a, b, c] {
                for x in p.to_array() {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
            out.extend_from_slice(&[0, 0]);
        }
        out
    }
}

enum MeshFormat {
    Stl,
    Obj,
}

/// A mesh file's format, by its extension (any case).
fn mesh_format(path: &Path) -> Result<MeshFormat, MeshError> {
    match path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).as_deref() {
        Some("stl") => Ok(MeshFormat::Stl),
        Some("obj") => Ok(MeshFormat::Obj),
        _ => Err(MeshError::Format { path: path.into() }),
    }
}

/// Parses STL bytes. Binary or ASCII is decided by size (84 + 50 n bytes), never by the first
/// word: the kit's binary files begin with "solid" too.
pub fn parse_stl(path: &Path, bytes: &[u8]) -> Result<Vec<[Vec3; 3]>, MeshError> {
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes(bytes[80..84].try_into().unwrap()) as u64;
        let expected = 84 + 50 * n;
        if expected == bytes.len() as u64 {
            return Ok(parse_binary_stl(&bytes[84..]));
        }
        let looks_ascii = bytes.trim_ascii_start().starts_with(b"solid") && bytes.is_ascii();
        if !looks_ascii {
            return Err(MeshError::Truncated { path: path.into(), triangles: n, expected, actual: bytes.len() as u64 });
        }
    } else if !bytes.trim_ascii_start().starts_with(b"solid") {
        let parse = MeshError::Parse {
            path: path.into(),
            line: 1,
            message: format!("only {} bytes: neither a binary STL (84-byte header) nor ASCII STL", bytes.len()),
        };
        return Err(parse);
    }
    parse_ascii_stl(path, std::str::from_utf8(bytes).unwrap_or_default())
}

fn parse_binary_stl(body: &[u8]) -> Vec<[Vec3; 3]> {
    body.chunks_exact(50)
        .map(|rec| {
            let f = |i: usize| f32::from_le_bytes(rec[i * 4..i * 4 + 4].try_into().unwrap());
            // Skip the stored normal (floats 0..3): it is recomputed from the winding.
            [Vec3::new(f(3), f(4), f(5)), Vec3::new(f(6), f(7), f(8)), Vec3::new(f(9), f(10), f(11))]
        })
        .collect()
}

fn parse_ascii_stl(path: &Path, text: &str) -> Result<Vec<[Vec3; 3]>, MeshError> {
    let err = |line: usize, message: String| MeshError::Parse { path: path.into(), line, message };
    let mut soup = Vec::new();
    let mut current: Vec<Vec3> = Vec::with_capacity(3);
    let mut in_facet = false;
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("vertex") => {
                let coords: Vec<&str> = words.collect();
                if coords.len() != 3 {
                    return Err(err(i + 1, format!("vertex needs 3 coordinates, got {}", coords.len())));
                }
                let mut p = [0f32; 3];
                for (k, c) in coords.iter().enumerate() {
                    p[k] = c.parse().map_err(|_| err(i + 1, format!("not a number: {c:?}")))?;
                }
                if !in_facet || current.len() == 3 {
                    return Err(err(i + 1, "vertex outside a facet, or more than 3 in one".into()));
                }
                current.push(Vec3::from_array(p));
            }
            Some("facet") => {
                in_facet = true;
                current.clear();
            }
            Some("endfacet") => {
                if current.len() != 3 {
                    return Err(err(i + 1, format!("facet has {} vertices, expected 3", current.len())));
                }
                soup.push([current[0], current[1], current[2]]);
                in_facet = false;
            }
            _ => {}
        }
    }
    if in_facet {
        return Err(err(text.lines().count(), "file ends inside a facet (truncated?)".into()));
    }
    Ok(soup)
}

/// Parses OBJ bytes (`path` names the file in errors): positions and faces, polygons
/// triangulated; materials and texture coordinates are not read.
pub fn parse_obj(path: &Path, bytes: &[u8]) -> Result<Vec<[Vec3; 3]>, MeshError> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: false, ..Default::default() };
    let no_materials = |_: &Path| Err(tobj::LoadError::OpenFileFailed);
    let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &opts, no_materials)
        .map_err(|e| MeshError::Parse { path: path.into(), line: 0, message: format!("OBJ: {e}") })?;
    let mut soup = Vec::new();
    for m in &models {
        let pos = &m.mesh.positions;
        let vertex = |i: u32| -> Option<Vec3> {
            let i = i as usize * 3;
            Some(Vec3::new(*pos.get(i)?, *pos.get(i + 1)?, *pos.get(i + 2)?))
        };
        for t in m.mesh.indices.chunks_exact(3) {
            let tri = [vertex(t[0]), vertex(t[1]), vertex(t[2])];
            let [Some(a), Some(b), Some(c)] = tri else {
                return Err(MeshError::Parse {
                    path: path.into(),
                    line: 0,
                    message: format!("OBJ object {:?} indexes a missing vertex", m.name),
                });
            };
            soup.push([a, b, c]);
        }
    }
    Ok(soup)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube_soup() -> Vec<[Vec3; 3]> {
        crate::shapes::box_mesh(Vec3::splat(10.0)).triangles_as_soup()
    }

    impl Mesh {
        fn triangles_as_soup(&self) -> Vec<[Vec3; 3]> {
            (0..self.triangles.len()).map(|i| self.triangle(i)).collect()
        }
    }

    #[test]
    fn binary_stl_starting_with_solid_round_trips() {
        let mesh = Mesh::from_soup(cube_soup());
        let bytes = mesh.to_binary_stl();
        assert!(bytes.starts_with(b"solid"));
        let back = Mesh::from_soup(parse_stl(Path::new("x.stl"), &bytes).unwrap());
        assert_eq!(back, mesh);
        assert_eq!(back.vertices.len(), 8, "welding joins the cube's corners");
    }

    #[test]
    fn obj_and_ascii_stl_round_trip() {
        let mesh = Mesh::from_soup(cube_soup());
        let obj = Mesh::from_soup(parse_obj(Path::new("c.obj"), mesh.to_obj().as_bytes()).unwrap());
        assert_eq!(obj, mesh);
        let stl = Mesh::from_soup(parse_stl(Path::new("c.stl"), mesh.to_ascii_stl().as_bytes()).unwrap());
        assert_eq!(stl, mesh);
        let opts = LoadOptions { up: UpAxis::Z, scale_to_mm: 1.0 };
        assert_eq!(Mesh::parse(Path::new("c.OBJ"), mesh.to_obj().as_bytes(), opts).unwrap(), mesh);
        let e = Mesh::parse(Path::new("c.ply"), b"ply", opts).unwrap_err().to_string();
        assert!(e.contains("c.ply") && e.contains("expected .stl or .obj"), "{e}");
    }

    #[test]
    fn ascii_stl_parses() {
        let text = "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n";
        let soup = parse_stl(Path::new("a.stl"), text.as_bytes()).unwrap();
        assert_eq!(soup, vec![[Vec3::ZERO, Vec3::X, Vec3::Y]]);
    }

    #[test]
    fn bad_files_are_named_errors() {
        let p = Path::new("part.stl");
        let mut bytes = Mesh::from_soup(cube_soup()).to_binary_stl();
        bytes[0] = b'x';
        bytes.truncate(bytes.len() - 7);
        let e = parse_stl(p, &bytes).unwrap_err().to_string();
        assert!(e.contains("part.stl") && e.contains("truncated"), "{e}");

        let e = parse_stl(p, b"solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n").unwrap_err().to_string();
        assert!(e.contains("part.stl") && e.contains("truncated"), "{e}");
        let e = parse_stl(p, b"solid x\n facet\n vertex 0 zero 0\n").unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("zero"), "{e}");

        let mut soup = cube_soup();
        soup[3][1].y = f32::NAN;
        let e = Mesh::from_checked_soup(p, soup, LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("triangle 3") && e.contains("non-finite"), "{e}");

        let e = Mesh::from_checked_soup(p, vec![], LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("no triangles"), "{e}");

        let metres: Vec<_> = cube_soup().into_iter().map(|t| t.map(|v| v * 0.001)).collect();
        let e = Mesh::from_checked_soup(p, metres.clone(), LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("metres"), "{e}");
        let ok = Mesh::from_checked_soup(p, metres, LoadOptions { scale_to_mm: 1000.0, ..Default::default() });
        assert!(ok.is_ok());
        let huge: Vec<_> = cube_soup().into_iter().map(|t| t.map(|v| v * 1000.0)).collect();
        assert!(Mesh::from_checked_soup(p, huge, LoadOptions::default()).is_err());

        let e = Mesh::load(Path::new("/nonexistent/part.stl"), LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/part.stl"), "{e}");
        let e = Mesh::load(Path::new("part.ply"), LoadOptions::default()).unwrap_err().to_string();
        assert!(e.contains("unsupported"), "{e}");
    }

    #[test]
    fn obj_loads_and_y_up_maps_to_z_up() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tri.obj");
        std::fs::write(&path, "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 2 3\nf 1 3 4\n").unwrap();
        let m = Mesh::load(&path, LoadOptions::default()).unwrap();
        assert_eq!(m.triangles.len(), 2);
        // File +y (up) becomes sensor +z; file +z becomes sensor -y.
        assert!(m.vertices.contains(&Vec3::new(0.0, 0.0, 10.0)));
        assert!(m.vertices.contains(&Vec3::new(0.0, -10.0, 0.0)));
        let bad = dir.path().join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
        assert!(Mesh::load(&bad, LoadOptions::default()).unwrap_err().to_string().contains("bad.obj"));
    }
}
