//! Procedural rooms: a box-shaped room with furniture against the walls (cabinets, shelves, desks) and
//! free-standing pieces (tables, crates, stools, balls), some carrying objects, some touching.

use super::shapes::{Aabb, Shape};
use crate::error::{Error, Result};
use crate::rng::Rng;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI};

/// Highest top (m above the floor) of anything standing away from the walls: cameras fly above it.
pub const LOW_TOP_M: f64 = 1.05;
/// Deepest reach (m from its wall) of any furniture taller than [`LOW_TOP_M`].
pub const WALL_BAND_M: f64 = 0.62;

/// How rooms are drawn. Ranges are `[min, max]`, sampled uniformly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Room extent along world x, metres (at least 2.6 so a camera fits away from the furniture).
    pub room_length_m: [f64; 2],
    /// Room extent along world y, metres (at least 2.6).
    pub room_width_m: [f64; 2],
    /// Floor-to-ceiling height, metres (at least 2.2).
    pub room_height_m: [f64; 2],
    /// Number of furniture pieces against the walls (cabinets, shelves, desks); a piece that finds no
    /// free spot is left out.
    pub wall_pieces: [u32; 2],
    /// Number of free-standing pieces (tables, crates, stools, balls); likewise.
    pub free_pieces: [u32; 2],
    /// Probability (0–1) that a table, desk, cabinet, crate or stool carries an object on top.
    pub stack_probability: f64,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            room_length_m: [3.0, 7.0],
            room_width_m: [3.0, 7.0],
            room_height_m: [2.4, 3.0],
            wall_pieces: [3, 6],
            free_pieces: [3, 6],
            stack_probability: 0.6,
        }
    }
}

impl SceneConfig {
    /// Checks ranges: ordered, finite, rooms large enough, probability in [0, 1].
    pub fn validate(&self) -> Result<()> {
        let ranges = [
            ("room_length_m", self.room_length_m, 2.6),
            ("room_width_m", self.room_width_m, 2.6),
            ("room_height_m", self.room_height_m, 2.2),
        ];
        for (field, [lo, hi], least) in ranges {
            if !(lo.is_finite() && hi.is_finite() && lo >= least && lo <= hi && hi <= 100.0) {
                return Err(Error::config(field, format!("needs {least} <= min <= max <= 100 m, got [{lo}, {hi}]")));
            }
        }
        for (field, [lo, hi]) in [("wall_pieces", self.wall_pieces), ("free_pieces", self.free_pieces)] {
            if lo > hi || hi > 100 {
                return Err(Error::config(field, format!("needs min <= max <= 100, got [{lo}, {hi}]")));
            }
        }
        if !(0.0..=1.0).contains(&self.stack_probability) {
            return Err(Error::config("stack_probability", "must lie in [0, 1]"));
        }
        Ok(())
    }
}

/// A static scene: surfaces in the world frame (metres, z up), with cached bounding boxes.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub(super) shapes: Vec<Shape>,
    pub(super) bounds: Vec<Option<Aabb>>,
}

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

impl Scene {
    /// A scene made of the given surfaces (for tests and hand-made scenes).
    pub fn from_shapes(shapes: Vec<Shape>) -> Self {
        let bounds = shapes.iter().map(Shape::aabb).collect();
        Scene { shapes, bounds }
    }

    /// The surfaces, the room shell first for generated scenes.
    pub fn shapes(&self) -> &[Shape] {
        &self.shapes
    }

    /// The room interior `(min, max)` (m), when the scene has a room shell.
    pub fn room(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        self.shapes.iter().find_map(|s| match s {
            Shape::Room { min, max } => Some((*min, *max)),
            _ => None,
        })
    }

    /// Whether `p` is at least `clearance` metres inside the room and away from every solid.
    pub fn is_free(&self, p: &Point3<f64>, clearance: f64) -> bool {
        // Room shells measure positive inside, solids positive outside: one test for both.
        self.shapes.iter().all(|s| matches!(s, Shape::Plane { .. }) || s.signed_distance(p) >= clearance)
    }

