//! Primitive surfaces of the synthetic scenes (room shell, boxes, cylinders, spheres, planes) with
//! analytic ray intersection, signed distance and bounding boxes. World frame: metres, z up.

use nalgebra::{Point3, Vector3};

/// The smallest ray parameter counted as a hit, so a ray never hits the point it starts on.
pub const T_MIN: f64 = 1e-9;

/// A ray–surface hit: `origin + t·dir` lies on the surface, whose unit normal (either orientation) is `normal`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter (metres when the direction has unit length).
    pub t: f64,
    /// Unit surface normal at the hit; its sign is unspecified.
    pub normal: Vector3<f64>,
}

/// A surface of a scene. Solids (cuboid, cylinder, sphere) are closed; a ray hits their boundary
/// wherever it crosses it, from outside or inside.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Shape {
    /// The infinite plane through `point` (m) with unit `normal`, visible from both sides.
    Plane { point: Point3<f64>, normal: Vector3<f64> },
    /// The inside of the axis-aligned box `[min, max]` (m): walls, floor and ceiling of a room.
    Room { min: Point3<f64>, max: Point3<f64> },
    /// A solid box: centre (m), half extents along its own axes (m), rotation about the world z axis
    /// (yaw, radians; its local x axis points along `(cos yaw, sin yaw, 0)`).
    Cuboid { center: Point3<f64>, half: Vector3<f64>, yaw: f64 },
    /// A solid upright cylinder with flat caps: vertical axis through `(axis_x, axis_y)`, radius
    /// `radius`, spanning heights `z_min..z_max` (all metres).
    Cylinder { axis_x: f64, axis_y: f64, radius: f64, z_min: f64, z_max: f64 },
    /// A solid sphere: centre and radius (m).
    Sphere { center: Point3<f64>, radius: f64 },
}

/// An axis-aligned bounding box (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Point3<f64>,
    pub max: Point3<f64>,
}

impl Aabb {
    /// Whether the ray `o + t·d`, `t ∈ [0, t_max]`, may touch the box; `inv_d` is `1/d` per component
    /// (infinite where `d` is 0). Conservative: never says no for a ray that touches the box.
    #[inline]
    pub fn may_hit(&self, o: &Point3<f64>, inv_d: &Vector3<f64>, t_max: f64) -> bool {
        let (mut lo, mut hi) = (0.0f64, t_max);
        for i in 0..3 {
            let t1 = (self.min[i] - o[i]) * inv_d[i];
            let t2 = (self.max[i] - o[i]) * inv_d[i];
            // f64::min/max ignore a NaN (0·∞), which leaves the axis unconstrained: conservative.
            lo = lo.max(t1.min(t2));
            hi = hi.min(t1.max(t2));
        }
        lo <= hi
    }
}

/// Entry and exit of the ray `o + t·d` through the origin-centred box `[-half, half]`, with the axis
/// of each; `None` when it misses.
fn slab(o: &Vector3<f64>, d: &Vector3<f64>, half: &Vector3<f64>) -> Option<((f64, usize), (f64, usize))> {
    let (mut near, mut far) = ((f64::NEG_INFINITY, 0), (f64::INFINITY, 0));
    for i in 0..3 {
        if d[i] == 0.0 {
            if o[i].abs() > half[i] {
                return None;
            }
            continue;
        }
        let (mut t1, mut t2) = ((-half[i] - o[i]) / d[i], (half[i] - o[i]) / d[i]);
        if t1 > t2 {
            std::mem::swap(&mut t1, &mut t2);
        }
        if t1 > near.0 {
            near = (t1, i);
        }
        if t2 < far.0 {
            far = (t2, i);
        }
    }
    (near.0 <= far.0).then_some((near, far))
}

/// The first of the slab crossings beyond [`T_MIN`], as (t, axis).
fn first_crossing(s: Option<((f64, usize), (f64, usize))>) -> Option<(f64, usize)> {
    let (near, far) = s?;
    if near.0 > T_MIN {
        Some(near)
    } else if far.0 > T_MIN {
        Some(far)
    } else {
        None
    }
}

