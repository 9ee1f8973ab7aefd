//! Marching-cubes lookup tables for the 256 sign cases of a cube, generated from the cube topology.
//!
//! Corner `n` of a cube sits at offset `(n & 1, n >> 1 & 1, n >> 2 & 1)` voxels from its first
//! corner; bit `n` of a case is set when corner `n` is inside (tsdf < 0). Edge `e` runs along axis
//! `e / 4` from corner [`EDGE_START`]`[e]`. For each case the generator cuts every face of the cube
//! into segments joining the crossings on its edges, always separating the inside corners of an
//! ambiguous face (two inside corners on a diagonal). The rule depends only on the face's own
//! signs, so two cubes sharing a face cut it the same way and the surface has no cracks. Each face
//! segment is oriented so that an inside corner lies on its right seen from outside the cube; the
//! segments then chain into loops, each fanned into triangles whose normals `(b−a)×(c−a)` point to
//! the outside (positive tsdf).

use std::sync::OnceLock;

/// Offset (voxels) of each cube corner from the cube's first corner.
pub const CORNER_OFFSET: [[usize; 3]; 8] = {
    let mut t = [[0; 3]; 8];
    let mut n = 0;
    while n < 8 {
        t[n] = [n & 1, n >> 1 & 1, n >> 2 & 1];
        n += 1;
    }
    t
};

/// The axis (0 = x, 1 = y, 2 = z) of each cube edge.
pub const EDGE_AXIS: [usize; 12] = [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2];

/// The corner each edge starts from (its other end is that corner + one voxel along the axis).
pub const EDGE_START: [usize; 12] = {
    let mut t = [0; 12];
    let mut e = 0;
    while e < 12 {
        let axis = e / 4;
        let (u, v) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        t[e] = (e & 1) << u | (e >> 1 & 1) << v;
        e += 1;
    }
    t
};

/// The triangles (as edge triples) of every case.
pub struct McTables {
    /// Triangles of case `c` are `triangles[offsets[c]..offsets[c + 1]]`.
    offsets: [usize; 257],
    triangles: Vec<[u8; 3]>,
}

impl McTables {
    /// The triangles of `case`, each three edge indices.
    #[inline]
    pub fn triangles(&self, case: usize) -> &[[u8; 3]] {
        &self.triangles[self.offsets[case]..self.offsets[case + 1]]
    }
}

/// The tables, generated on first use (a few microseconds).
pub fn tables() -> &'static McTables {
    static TABLES: OnceLock<McTables> = OnceLock::new();
    TABLES.get_or_init(|| {
        let mut offsets = [0; 257];
        let mut triangles = Vec::new();
        for case in 0..256 {
            triangles.extend(case_triangles(case));
            offsets[case + 1] = triangles.len();
        }
        McTables { offsets, triangles }
    })
}

/// The edge joining corners `a` and `b` (which differ in one bit).
fn edge_between(a: usize, b: usize) -> usize {
    let (lo, hi) = (a.min(b), a.max(b));
    let axis = (hi ^ lo).trailing_zeros() as usize;
    (0..12).find(|&e| EDGE_AXIS[e] == axis && EDGE_START[e] == lo).expect("adjacent corners")
}

fn edge_midpoint(e: usize) -> [f64; 3] {
    let mut p = CORNER_OFFSET[EDGE_START[e]].map(|v| v as f64);
    p[EDGE_AXIS[e]] += 0.5;
    p
}

