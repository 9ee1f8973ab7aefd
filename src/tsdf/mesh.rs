//! [`Mesh`] (indexed triangles, metres) and its binary little-endian PLY writer.

use crate::error::{Error, Result};
use crate::geometry::Point;
use std::collections::HashMap;
use std::path::Path;

/// An indexed triangle mesh: vertex positions in metres and triangles as three vertex indices,
/// counter-clockwise seen from the side the normal points to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<Point>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Whether the mesh is a closed, consistently oriented surface: every edge is shared by exactly
    /// two triangles that traverse it in opposite directions (and no triangle repeats an index).
    pub fn is_closed(&self) -> bool {
        let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 3);
        for t in &self.triangles {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return false;
            }
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *directed.entry((a, b)).or_default() += 1;
            }
        }
        directed.iter().all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
    }

    /// Total triangle area, square metres.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].cast::<f64>());
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }
}

/// The mesh as a binary little-endian PLY: `element vertex` with float `x y z`, then `element face`
/// with `property list uchar int vertex_indices`.
pub fn encode_mesh_ply(mesh: &Mesh) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt (TSDF marching cubes)\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    );
    let mut out = Vec::with_capacity(header.len() + 12 * mesh.vertices.len() + 13 * mesh.triangles.len());
    out.extend_from_slice(header.as_bytes());
    for p in &mesh.vertices {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

/// Writes [`encode_mesh_ply`] of `mesh` to `path`, creating parent folders.
pub fn write_mesh_ply(path: &Path, mesh: &Mesh) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, encode_mesh_ply(mesh)).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> Mesh {
        let vertices = vec![
            Point::new(0.0, 0.0, 0.0),
            Point::new(1.0, 0.0, 0.0),
            Point::new(0.0, 1.0, 0.0),
            Point::new(0.0, 0.0, 1.0),
        ];
        Mesh { vertices, triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] }
    }

    #[test]
    fn closedness_and_area() {
        let t = tetrahedron();
        assert!(t.is_closed());
        assert!((t.area() - (1.5 + 3f64.sqrt() / 2.0)).abs() < 1e-9);
        let mut open = t.clone();
        open.triangles.pop();
        assert!(!open.is_closed());
        let mut flipped = t.clone();
        flipped.triangles[3] = [1, 3, 2];
        assert!(!flipped.is_closed(), "inconsistent orientation");
    }

    #[test]
    fn ply_has_vertices_and_faces_readable_by_the_point_reader() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m/tet.ply");
        let t = tetrahedron();
        write_mesh_ply(&path, &t).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(bytes.len(), header_end + 4 * 12 + 4 * 13);
        // The last face: count 3, then 1, 2, 3 as little-endian int32.
        assert_eq!(&bytes[bytes.len() - 13..], &[3, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0]);
        assert_eq!(crate::sources::ply::read_ply(&path).unwrap(), t.vertices);
    }
}
