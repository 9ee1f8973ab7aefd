//! Procedural rooms: the [`Scene`] type and room generation (the configuration and proportions are in
//! `room.rs`, the furniture in `furnish.rs`).

use super::furnish::furnish;
use super::room::SceneConfig;
use super::shapes::{Aabb, Shape};
use crate::rng::Rng;
use nalgebra::{Point3, Vector3};

/// A static scene: surfaces in the world frame (metres, z up), with cached bounding boxes.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    pub(super) shapes: Vec<Shape>,
    pub(super) bounds: Vec<Option<Aabb>>,
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
        Scene::from_shapes(furnish(config, size, rng))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sources::synthetic::room::{LOW_TOP_M, WALL_BAND_M};
    use std::f64::consts::FRAC_PI_2;

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
                    // Something off the floor rests on a solid whose top is its bottom, or hangs on a
                    // wall; shelf boards and panels (thinner than 2.2 cm) hang from their sides.
                    let rests = solids.iter().any(|o| {
                        let ob = o.aabb().unwrap();
                        !std::ptr::eq(*o, *shape)
                            && (ob.max.z - b.min.z).abs() < 1e-4
                            && ob.min.x < b.max.x && b.min.x < ob.max.x && ob.min.y < b.max.y && b.min.y < ob.max.y
                    });
                    let panel = matches!(shape, Shape::Cuboid { half, .. } if half.min() <= 0.011);
                    let (size, tol) = (s.room().unwrap().1, 1e-4);
                    let on_wall = b.min.x < tol || b.min.y < tol || b.max.x > size.x - tol || b.max.y > size.y - tol;
                    let table_top = matches!(shape, Shape::Cuboid { half, .. } if half.z <= 0.021);
                    if rests {
                        stacked += usize::from(!table_top);
                    } else if !panel && !on_wall {
                        floating += 1;
                    }
                }
            }
        }
        assert!(spheres > 5 && cylinders > 5 && yawed > 10 && stacked > 10, "{spheres} {cylinders} {yawed} {stacked}");
        assert_eq!(floating, 0, "objects hovering in the air");
    }

    #[test]
    fn solids_do_not_interpenetrate() {
        for seed in 0..20 {
            let s = Scene::generate(&SceneConfig::default(), seed);
            let solids: Vec<&Shape> = s.shapes().iter().filter(|s| s.is_solid()).collect();
            let mut rng = Rng::new(seed);
            for (i, a) in solids.iter().enumerate() {
                let b = a.aabb().unwrap();
                for _ in 0..200 {
                    let p = Point3::new(
                        rng.uniform_range(b.min.x, b.max.x),
                        rng.uniform_range(b.min.y, b.max.y),
                        rng.uniform_range(b.min.z, b.max.z),
                    );
                    if a.signed_distance(&p) >= -1e-3 {
                        continue;
                    }
                    for (j, o) in solids.iter().enumerate() {
                        assert!(i == j || o.signed_distance(&p) >= -1e-3, "seed {seed}: {a:?} and {o:?} overlap at {p}");
                    }
                }
            }
        }
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