/// The roots of `a t² + b t + c = 0` (`a > 0`), ascending; `None` without real roots.
fn quadratic(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 || a <= 0.0 {
        return None;
    }
    // The numerically stable form: no cancellation between b and the square root.
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (q / a, c / q) };
    Some(if t0 <= t1 { (t0, t1) } else { (t1, t0) })
}

/// Rotates `v` about the z axis by `angle` radians.
fn rot_z(v: &Vector3<f64>, angle: f64) -> Vector3<f64> {
    let (s, c) = angle.sin_cos();
    Vector3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z)
}

fn unit_axis(i: usize) -> Vector3<f64> {
    let mut n = Vector3::zeros();
    n[i] = 1.0;
    n
}

impl Shape {
    /// The first hit of the ray `o + t·d` with `T_MIN < t < t_max`; `d` need not have unit length.
    pub fn intersect(&self, o: &Point3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let hit = match self {
            Shape::Plane { point, normal } => {
                let den = normal.dot(d);
                if den == 0.0 {
                    return None;
                }
                let t = normal.dot(&(point - o)) / den;
                (t > T_MIN).then_some(Hit { t, normal: *normal })
            }
            Shape::Room { min, max } => {
                let c = nalgebra::center(min, max);
                let half = (max - min) * 0.5;
                first_crossing(slab(&(o - c), d, &half)).map(|(t, i)| Hit { t, normal: unit_axis(i) })
            }
            Shape::Cuboid { center, half, yaw } => {
                let lo = rot_z(&(o - center), -yaw);
                let ld = rot_z(d, -yaw);
                first_crossing(slab(&lo, &ld, half)).map(|(t, i)| Hit { t, normal: rot_z(&unit_axis(i), *yaw) })
            }
            Shape::Sphere { center, radius } => {
                let oc = o - center;
                let (t0, t1) = quadratic(d.norm_squared(), 2.0 * d.dot(&oc), oc.norm_squared() - radius * radius)?;
                let t = if t0 > T_MIN { t0 } else if t1 > T_MIN { t1 } else { return None };
                Some(Hit { t, normal: (oc + d * t) / *radius })
            }
            Shape::Cylinder { axis_x, axis_y, radius, z_min, z_max } => {
                let (ox, oy) = (o.x - axis_x, o.y - axis_y);
                let mut best: Option<Hit> = None;
                let mut consider = |t: f64, normal: Vector3<f64>| {
                    if t > T_MIN && best.map_or(true, |b| t < b.t) {
                        best = Some(Hit { t, normal });
                    }
                };
                let a = d.x * d.x + d.y * d.y;
                if let Some((t0, t1)) = quadratic(a, 2.0 * (d.x * ox + d.y * oy), ox * ox + oy * oy - radius * radius) {
                    for t in [t0, t1] {
                        let z = o.z + t * d.z;
                        if z >= *z_min && z <= *z_max {
                            consider(t, Vector3::new(ox + t * d.x, oy + t * d.y, 0.0) / *radius);
                        }
                    }
                }
                if d.z != 0.0 {
                    for zc in [*z_min, *z_max] {
                        let t = (zc - o.z) / d.z;
                        let (x, y) = (ox + t * d.x, oy + t * d.y);
                        if x * x + y * y <= radius * radius {
                            consider(t, Vector3::z());
                        }
                    }
                }
                best
            }
        }?;
        (hit.t < t_max).then_some(hit)
    }

    /// Signed distance from `p` to the surface (m): negative inside a solid, positive outside it;
    /// for a room, positive inside; for a plane, positive on the side the normal points to.
    pub fn signed_distance(&self, p: &Point3<f64>) -> f64 {
        fn box_sdf(q: &Vector3<f64>, half: &Vector3<f64>) -> f64 {
            let d = q.abs() - half;
            d.sup(&Vector3::zeros()).norm() + d.max().min(0.0)
        }
        match self {
            Shape::Plane { point, normal } => normal.dot(&(p - point)),
            Shape::Room { min, max } => -box_sdf(&(p - nalgebra::center(min, max)), &((max - min) * 0.5)),
            Shape::Cuboid { center, half, yaw } => box_sdf(&rot_z(&(p - center), -yaw), half),
            Shape::Sphere { center, radius } => (p - center).norm() - radius,
            Shape::Cylinder { axis_x, axis_y, radius, z_min, z_max } => {
                let radial = (p.x - axis_x).hypot(p.y - axis_y) - radius;
                let axial = (p.z - 0.5 * (z_min + z_max)).abs() - 0.5 * (z_max - z_min);
                radial.max(axial).min(0.0) + radial.max(0.0).hypot(axial.max(0.0))
            }
        }
    }

