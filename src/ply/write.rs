//! PLY writing: point clouds (`x y z` floats) and triangle meshes, binary little-endian, readable by
//! Open3D, CloudCompare, MeshLab, numpy and [`super::read`].

use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::Path;

/// A binary little-endian PLY of `points` (`element vertex N`, `property float x/y/z`).
pub fn encode_points(points: &[Point]) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    );
    let mut out = Vec::with_capacity(header.len() + 12 * points.len());
    out.extend_from_slice(header.as_bytes());
    for p in points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// Writes [`encode_points`] of `points` to `path`, creating parent folders.
pub fn write_points(path: &Path, points: &[Point]) -> Result<()> {
    write_bytes(path, &encode_points(points))
}

/// The per-point provenance of a target cloud (the `target_known_share`, `target_scene_share` and
/// `target_view` columns), each list aligned with the points or empty.
#[derive(Clone, Copy)]
pub struct Provenance<'a> {
    pub known_share: &'a [f32],
    pub scene_share: &'a [f32],
    pub view: &'a [u8],
}

impl<'a> Provenance<'a> {
    /// The provenance of a row's target cloud.
    pub fn of(row: &'a crate::shards::PairRow) -> Self {
        Provenance { known_share: &row.target_known_share, scene_share: &row.target_scene_share, view: &row.target_view }
    }
}

/// A target cloud with its per-point provenance: [`encode_points`] plus three vertex properties,
/// `property float known_share`, `property float scene_share` and `property uchar view`. Without
/// provenance (lists not aligned with the points: a version-1 dataset), the plain cloud.
pub fn encode_points_with_provenance(points: &[Point], p: Provenance) -> Vec<u8> {
    let n = points.len();
    if p.known_share.len() != n || p.scene_share.len() != n || p.view.len() != n {
        return encode_points(points);
    }
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\n\
         comment known_share: share of the voxel's points re-projected from the source frame; scene_share: \
         seen by the posed frames around it (the rest a fill made up); view: first target view\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property float known_share\nproperty float scene_share\nproperty uchar view\nend_header\n"
    );
    let mut out = Vec::with_capacity(header.len() + 21 * n);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        let q = &points[i];
        for c in [q.x, q.y, q.z, p.known_share[i], p.scene_share[i]] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.push(p.view[i]);
    }
    out
}

/// Writes [`encode_points_with_provenance`] to `path`, creating parent folders.
pub fn write_points_with_provenance(path: &Path, points: &[Point], provenance: Provenance) -> Result<()> {
    write_bytes(path, &encode_points_with_provenance(points, provenance))
}

/// A triangle mesh (vertex positions, triangles as vertex indices) as a binary little-endian PLY:
/// `element vertex` with float `x y z`, then `element face` with `property list uchar int vertex_indices`.
pub fn encode_mesh(vertices: &[Point], triangles: &[[u32; 3]]) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        vertices.len(),
        triangles.len()
    );
    let mut out = Vec::with_capacity(header.len() + 12 * vertices.len() + 13 * triangles.len());
    out.extend_from_slice(header.as_bytes());
    for p in vertices {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in triangles {
        out.push(3);
        for i in t {
            out.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    out
}

/// Writes [`encode_mesh`] to `path`, creating parent folders.
pub fn write_mesh(path: &Path, vertices: &[Point], triangles: &[[u32; 3]]) -> Result<()> {
    write_bytes(path, &encode_mesh(vertices, triangles))
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}
