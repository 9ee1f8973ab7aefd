//! Analytic ray casting of a scene: exact noise-free z-depth images and incidence angles.
//!
//! Pixel convention (the official one): pixel (c, r) looks along `((c − cx)/fx, (r − cy)/fy, 1)` in the
//! camera frame (x right, y down, z forward), integer coordinates, no half-pixel offset. With that
//! unnormalised direction the ray parameter of a hit *is* its z-depth.

use super::scene::Scene;
use super::shapes::{Aabb, Hit};
use crate::geometry::{DepthMap, Intrinsics};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// A rendered view: noise-free depth and, per pixel, the cosine of the incidence angle.
#[derive(Clone, Debug, PartialEq)]
pub struct Render {
    /// Exact z-depth in metres; 0 where the ray hits nothing.
    pub depth: DepthMap,
    /// `|cos θ|` between the viewing ray and the surface normal (1 = frontal, 0 = grazing), row-major;
    /// 0 where the ray hits nothing.
    pub cos_incidence: Vec<f32>,
}

/// The pixel rectangle `[c0, r0, c1, r1]` that can see `b`, `None` when `b` lies entirely behind
/// the camera: the bounds of the projection of the part of `b` with camera z ≥ 1e-9 m (hits nearer
/// than that are not counted anyway, see [`super::shapes::T_MIN`]), padded by a pixel.
fn screen_rect(b: &Aabb, t_camera_from_world: &Isometry3<f64>, k: &Intrinsics) -> Option<[f64; 4]> {
    const NEAR: f64 = 1e-9;
    let corners: Vec<Point3<f64>> = (0..8)
        .map(|i| {
            let pick = |bit: usize, axis: usize| if i & bit == 0 { b.min[axis] } else { b.max[axis] };
            t_camera_from_world * Point3::new(pick(1, 0), pick(2, 1), pick(4, 2))
        })
        .collect();
    let mut visible: Vec<Point3<f64>> = corners.iter().filter(|p| p.z >= NEAR).copied().collect();
    // Where the box's edges cross the near plane.
    for i in 0..8 {
        for bit in [1, 2, 4] {
            let (p, q) = (corners[i], corners[i | bit]);
            if i & bit == 0 && (p.z < NEAR) != (q.z < NEAR) {
                visible.push(p + (q - p) * ((NEAR - p.z) / (q.z - p.z)));
            }
        }
    }
    let mut rect = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    for p in &visible {
        let z = p.z.max(NEAR);
        let (u, v) = (k.fx * p.x / z + k.cx, k.fy * p.y / z + k.cy);
        rect = [rect[0].min(u), rect[1].min(v), rect[2].max(u), rect[3].max(v)];
    }
    (!visible.is_empty()).then_some([rect[0] - 1.0, rect[1] - 1.0, rect[2] + 1.0, rect[3] + 1.0])
}

impl Scene {
    /// The first surface hit by the ray `o + t·d` (`t > 0`), among `candidates` (indices into the shapes).
    fn first_hit_among(&self, o: &Point3<f64>, d: &Vector3<f64>, candidates: impl Iterator<Item = usize>) -> Option<Hit> {
        let inv = d.map(|v| 1.0 / v);
        let mut best: Option<Hit> = None;
        let mut t_max = f64::INFINITY;
        for i in candidates {
            if let Some(b) = &self.bounds[i] {
                if !b.may_hit(o, &inv, t_max) {
                    continue;
                }
            }
            if let Some(h) = self.shapes[i].intersect(o, d, t_max) {
                t_max = h.t;
                best = Some(h);
            }
        }
        best
    }

    /// The first surface hit by the ray `o + t·d`, `t > 0`; `d` need not have unit length.
    pub fn first_hit(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        self.first_hit_among(o, d, 0..self.shapes.len())
    }

    /// Distance in metres from `origin` along `dir` (any non-zero length) to the first surface, or
    /// `None` when the ray escapes (or `dir` is zero or not finite).
    pub fn raycast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<f64> {
        let n = dir.norm();
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        self.first_hit(origin, &(dir / n)).map(|h| h.t)
    }