    /// A random room drawn from `config` (which should pass [`SceneConfig::validate`]); the same
    /// seed gives the same scene. The room spans `[0, L] × [0, W] × [0, H]`.
    pub fn generate(config: &SceneConfig, seed: u64) -> Scene {
        let mut rng = Rng::new(seed).fork(0x5CE4E);
        let mut draw = |r: [f64; 2]| rng.uniform_range(r[0], r[1]);
        let size = Vector3::new(draw(config.room_length_m), draw(config.room_width_m), draw(config.room_height_m));
        let mut b = Builder { rng, size, stack: config.stack_probability, shapes: Vec::new(), footprints: Vec::new() };
        b.shapes.push(Shape::Room { min: Point3::origin(), max: Point3::from(size) });
        let count = |rng: &mut Rng, [lo, hi]: [u32; 2]| lo as u64 + rng.below((hi - lo) as u64 + 1);
        for _ in 0..count(&mut b.rng, config.wall_pieces) {
            b.wall_piece();
        }
        for _ in 0..count(&mut b.rng, config.free_pieces) {
            b.free_piece();
        }
        Scene::from_shapes(b.shapes)
    }
}

/// Places pieces without overlapping footprints (touching is allowed).
struct Builder {
    rng: Rng,
    size: Vector3<f64>,
    stack: f64,
    shapes: Vec<Shape>,
    /// World-axis rectangles `[x0, y0, x1, y1]` already taken on the floor.
    footprints: Vec<[f64; 4]>,
}

impl Builder {
    fn r(&mut self, lo: f64, hi: f64) -> f64 {
        self.rng.uniform_range(lo, hi)
    }

