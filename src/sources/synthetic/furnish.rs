//! Furnishing a room: cabinets, bookshelves and desks against the walls, pictures, wall cabinets and
//! radiators on them, and free-standing tables, crates, stools and balls, some carrying objects.
//! Pieces never overlap (their bounding boxes may touch); everything is built in a piece's local
//! frame and then turned and moved into place.

use super::room::{camera_zone, SceneConfig, LOW_TOP_M};
use super::shapes::Shape;
use crate::rng::Rng;
use nalgebra::{Point3, Vector3};
use std::f64::consts::{FRAC_PI_2, PI, SQRT_2};

/// `shape` moved from a piece's local frame to the world: turned by `yaw` about z, then shifted by (x, y).
fn place(shape: &Shape, x: f64, y: f64, yaw: f64) -> Shape {
    let (s, c) = yaw.sin_cos();
    let tp = |p: &Point3<f64>| Point3::new(x + c * p.x - s * p.y, y + s * p.x + c * p.y, p.z);
    match shape {
        Shape::Cuboid { center, half, yaw: y0 } => Shape::Cuboid { center: tp(center), half: *half, yaw: y0 + yaw },
        Shape::Sphere { center, radius } => Shape::Sphere { center: tp(center), radius: *radius },
        Shape::Cylinder { axis_x, axis_y, radius, z_min, z_max } => {
            let a = tp(&Point3::new(*axis_x, *axis_y, 0.0));
            Shape::Cylinder { axis_x: a.x, axis_y: a.y, radius: *radius, z_min: *z_min, z_max: *z_max }
        }
        other => other.clone(),
    }
}

/// A box standing on height `z0`, centred at local (x, y), half extents (hx, hy), height `h`.
fn block(x: f64, y: f64, z0: f64, hx: f64, hy: f64, h: f64, yaw: f64) -> Shape {
    Shape::Cuboid { center: Point3::new(x, y, z0 + h / 2.0), half: Vector3::new(hx, hy, h / 2.0), yaw }
}

/// The surfaces of a furnished room of interior `size` (m): the room shell, then the pieces.
pub(super) fn furnish(config: &SceneConfig, size: Vector3<f64>, rng: Rng) -> Vec<Shape> {
    let mut b = Builder { rng, size, stack: config.stack_probability, shapes: Vec::new(), taken: Vec::new() };
    b.shapes.push(Shape::Room { min: Point3::origin(), max: Point3::from(size) });
    let count = |rng: &mut Rng, [lo, hi]: [u32; 2]| lo as u64 + rng.below((hi - lo) as u64 + 1);
    for _ in 0..count(&mut b.rng, config.wall_pieces) {
        b.wall_piece();
    }
    for _ in 0..count(&mut b.rng, config.wall_fixtures) {
        b.wall_fixture();
    }
    for _ in 0..count(&mut b.rng, config.free_pieces) {
        b.free_piece();
    }
    b.shapes
}

struct Builder {
    rng: Rng,
    size: Vector3<f64>,
    stack: f64,
    shapes: Vec<Shape>,
    /// World bounding boxes `(min, max)` of the pieces placed so far.
    taken: Vec<(Point3<f64>, Point3<f64>)>,
}

impl Builder {
    fn r(&mut self, lo: f64, hi: f64) -> f64 {
        self.rng.uniform_range(lo, hi)
    }

    /// Adds `parts` (local frame) at (x, y, yaw) if they stay inside the room and clear of every
    /// piece placed before (touching allowed); returns whether it did.
    fn try_add(&mut self, parts: &[Shape], x: f64, y: f64, yaw: f64) -> bool {
        let placed: Vec<Shape> = parts.iter().map(|p| place(p, x, y, yaw)).collect();
        let (mut lo, mut hi) = (Point3::from(Vector3::repeat(f64::INFINITY)), Point3::from(Vector3::repeat(f64::NEG_INFINITY)));
        for b in placed.iter().filter_map(Shape::aabb) {
            lo = lo.inf(&b.min);
            hi = hi.sup(&b.max);
        }
        let eps = 1e-5;
        let inside = (0..3).all(|i| lo[i] >= -eps && hi[i] <= self.size[i] + eps);
        let overlaps = |(a, b): &(Point3<f64>, Point3<f64>)| (0..3).all(|i| lo[i] < b[i] - eps && a[i] < hi[i] - eps);
        if !inside || self.taken.iter().any(overlaps) {
            return false;
        }
        self.taken.push((lo, hi));
        self.shapes.extend(placed);
        true
    }