    /// Exact noise-free z-depth (metres, not ray length) seen by camera `k` at `t_world_from_camera`.
    pub fn render_depth(&self, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> DepthMap {
        self.render(k, t_world_from_camera).depth
    }

    /// Depth and incidence cosines of the view, rows in parallel (the result is independent of the
    /// thread count: every pixel is computed on its own).
    pub fn render(&self, k: &Intrinsics, t_world_from_camera: &Isometry3<f64>) -> Render {
        let (w, h) = (k.width as usize, k.height as usize);
        let t_camera_from_world = t_world_from_camera.inverse();
        let rects: Vec<Option<[f64; 4]>> = self
            .bounds
            .iter()
            .map(|b| match b {
                Some(b) => screen_rect(b, &t_camera_from_world, k),
                None => Some([f64::NEG_INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::INFINITY]),
            })
            .collect();
        let rot = t_world_from_camera.rotation.to_rotation_matrix();
        let o = Point3::from(t_world_from_camera.translation.vector);
        let mut depth = vec![0.0f32; w * h];
        let mut cos = vec![0.0f32; w * h];
        depth.par_chunks_mut(w).zip(cos.par_chunks_mut(w)).enumerate().for_each(|(r, (drow, crow))| {
            let rf = r as f64;
            let active: Vec<(usize, f64, f64)> = rects
                .iter()
                .enumerate()
                .filter_map(|(i, rect)| rect.filter(|q| q[1] <= rf && rf <= q[3]).map(|q| (i, q[0], q[2])))
                .collect();
            let ay = (rf - k.cy) / k.fy;
            for c in 0..w {
                let cf = c as f64;
                let d = rot * Vector3::new((cf - k.cx) / k.fx, ay, 1.0);
                let candidates = active.iter().filter(|a| a.1 <= cf && cf <= a.2).map(|a| a.0);
                if let Some(hit) = self.first_hit_among(&o, &d, candidates) {
                    let z = hit.t as f32;
                    if z.is_finite() && z > 0.0 {
                        drow[c] = z;
                        crow[c] = (hit.normal.dot(&d).abs() / d.norm()) as f32;
                    }
                }
            }
        });
        Render { depth: DepthMap::new(k.width, k.height, depth).expect("finite non-negative depth"), cos_incidence: cos }
    }
}

#[cfg(test)]
mod tests {
    use super::super::shapes::Shape;
    use super::super::{look_pose, trajectory, Scene, SceneConfig};
    use super::*;
    use crate::geometry::{backproject, DepthRange};

    fn plane(point: Point3<f64>, normal: Vector3<f64>) -> Shape {
        Shape::Plane { point, normal }
    }

    #[test]
    fn a_wall_facing_the_camera_reads_its_distance_everywhere() {
        let k = Intrinsics::new(123.4, 118.9, 41.3, 29.7, 80, 60).unwrap();
        let scene = Scene::from_shapes(vec![plane(Point3::new(0.0, 0.0, 2.5), Vector3::z())]);
        let d = scene.render_depth(&k, &Isometry3::identity());
        assert!(d.data().iter().all(|&z| z == 2.5f32), "identity pose: exact");
        // Any pose: a plane perpendicular to the optical axis at distance d has z = d at every pixel.
        let pose = look_pose(Point3::new(1.0, -2.0, 1.3), 0.7, -0.3, 0.05);
        let f = pose.rotation * Vector3::z();
        let wall = Scene::from_shapes(vec![plane(Point3::from(pose.translation.vector + f * 3.25), f)]);
        let r = wall.render(&k, &pose);
        assert!(r.depth.data().iter().all(|&z| (z - 3.25).abs() < 2e-6));
        // Incidence cosine of a frontal plane: the cosine of the pixel's angle to the axis.
        let (c, row) = (70usize, 5usize);
        let (a, b) = ((c as f64 - k.cx) / k.fx, (row as f64 - k.cy) / k.fy);
        let expect = 1.0 / (1.0 + a * a + b * b).sqrt();
        assert!((r.cos_incidence[row * 80 + c] as f64 - expect).abs() < 1e-6);
    }