    /// Whether this is a solid object (not the room shell or a plane).
    pub fn is_solid(&self) -> bool {
        matches!(self, Shape::Cuboid { .. } | Shape::Cylinder { .. } | Shape::Sphere { .. })
    }

    /// The axis-aligned bounding box (m), `None` for an unbounded plane.
    pub fn aabb(&self) -> Option<Aabb> {
        let (min, max) = match self {
            Shape::Plane { .. } => return None,
            Shape::Room { min, max } => (*min, *max),
            Shape::Cuboid { center, half, yaw } => {
                let (s, c) = yaw.sin_cos();
                let ex = Vector3::new(
                    c.abs() * half.x + s.abs() * half.y,
                    s.abs() * half.x + c.abs() * half.y,
                    half.z,
                );
                (center - ex, center + ex)
            }
            Shape::Sphere { center, radius } => {
                (center - Vector3::repeat(*radius), center + Vector3::repeat(*radius))
            }
            Shape::Cylinder { axis_x, axis_y, radius, z_min, z_max } => (
                Point3::new(axis_x - radius, axis_y - radius, *z_min),
                Point3::new(axis_x + radius, axis_y + radius, *z_max),
            ),
        };
        // Padding keeps the pre-test conservative against rounding.
        let pad = Vector3::repeat(1e-6);
        Some(Aabb { min: min - pad, max: max + pad })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }
    fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z)
    }

    #[test]
    fn sphere_hits_match_closed_form_and_misses_are_none() {
        let s = Shape::Sphere { center: p(0.0, 0.0, 5.0), radius: 1.0 };
        // Along the axis: enters at z = 4.
        let h = s.intersect(&p(0.0, 0.0, 0.0), &v(0.0, 0.0, 1.0), f64::INFINITY).unwrap();
        assert!((h.t - 4.0).abs() < 1e-12 && (h.normal - v(0.0, 0.0, -1.0)).norm() < 1e-12);
        // Offset by b = 0.6: t = 5 − sqrt(1 − 0.36) = 4.2; an unnormalised direction scales t.
        let h = s.intersect(&p(0.6, 0.0, 0.0), &v(0.0, 0.0, 2.0), f64::INFINITY).unwrap();
        assert!((h.t - 2.1).abs() < 1e-12, "{}", h.t);
        // From inside: the exit.
        let h = s.intersect(&p(0.0, 0.0, 5.0), &v(1.0, 0.0, 0.0), f64::INFINITY).unwrap();
        assert!((h.t - 1.0).abs() < 1e-12);
        assert!(s.intersect(&p(1.01, 0.0, 0.0), &v(0.0, 0.0, 1.0), f64::INFINITY).is_none());
        assert!(s.intersect(&p(0.0, 0.0, 0.0), &v(0.0, 0.0, -1.0), f64::INFINITY).is_none());
        assert!(s.intersect(&p(0.0, 0.0, 0.0), &v(0.0, 0.0, 1.0), 3.9).is_none(), "beyond t_max");
    }

    #[test]
    fn cylinder_side_and_cap_hits_match_closed_form() {
        let c = Shape::Cylinder { axis_x: 2.0, axis_y: 0.0, radius: 0.5, z_min: 0.0, z_max: 1.0 };
        // Horizontal ray at height 0.5 offset by 0.3 from the axis: x = 2 − sqrt(0.25 − 0.09) = 1.6.
        let h = c.intersect(&p(0.0, 0.3, 0.5), &v(1.0, 0.0, 0.0), f64::INFINITY).unwrap();
        assert!((h.t - 1.6).abs() < 1e-12, "{}", h.t);
        assert!((h.normal - v(-0.8, 0.6, 0.0)).norm() < 1e-12);
        // Straight down onto the top cap.
        let h = c.intersect(&p(2.1, 0.1, 3.0), &v(0.0, 0.0, -1.0), f64::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-12 && h.normal.z.abs() == 1.0);
        // Oblique ray passing over the rim: it reaches the top plane at x = 3 (outside the disc) and
        // the side surface x = 2.5 at z = 1.5 (above the cylinder).
        assert!(c.intersect(&p(2.0, 0.0, 2.0), &v(1.0, 0.0, -1.0), f64::INFINITY).is_none());
        // Above the cylinder and below it: misses.
        assert!(c.intersect(&p(0.0, 0.0, 1.2), &v(1.0, 0.0, 0.0), f64::INFINITY).is_none());
        assert!(c.intersect(&p(0.0, 0.6, 0.5), &v(1.0, 0.0, 0.0), f64::INFINITY).is_none());
    }

    #[test]
    fn yawed_cuboid_and_room_hits() {
        // A unit cube at x = 3 turned 45°: the ray along x meets its edge at x = 3 − sqrt(0.5).
        let b = Shape::Cuboid { center: p(3.0, 0.0, 0.0), half: v(0.5, 0.5, 0.5), yaw: std::f64::consts::FRAC_PI_4 };
        let h = b.intersect(&p(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), f64::INFINITY).unwrap();
        assert!((h.t - (3.0 - 0.5f64.sqrt())).abs() < 1e-12);
        assert!(b.intersect(&p(0.0, 0.75, 0.0), &v(1.0, 0.0, 0.0), f64::INFINITY).is_none());
        let r = Shape::Room { min: p(0.0, 0.0, 0.0), max: p(4.0, 5.0, 3.0) };
        let h = r.intersect(&p(1.0, 1.0, 1.5), &v(0.0, 1.0, 0.0), f64::INFINITY).unwrap();
        assert!((h.t - 4.0).abs() < 1e-12 && h.normal == v(0.0, 1.0, 0.0));
        let pl = Shape::Plane { point: p(0.0, 0.0, 2.0), normal: v(0.0, 0.0, 1.0) };
        assert_eq!(pl.intersect(&p(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.5), f64::INFINITY).unwrap().t, 4.0);
        assert!(pl.intersect(&p(0.0, 0.0, 0.0), &v(1.0, 0.0, 0.0), f64::INFINITY).is_none());
    }

    #[test]
    fn signed_distances_and_bounds() {
        let b = Shape::Cuboid { center: p(0.0, 0.0, 0.0), half: v(1.0, 2.0, 3.0), yaw: 0.0 };
        assert_eq!(b.signed_distance(&p(0.0, 0.0, 0.0)), -1.0);
        assert!((b.signed_distance(&p(4.0, 6.0, 0.0)) - 5.0).abs() < 1e-12);
        let c = Shape::Cylinder { axis_x: 0.0, axis_y: 0.0, radius: 1.0, z_min: 0.0, z_max: 2.0 };
        assert!((c.signed_distance(&p(4.0, 0.0, 6.0)) - 5.0).abs() < 1e-12);
        assert!((c.signed_distance(&p(0.5, 0.0, 1.0)) + 0.5).abs() < 1e-12);
        let r = Shape::Room { min: p(0.0, 0.0, 0.0), max: p(4.0, 4.0, 3.0) };
        assert!((r.signed_distance(&p(1.0, 2.0, 2.5)) - 0.5).abs() < 1e-12);
        let y = Shape::Cuboid { center: p(1.0, 1.0, 0.5), half: v(1.0, 0.2, 0.5), yaw: 0.7 };
        let bb = y.aabb().unwrap();
        // Every corner of the turned box lies inside its bounds.
        for sx in [-1.0, 1.0] {
            for sy in [-1.0, 1.0] {
                let q = p(1.0, 1.0, 0.5) + rot_z(&v(sx * 1.0, sy * 0.2, 0.0), 0.7);
                assert!((0..3).all(|i| q[i] >= bb.min[i] && q[i] <= bb.max[i]));
            }
        }
        let inv = v(1.0, 1.0 / 0.0, 1.0 / 0.0);
        assert!(bb.may_hit(&p(-5.0, 1.0, 0.5), &inv, f64::INFINITY));
        assert!(!bb.may_hit(&p(-5.0, 5.0, 0.5), &inv, f64::INFINITY));
        assert!(!bb.may_hit(&p(-5.0, 1.0, 0.5), &inv, 1.0));
    }
}
