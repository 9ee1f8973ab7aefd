//! [`Mesh`] (indexed triangles, metres); [`crate::ply::write_mesh`] writes it.

use crate::geometry::Point;
use std::collections::HashMap;

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
}