    #[test]
    fn a_box_in_front_of_a_wall_covers_its_analytic_footprint() {
        let k = Intrinsics::new(123.4, 118.9, 41.3, 29.7, 80, 60).unwrap();
        let (x0, x1, y0, y1, z0, z1) = (0.2, 0.6, -0.3, 0.1, 2.0, 3.0);
        let scene = Scene::from_shapes(vec![
            plane(Point3::new(0.0, 0.0, z1), -Vector3::z()),
            Shape::Cuboid {
                center: Point3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, (z0 + z1) / 2.0),
                half: Vector3::new((x1 - x0) / 2.0, (y1 - y0) / 2.0, (z1 - z0) / 2.0),
                yaw: 0.0,
            },
        ]);
        let d = scene.render_depth(&k, &Isometry3::identity());
        let (mut front, mut side, mut wall) = (0, 0, 0);
        for r in 0..60u32 {
            for c in 0..80u32 {
                let (a, b) = ((c as f64 - k.cx) / k.fx, (r as f64 - k.cy) / k.fy);
                // Depths z at which the ray (a z, b z, z) is inside the box's x and y ranges.
                let range = |s: f64, lo: f64, hi: f64| {
                    if s > 0.0 { (lo / s, hi / s) } else if s < 0.0 { (hi / s, lo / s) } else if lo <= 0.0 && 0.0 <= hi { (f64::NEG_INFINITY, f64::INFINITY) } else { (1.0, 0.0) }
                };
                let (ax, bx) = range(a, x0, x1);
                let (ay, by) = range(b, y0, y1);
                let (lo, hi) = (ax.max(ay).max(z0), bx.min(by).min(z1));
                let expect = if lo <= hi { lo } else { z1 };
                if expect == z0 {
                    front += 1;
                } else if expect == z1 {
                    wall += 1;
                } else {
                    side += 1;
                }
                assert!((d.at(c, r) as f64 - expect).abs() < 1e-6, "pixel ({c},{r}): {} vs {expect}", d.at(c, r));
            }
        }
        assert!(front > 300 && side > 20 && wall > 1000, "{front} {side} {wall}");
    }

    #[test]
    fn rendered_points_lie_on_scene_surfaces_and_raycast_agrees() {
        let k = Intrinsics::new(150.0, 150.0, 80.0, 60.0, 160, 120).unwrap();
        for seed in [1u64, 2, 3] {
            let scene = Scene::generate(&SceneConfig::default(), seed);
            let poses = trajectory(&scene, 40, seed);
            for pose in [poses[0], poses[39]] {
                let d = scene.render_depth(&k, &pose);
                assert_eq!(d.valid_count(), 160 * 120, "a closed room: every ray hits");
                for p in backproject(&d, &k, DepthRange::ANY).iter().step_by(7) {
                    let w = pose * Point3::new(p.x as f64, p.y as f64, p.z as f64);
                    let dist = scene.shapes().iter().map(|s| s.signed_distance(&w).abs()).fold(f64::INFINITY, f64::min);
                    assert!(dist < 1e-4, "seed {seed}: point {w} is {dist} m off every surface");
                }
                // raycast gives ray length: z·|dir| for the pixel's unnormalised direction.
                let (c, r) = (37u32, 101u32);
                let dir_cam = Vector3::new((c as f64 - k.cx) / k.fx, (r as f64 - k.cy) / k.fy, 1.0);
                let o = Point3::from(pose.translation.vector);
                let len = scene.raycast(&o, &(pose.rotation * dir_cam * 3.0)).unwrap();
                assert!((len - d.at(c, r) as f64 * dir_cam.norm()).abs() < 1e-5);
            }
        }
        let empty = Scene::from_shapes(vec![plane(Point3::new(0.0, 0.0, 1.0), Vector3::z())]);
        assert_eq!(empty.raycast(&Point3::origin(), &Vector3::new(0.0, 0.0, -2.0)), None, "plane behind");
        assert_eq!(empty.raycast(&Point3::origin(), &Vector3::new(1.0, 0.0, 0.0)), None);
        assert_eq!(empty.raycast(&Point3::origin(), &Vector3::zeros()), None);
    }

    #[test]
    fn screen_culling_never_hides_a_surface() {
        // Wide-angle cameras at random free spots, often right next to furniture, so that bounding
        // boxes straddle the camera plane: the culled render must equal a brute-force cast per pixel.
        let k = Intrinsics::new(20.0, 20.0, 31.5, 23.5, 64, 48).unwrap();
        let mut rng = crate::rng::Rng::new(8);
        for seed in 0..6 {
            let scene = Scene::generate(&SceneConfig::default(), seed);
            let (_, max) = scene.room().unwrap();
            let mut views = 0;
            while views < 8 {
                let o = Point3::new(rng.uniform_range(0.0, max.x), rng.uniform_range(0.0, max.y), rng.uniform_range(0.0, max.z));
                if !scene.is_free(&o, 0.02) {
                    continue;
                }
                views += 1;
                let pose = look_pose(o, rng.uniform_range(0.0, 6.3), rng.uniform_range(-1.2, 1.2), rng.uniform_range(-0.5, 0.5));
                let r = scene.render(&k, &pose);
                for row in 0..48u32 {
                    for c in 0..64u32 {
                        let d = pose.rotation * Vector3::new((c as f64 - k.cx) / k.fx, (row as f64 - k.cy) / k.fy, 1.0);
                        let t = scene.first_hit(&o, &d).map_or(0.0, |h| h.t as f32);
                        assert_eq!(r.depth.at(c, row), t, "seed {seed}, pixel ({c},{row})");
                    }
                }
            }
        }
    }
}