    /// Adds `parts` (local frame) at (x, y, yaw) if the local rectangle `rect = [x0, y0, x1, y1]`
    /// lands inside the room on free floor; returns whether it did.
    fn try_add(&mut self, parts: &[Shape], rect: [f64; 4], x: f64, y: f64, yaw: f64) -> bool {
        let (s, c) = yaw.sin_cos();
        let corners = [(rect[0], rect[1]), (rect[2], rect[1]), (rect[0], rect[3]), (rect[2], rect[3])];
        let wx = corners.map(|(u, v)| x + c * u - s * v);
        let wy = corners.map(|(u, v)| y + s * u + c * v);
        let fold = |a: [f64; 4], f: fn(f64, f64) -> f64| a.into_iter().reduce(f).unwrap();
        let fp = [fold(wx, f64::min), fold(wy, f64::min), fold(wx, f64::max), fold(wy, f64::max)];
        let eps = 1e-9;
        let inside = fp[0] >= -eps && fp[1] >= -eps && fp[2] <= self.size.x + eps && fp[3] <= self.size.y + eps;
        let overlaps = |o: &[f64; 4]| fp[0] < o[2] - eps && o[0] < fp[2] - eps && fp[1] < o[3] - eps && o[1] < fp[3] - eps;
        if !inside || self.footprints.iter().any(overlaps) {
            return false;
        }
        self.footprints.push(fp);
        self.shapes.extend(parts.iter().map(|p| place(p, x, y, yaw)));
        true
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

    /// Maybe (with the stack probability) an object standing on the rectangle of half size (hx, hy)
    /// at height z, no taller than `room` metres.
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

    /// A cabinet, bookshelf or desk with its back to a random wall.
    fn wall_piece(&mut self) {
        let (gap, ceiling) = (0.01, self.size.z - 0.1);
        let kind = self.rng.below(3);
        let (w, d) = match kind {
            0 => (self.r(0.4, 1.2), self.r(0.35, 0.6)),
            1 => (self.r(0.6, 1.2), self.r(0.25, 0.4)),
            _ => (self.r(0.8, 1.6), self.r(0.5, 0.8)),
        };
        let (hx, hy) = (w / 2.0, d / 2.0);
        let mut parts = Vec::new();
        match kind {
            0 => {
                let h = self.r(0.8, 2.0).min(ceiling - 0.1);
                parts.push(block(0.0, 0.0, 0.0, hx, hy, h, 0.0));
                parts.extend(self.on_top(hx, hy, h, (ceiling - h).min(0.35)));
            }
            1 => {
                let (h, t) = (self.r(1.2, 2.0).min(ceiling), 0.02);
                for sx in [-1.0, 1.0] {
                    parts.push(block(sx * (hx - t / 2.0), 0.0, 0.0, t / 2.0, hy, h, 0.0));
                }
                parts.push(block(0.0, -hy + t / 2.0, 0.0, hx - t, t / 2.0, h, 0.0));
                let boards = 3 + self.rng.below(3);
                for k in 0..=boards {
                    let z = k as f64 * (h - t) / boards as f64;
                    parts.push(block(0.0, t / 2.0, z, hx - t, hy - t / 2.0, t, 0.0));
                }
            }
            _ => {
                let h = self.r(0.7, 0.78);
                parts = self.table(hx, hy, h);
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
            }
        }
        let wall = self.rng.below(4);
        let along_len = if wall < 2 { self.size.x } else { self.size.y };
        for _ in 0..20 {
            if w + 0.1 > along_len {
                return;
            }
            let along = self.r(hx + 0.05, along_len - hx - 0.05);
            let off = gap + hy;
            // Local +y points from the wall into the room.
            let (x, y, yaw) = match wall {
                0 => (along, off, 0.0),
                1 => (along, self.size.y - off, PI),
                2 => (off, along, -FRAC_PI_2),
                _ => (self.size.x - off, along, FRAC_PI_2),
            };
            if self.try_add(&parts, [-hx, -hy, hx, hy], x, y, yaw) {
                return;
            }
        }
    }

    /// A table, a crate (maybe stacked, maybe with a touching neighbour), a stool or a ball.
    fn free_piece(&mut self) {
        let mut parts = Vec::new();
        let rect = match self.rng.below(4) {
            0 => {
                let (hx, hy, h) = (self.r(0.3, 0.7), self.r(0.3, 0.5), self.r(0.7, 0.78));
                parts = self.table(hx, hy, h);
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
                [-hx, -hy, hx, hy]
            }
            1 => {
                let (hx, hy, h) = (self.r(0.15, 0.3), self.r(0.15, 0.3), self.r(0.25, 0.6));
                parts.push(block(0.0, 0.0, 0.0, hx, hy, h, 0.0));
                parts.extend(self.on_top(hx, hy, h, LOW_TOP_M - h));
                let mut rect = [-hx, -hy, hx, hy];
                if self.rng.uniform() < 0.5 {
                    // A second crate flush against the first one's +x side.
                    let (hx2, hy2, h2) = (self.r(0.12, 0.25), self.r(0.12, hy), self.r(0.2, 0.6));
                    parts.push(block(hx + hx2, 0.0, 0.0, hx2, hy2, h2, 0.0));
                    rect[2] = hx + 2.0 * hx2;
                }
                rect
            }
            2 => {
                let (rad, h) = (self.r(0.12, 0.3), self.r(0.3, 0.75));
                parts.push(Shape::Cylinder { axis_x: 0.0, axis_y: 0.0, radius: rad, z_min: 0.0, z_max: h });
                let s = rad / std::f64::consts::SQRT_2;
                parts.extend(self.on_top(s, s, h, LOW_TOP_M - h));
                [-rad, -rad, rad, rad]
            }
            _ => {
                let rad = self.r(0.1, 0.3);
                parts.push(Shape::Sphere { center: Point3::new(0.0, 0.0, rad), radius: rad });
                [-rad, -rad, rad, rad]
            }
        };
        let yaw = self.r(0.0, 2.0 * PI);
        for _ in 0..20 {
            let (x, y) = (self.r(0.0, self.size.x), self.r(0.0, self.size.y));
            if self.try_add(&parts, rect, x, y, yaw) {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rooms_are_deterministic_and_within_the_configured_ranges() {
        let c = SceneConfig::default();
        assert_eq!(Scene::generate(&c, 5), Scene::generate(&c, 5));
        assert_ne!(Scene::generate(&c, 5), Scene::generate(&c, 6));
        for seed in 0..40 {
            let s = Scene::generate(&c, seed);
            let (min, max) = s.room().unwrap();
            let size = max - min;
            assert!((3.0..=7.0).contains(&size.x) && (3.0..=7.0).contains(&size.y) && (2.4..=3.0).contains(&size.z));
            assert!(s.shapes().len() >= 8, "seed {seed}: only {} shapes", s.shapes().len());
            for shape in s.shapes().iter().filter(|s| s.is_solid()) {
                let b = shape.aabb().unwrap();
                // Inside the room, standing on the floor or above it, below the ceiling.
                assert!((0..3).all(|i| b.min[i] >= -1e-5 && b.max[i] <= max[i] + 1e-5), "seed {seed}: {shape:?}");
                // Tall furniture stays in the band along the walls, leaving the middle free for cameras.
                if b.max.z > LOW_TOP_M + 1e-5 {
                    let band = WALL_BAND_M + 1e-5;
                    let near_wall = b.max.x <= band || b.min.x >= size.x - band || b.max.y <= band || b.min.y >= size.y - band;
                    assert!(near_wall, "seed {seed}: tall {shape:?} away from the walls");
                }
            }
        }
    }

    #[test]
    fn rooms_hold_every_kind_of_object() {
        let (mut spheres, mut cylinders, mut yawed, mut stacked, mut floating) = (0, 0, 0, 0, 0);
        for seed in 0..20 {
            let s = Scene::generate(&SceneConfig::default(), seed);
            let solids: Vec<&Shape> = s.shapes().iter().filter(|s| s.is_solid()).collect();
            for shape in &solids {
                match shape {
                    Shape::Sphere { .. } => spheres += 1,
                    Shape::Cylinder { .. } => cylinders += 1,
                    Shape::Cuboid { yaw, .. } if (yaw / FRAC_PI_2).fract().abs() > 0.01 => yawed += 1,
                    _ => {}
                }
                let b = shape.aabb().unwrap();
                if b.min.z > 0.1 {
                    // Something off the floor rests on a solid whose top is its bottom (shelf boards and
                    // panels, thinner than 2.2 cm, hang from their sides instead).
                    let rests = solids.iter().any(|o| {
                        let ob = o.aabb().unwrap();
                        !std::ptr::eq(*o, *shape)
                            && (ob.max.z - b.min.z).abs() < 1e-4
                            && ob.min.x < b.max.x && b.min.x < ob.max.x && ob.min.y < b.max.y && b.min.y < ob.max.y
                    });
                    let panel = matches!(shape, Shape::Cuboid { half, .. } if half.min() <= 0.011);
                    let table_top = matches!(shape, Shape::Cuboid { half, .. } if half.z <= 0.021);
                    if rests {
                        stacked += usize::from(!table_top);
                    } else if !panel {
                        floating += 1;
                    }
                }
            }
        }
        assert!(spheres > 5 && cylinders > 5 && yawed > 10 && stacked > 10, "{spheres} {cylinders} {yawed} {stacked}");
        assert_eq!(floating, 0, "objects hovering in the air");
    }

    #[test]
    fn config_validation_names_the_field() {
        let bad = SceneConfig { room_length_m: [2.0, 5.0], ..SceneConfig::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("room_length_m"));
        let bad = SceneConfig { stack_probability: 1.5, ..SceneConfig::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("stack_probability"));
        assert!(SceneConfig::default().validate().is_ok());
        let parsed: SceneConfig = toml::from_str("room_height_m = [2.5, 2.6]").unwrap();
        assert_eq!(parsed.room_height_m, [2.5, 2.6]);
        assert!(toml::from_str::<SceneConfig>("room_size = 3").is_err());
    }
}