    /// Tries up to 20 spots along the walls (a wall drawn per try, in proportion to its length) for
    /// `parts`, built with local +y pointing from the wall into the room, back face at local y =
    /// `back`, `gap` metres off the wall, `half_width` either side of the centre.
    fn against_wall(&mut self, parts: &[Shape], half_width: f64, back: f64, gap: f64) {
        for _ in 0..20 {
            let u = self.rng.uniform() * 2.0 * (self.size.x + self.size.y);
            let wall = if u < 2.0 * self.size.x { (u / self.size.x) as u64 } else { 2 + ((u - 2.0 * self.size.x) / self.size.y) as u64 };
            let length = if wall < 2 { self.size.x } else { self.size.y };
            if 2.0 * half_width + 0.1 > length {
                continue;
            }
            let along = self.r(half_width + 0.05, length - half_width - 0.05);
            let off = gap - back;
            let (x, y, yaw) = match wall.min(3) {
                0 => (along, off, 0.0),
                1 => (along, self.size.y - off, PI),
                2 => (off, along, -FRAC_PI_2),
                _ => (self.size.x - off, along, FRAC_PI_2),
            };
            if self.try_add(parts, x, y, yaw) {
                return;
            }
        }
    }

    /// A table (top slab and four legs) of half size (hx, hy) and height h, local frame.
    fn table(&self, hx: f64, hy: f64, h: f64) -> Vec<Shape> {
        let (t, leg) = (0.04, 0.025);
        let mut parts = vec![block(0.0, 0.0, h - t, hx, hy, t, 0.0)];
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            parts.push(block(sx * (hx - leg - 0.02), sy * (hy - leg - 0.02), 0.0, leg, leg, h - t, 0.0));
        }
        parts
    }

    /// Maybe (with the stack probability) a ball, box or can standing on the rectangle of half size
    /// (hx, hy) centred at the local origin at height z, no taller than `room` metres.
    fn on_top(&mut self, hx: f64, hy: f64, z: f64, room: f64) -> Option<Shape> {
        if self.rng.uniform() >= self.stack || room < 0.08 || hx.min(hy) < 0.08 {
            return None;
        }
        let fit = |b: &mut Self, rad: f64| (b.r(-(hx - rad), hx - rad), b.r(-(hy - rad), hy - rad));
        match self.rng.below(3) {
            0 => {
                let rad = self.r(0.05, 0.15).min(0.8 * hx.min(hy)).min(room / 2.0);
                let (x, y) = fit(self, rad);
                Some(Shape::Sphere { center: Point3::new(x, y, z + rad), radius: rad })
            }
            1 => {
                let (bx, by) = (self.r(0.04, 0.2), self.r(0.04, 0.2));
                let scale = (0.9 * hx.min(hy) / bx.hypot(by)).min(1.0);
                let (bx, by, h) = (bx * scale, by * scale, self.r(0.05, 0.35).min(room));
                let (x, y) = fit(self, bx.hypot(by));
                let yaw = self.r(0.0, PI);
                Some(block(x, y, z, bx, by, h, yaw))
            }
            _ => {
                let rad = self.r(0.03, 0.12).min(0.8 * hx.min(hy));
                let h = self.r(0.08, 0.3).min(room);
                let (x, y) = fit(self, rad);
                Some(Shape::Cylinder { axis_x: x, axis_y: y, radius: rad, z_min: z, z_max: z + h })
            }
        }
    }

    /// A cabinet, bookshelf or desk with its back 1 cm off a random wall (depth at most 0.6 m when
    /// taller than [`LOW_TOP_M`]).
    fn wall_piece(&mut self) {
        let ceiling = self.size.z - 0.1;
        let mut parts = Vec::new();
        let (hx, hy) = match self.rng.below(3) {
            0 => {
                let (hx, hy, h) = (self.r(0.2, 0.6), self.r(0.175, 0.3), self.r(0.8, 2.0).min(ceiling - 0.1));
                parts.push(block(0.0, 0.0, 0.0, hx, hy, h, 0.0));
                parts.extend(self.on_top(hx, hy, h, (ceiling - h).min(0.35)));
                (hx, hy)
            }
            1 => {
                let (hx, hy, h, t) = (self.r(0.3, 0.6), self.r(0.125, 0.2), self.r(1.2, 2.0).min(ceiling), 0.02);
                for sx in [-1.0, 1.0] {
                    parts.push(block(sx * (hx - t / 2.0), 0.0, 0.0, t / 2.0, hy, h, 0.0));
                }
                parts.push(block(0.0, -hy + t / 2.0, 0.0, hx - t, t / 2.0, h, 0.0));
                let boards = 3 + self.rng.below(3);
                for k in 0..=boards {
                    let z = k as f64 * (h - t) / boards as f64;
                    parts.push(block(0.0, t / 2.0, z, hx - t, hy - t / 2.0, t, 0.0));
                }
                (hx, hy)
            }
            _ => {
                let (hx, hy, h) = (self.r(0.4, 0.8), self.r(0.25, 0.4), self.r(0.7, 0.78));
                parts = self.table(hx, hy, h);
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
                (hx, hy)
            }
        };
        self.against_wall(&parts, hx, -hy, 0.01);
    }

    /// A picture, a wall cabinet or a radiator hanging on a random wall.
    fn wall_fixture(&mut self) {
        let top = self.size.z - 0.05;
        let (hx, hy, h, z0) = match self.rng.below(3) {
            0 => (self.r(0.15, 0.5), self.r(0.01, 0.02), self.r(0.3, 0.8), self.r(1.0, 1.6)),
            1 => (self.r(0.2, 0.5), self.r(0.12, 0.17), self.r(0.4, 0.7), self.r(1.5, 1.8)),
            _ => (self.r(0.3, 0.6), self.r(0.04, 0.06), self.r(0.4, 0.6), self.r(0.1, 0.15)),
        };
        let h = h.min(top - z0);
        if h < 0.1 {
            return;
        }
        self.against_wall(&[block(0.0, 0.0, z0, hx, hy, h, 0.0)], hx, -hy, 0.0);
    }

    /// A table, a crate (maybe stacked, maybe with a touching neighbour), a stool or a ball, at most
    /// [`LOW_TOP_M`] tall, on free floor outside the camera zone.
    fn free_piece(&mut self) {
        let mut parts = Vec::new();
        match self.rng.below(4) {
            0 => {
                let (hx, hy, h) = (self.r(0.3, 0.7), self.r(0.3, 0.5), self.r(0.7, 0.78));
                parts = self.table(hx, hy, h);
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
            }
            1 => {
                let (hx, hy, h) = (self.r(0.15, 0.3), self.r(0.15, 0.3), self.r(0.25, 0.6));
                parts.push(block(0.0, 0.0, 0.0, hx, hy, h, 0.0));
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
                if self.rng.uniform() < 0.5 {
                    // A second crate flush against the first one's +x side.
                    let (hx2, hy2, h2) = (self.r(0.12, 0.25), self.r(0.12, hy), self.r(0.2, 0.6));
                    parts.push(block(hx + hx2, 0.0, 0.0, hx2, hy2, h2, 0.0));
                }
            }
            2 => {
                let (rad, h) = (self.r(0.12, 0.3), self.r(0.3, 0.75));
                parts.push(Shape::Cylinder { axis_x: 0.0, axis_y: 0.0, radius: rad, z_min: 0.0, z_max: h });
                parts.extend(self.on_top(rad / SQRT_2, rad / SQRT_2, h, LOW_TOP_M - h));
            }
            _ => {
                let rad = self.r(0.1, 0.3);
                parts.push(Shape::Sphere { center: Point3::new(0.0, 0.0, rad), radius: rad });
            }
        }
        let yaw = self.r(0.0, 2.0 * PI);
        let (zx, zy) = camera_zone(&self.size);
        for _ in 0..20 {
            let (x, y) = (self.r(0.0, self.size.x), self.r(0.0, self.size.y));
            let in_zone = (x - self.size.x / 2.0).abs() < zx && (y - self.size.y / 2.0).abs() < zy;
            if !in_zone && self.try_add(&parts, x, y, yaw) {
                return;
            }
        }
    }
}