/// The directed segments (edge → edge) that cut the cube's six faces for `case`.
fn face_segments(case: usize) -> Vec<(usize, usize)> {
    let inside = |n: usize| case >> n & 1 == 1;
    let mut segments = Vec::new();
    for axis in 0..3 {
        let (u, v) = [(1, 2), (0, 2), (0, 1)][axis];
        for side in 0..2 {
            // The face's corners in cyclic order.
            let ring: Vec<usize> =
                [(0, 0), (1, 0), (1, 1), (0, 1)].iter().map(|&(a, b)| side << axis | a << u | b << v).collect();
            let edge = |i: usize| edge_between(ring[i % 4], ring[(i + 1) % 4]);
            let ins: Vec<usize> = (0..4).filter(|&i| inside(ring[i])).collect();
            // (entry edge, exit edge, a reference corner strictly on one side of the segment).
            let cuts: Vec<(usize, usize, usize)> = match ins.len() {
                1 => vec![(edge(ins[0] + 3), edge(ins[0]), ring[ins[0]])],
                3 => {
                    let out = (0..4).find(|i| !inside(ring[*i])).expect("one outside corner");
                    vec![(edge(out + 3), edge(out), ring[out])]
                }
                2 if (ins[1] - ins[0]) % 2 == 1 => {
                    // Adjacent inside corners i, i+1 (cyclically): cut before i and after i+1.
                    let first = if ins[1] - ins[0] == 1 { ins[0] } else { ins[1] };
                    vec![(edge(first + 3), edge(first + 1), ring[first])]
                }
                2 => ins.iter().map(|&i| (edge(i + 3), edge(i), ring[i])).collect(),
                _ => vec![],
            };
            let mut normal = [0.0; 3];
            normal[axis] = if side == 1 { 1.0 } else { -1.0 };
            for (a, b, corner) in cuts {
                let (p, q) = (edge_midpoint(a), edge_midpoint(b));
                let c = CORNER_OFFSET[corner].map(|v| v as f64);
                let s = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
                let m = [0, 1, 2].map(|i| c[i] - 0.5 * (p[i] + q[i]));
                let cross = [s[1] * m[2] - s[2] * m[1], s[2] * m[0] - s[0] * m[2], s[0] * m[1] - s[1] * m[0]];
                let side_of = cross[0] * normal[0] + cross[1] * normal[1] + cross[2] * normal[2];
                // Inside corners go to the right (negative), outside corners to the left.
                let keep = (side_of < 0.0) == inside(corner);
                segments.push(if keep { (a, b) } else { (b, a) });
            }
        }
    }
    segments
}

/// The two faces (axis, side) an edge lies on.
fn faces_of(e: usize) -> [(usize, usize); 2] {
    let (axis, c) = (EDGE_AXIS[e], CORNER_OFFSET[EDGE_START[e]]);
    let (u, v) = [(1, 2), (0, 2), (0, 1)][axis];
    [(u, c[u]), (v, c[v])]
}

/// Whether two distinct edges lie on a common face of the cube.
fn share_face(a: usize, b: usize) -> bool {
    faces_of(a).iter().any(|f| faces_of(b).contains(f))
}

/// A triangulation of the polygon `ring` (kept in its orientation) whose diagonals all satisfy
/// `ok`. A diagonal joining two edges of one face could also be drawn by the neighbouring cube
/// (on an ambiguous face), giving an edge of four triangles; diagonals through the cube's inside
/// belong to this cube alone.
fn triangulate(ring: &[usize], ok: &impl Fn(usize, usize) -> bool) -> Option<Vec<[usize; 3]>> {
    let n = ring.len();
    if n < 3 {
        return Some(vec![]);
    }
    // The triangle on the closing side (ring[0], ring[n-1]) has its apex at some k.
    for k in 1..n - 1 {
        if (k == 1 || ok(ring[0], ring[k])) && (k == n - 2 || ok(ring[k], ring[n - 1])) {
            if let (Some(left), Some(right)) = (triangulate(&ring[..=k], ok), triangulate(&ring[k..], ok)) {
                let mut out = vec![[ring[0], ring[k], ring[n - 1]]];
                out.extend(left);
                out.extend(right);
                return Some(out);
            }
        }
    }
    None
}

