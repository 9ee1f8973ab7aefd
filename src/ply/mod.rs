//! PLY files, the one place for them: [`write`] encodes point clouds and triangle meshes (binary
//! little-endian, readable by Open3D, CloudCompare, MeshLab and numpy); [`read`] decodes the vertex
//! positions of any PLY flavour (ascii, binary little- or big-endian), as fragment clouds of the
//! official 3DMatch benchmark (`cloud_bin_k.ply`) come.

pub mod read;
pub mod write;

pub use read::{decode_ply, read_ply};
pub use write::{encode_mesh, encode_points, encode_points_with_provenance, write_mesh, write_points, write_points_with_provenance, Provenance};
