//! PLY: what `pointreggpt::ply::write` writes, checked byte by byte and read back by `pointreggpt::ply::read`,
//! and that reader on hand-made files of the other PLY flavours (ascii, big-endian, extra elements).

use pointreggpt::geometry::Point;
use pointreggpt::ply::{decode_ply, encode_points, read_ply, write_mesh, write_points};
use std::path::Path;

fn pts() -> Vec<Point> {
    vec![Point::new(0.0, -1.5, 2.25), Point::new(1e-3, 3.0e4, -0.125), Point::new(-7.0, 0.5, 1.0)]
}

#[test]
fn round_trip_and_exact_layout() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub/cloud.ply");
    write_points(&path, &pts()).unwrap();
    assert_eq!(read_ply(&path).unwrap(), pts());

    let bytes = std::fs::read(&path).unwrap();
    let header = "ply\nformat binary_little_endian 1.0\ncomment written by pointreggpt\nelement vertex 3\n\
                  property float x\nproperty float y\nproperty float z\nend_header\n";
    assert!(bytes.starts_with(header.as_bytes()));
    assert_eq!(bytes.len(), header.len() + 3 * 12);
    // Second point's y = 30000.0 = 0x46EA6000 as an IEEE single, little-endian.
    let at = header.len() + 12 + 4;
    assert_eq!(&bytes[at..at + 4], &[0x00, 0x60, 0xEA, 0x46]);
    assert_eq!(read_ply(&{
        let p = dir.path().join("empty.ply");
        write_points(&p, &[]).unwrap();
        p
    })
    .unwrap(), vec![]);
}

#[test]
fn ascii_with_normals_colours_and_faces() {
    let _timing = crate::support::timed();
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info test\r\nelement vertex 3\r\n\
                property float nx\r\nproperty double x\r\nproperty double y\r\nproperty uchar red\r\n\
                property double z\r\nproperty list uchar int tags\r\nelement face 1\r\n\
                property list uchar int vertex_indices\r\nend_header\r\n\
                0 1.5 2 255 -3 2 7 8\r\n1 0.25 -0.5 0 4e-1 0\r\n0 10 20 128 30 1 5\r\n3 0 1 2\r\n";
    let p = decode_ply(text.as_bytes(), Path::new("hand.ply")).unwrap();
    assert_eq!(p, vec![Point::new(1.5, 2.0, -3.0), Point::new(0.25, -0.5, 0.4), Point::new(10.0, 20.0, 30.0)]);
}

#[test]
fn binary_big_endian_doubles_after_another_element() {
    let _timing = crate::support::timed();
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement camera 1\nproperty list uchar float k\n\
                  element vertex 2\nproperty uchar red\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
        .to_vec();
    b.push(2); // camera row: a list of two floats
    b.extend_from_slice(&1.0f32.to_be_bytes());
    b.extend_from_slice(&2.0f32.to_be_bytes());
    for (red, xyz) in [(9u8, [0.1f64, 0.2, 0.3]), (10, [-4.0, 5.5, 6.0])] {
        b.push(red);
        for v in xyz {
            b.extend_from_slice(&v.to_be_bytes());
        }
    }
    let p = decode_ply(&b, Path::new("be.ply")).unwrap();
    assert_eq!(p, vec![Point::new(0.1, 0.2, 0.3), Point::new(-4.0, 5.5, 6.0)]);
}

#[test]
fn truncated_and_malformed_files_name_the_file() {
    let _timing = crate::support::timed();
    let bytes = encode_points(&pts());
    let e = decode_ply(&bytes[..bytes.len() - 5], Path::new("cut.ply")).unwrap_err().to_string();
    assert!(e.starts_with("cut.ply:") && e.contains("vertex 2 of 3") && e.contains("truncated"), "{e}");

    let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5\n";
    let e = decode_ply(ascii.as_bytes(), Path::new("short.ply")).unwrap_err().to_string();
    assert!(e.contains("short.ply") && e.contains("vertex 1 of 2") && e.contains("truncated"), "{e}");

    let no_z = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
    let e = decode_ply(no_z.as_bytes(), Path::new("noz.ply")).unwrap_err().to_string();
    assert!(e.contains("noz.ply") && e.contains("no scalar `z`"), "{e}");

    let e = decode_ply(&bytes[..30], Path::new("head.ply")).unwrap_err().to_string();
    assert!(e.contains("head.ply") && e.contains("end_header"), "{e}");
    let e = decode_ply(b"PNG\n", Path::new("x.ply")).unwrap_err().to_string();
    assert!(e.contains("not a PLY file"), "{e}");
    let e = read_ply(Path::new("/nonexistent/dir/missing.ply")).unwrap_err().to_string();
    assert!(e.contains("missing.ply"), "{e}");
}

#[test]
fn a_mesh_has_vertices_and_faces_readable_by_the_point_reader() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m/tet.ply");
    let vertices = vec![Point::new(0.0, 0.0, 0.0), Point::new(1.0, 0.0, 0.0), Point::new(0.0, 1.0, 0.0), Point::new(0.0, 0.0, 1.0)];
    let triangles = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    write_mesh(&path, &vertices, &triangles).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    assert_eq!(bytes.len(), header_end + 4 * 12 + 4 * 13);
    // The last face: count 3, then 1, 2, 3 as little-endian int32.
    assert_eq!(&bytes[bytes.len() - 13..], &[3, 1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0]);
    assert_eq!(read_ply(&path).unwrap(), vertices);
}