/// The triangles of one case: face segments chained into loops, each loop fanned.
fn case_triangles(case: usize) -> Vec<[u8; 3]> {
    let segments = face_segments(case);
    let mut next = [usize::MAX; 12];
    for &(a, b) in &segments {
        assert_eq!(next[a], usize::MAX, "case {case}: edge {a} starts two segments");
        next[a] = b;
    }
    let mut used = [false; 12];
    let mut triangles = Vec::new();
    for start in 0..12 {
        if next[start] == usize::MAX || used[start] {
            continue;
        }
        let mut ring = vec![start];
        used[start] = true;
        let mut e = next[start];
        while e != start {
            assert!(!used[e] && next[e] != usize::MAX, "case {case}: segments do not close into loops");
            used[e] = true;
            ring.push(e);
            e = next[e];
        }
        let tris =
            triangulate(&ring, &|a, b| !share_face(a, b)).unwrap_or_else(|| panic!("case {case}: loop {ring:?}"));
        triangles.extend(tris.iter().map(|t| t.map(|e| e as u8)));
    }
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;

    fn crossed(case: usize, e: usize) -> bool {
        let a = EDGE_START[e];
        (case >> a & 1) != (case >> (a | 1 << EDGE_AXIS[e]) & 1)
    }

    #[test]
    fn edges_and_corners_are_the_cube_topology() {
        for e in 0..12 {
            let (a, axis) = (EDGE_START[e], EDGE_AXIS[e]);
            assert_eq!(a >> axis & 1, 0, "edge {e} starts at its low end");
            assert_eq!(edge_between(a, a | 1 << axis), e);
        }
        let mut seen = std::collections::HashSet::new();
        assert!((0..12).all(|e| seen.insert((EDGE_START[e], EDGE_AXIS[e]))));
    }

    #[test]
    fn every_case_uses_exactly_its_crossed_edges_and_is_a_closed_patch_boundary() {
        let t = tables();
        assert!(t.triangles(0).is_empty() && t.triangles(255).is_empty());
        let mut total = 0;
        for case in 0..256 {
            let tris = t.triangles(case);
            total += tris.len();
            let used: std::collections::HashSet<usize> = tris.iter().flatten().map(|&e| e as usize).collect();
            let expect: std::collections::HashSet<usize> = (0..12).filter(|&e| crossed(case, e)).collect();
            assert_eq!(used, expect, "case {case}");
            // Directed edges of the triangles that are not cancelled by their reverse are the face
            // segments, each once: the patch's boundary lies on the cube's faces.
            let mut directed: Vec<(u8, u8)> =
                tris.iter().flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]).collect();
            directed.sort();
            let boundary: Vec<(u8, u8)> =
                directed.iter().copied().filter(|(a, b)| !directed.contains(&(*b, *a))).collect();
            let mut segs: Vec<(u8, u8)> = face_segments(case).iter().map(|&(a, b)| (a as u8, b as u8)).collect();
            segs.sort();
            assert_eq!(boundary, segs, "case {case}");
            // Inner edges (used both ways) never join two edges of one face.
            for (a, b) in directed.iter().filter(|(a, b)| directed.contains(&(*b, *a))) {
                assert!(!share_face(*a as usize, *b as usize), "case {case}: diagonal {a}-{b} lies on a face");
            }
        }
        // One inside corner: one triangle whose normal points away from that corner.
        assert_eq!(t.triangles(1).len(), 1);
        let p = t.triangles(1)[0].map(|e| edge_midpoint(e as usize));
        let (u, v) = ([0, 1, 2].map(|i| p[1][i] - p[0][i]), [0, 1, 2].map(|i| p[2][i] - p[0][i]));
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        assert!(n.iter().all(|c| *c > 0.0), "{n:?}");
        assert!(total > 600 && total < 256 * 6, "{total}");
    }

    #[test]
    fn complementary_cases_cut_the_same_edges_with_opposite_orientation_when_unambiguous() {
        let t = tables();
        let rotations = |x: [u8; 3]| [x, [x[1], x[2], x[0]], [x[2], x[0], x[1]]];
        for case in [1usize, 2, 4, 8, 16, 32, 64, 128] {
            let (a, b) = (t.triangles(case)[0], t.triangles(255 - case)[0]);
            assert!(rotations([a[0], a[2], a[1]]).contains(&b), "case {case}: {a:?} vs {b:?}");
        }
    }
}
