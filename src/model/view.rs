//! View-dependent detail inside one tree: each placement and each level-2
//! node of a [`PrototypeRecord`](super::PrototypeRecord) takes its spatial
//! error from the nearest point of its own bounding sphere, so a camera in
//! a 40 m crown sees prisms beside it and merged lines across the crown.
//!
//! ## Why the cut stays an exact partition
//!
//! With `k` the spatial error per metre of distance, node `X` is
//! *acceptable* from camera `c` when `e(X) ≤ k · d(c, S_X)`, where `S_X` is
//! its sphere and `d` the distance to the sphere's nearest point (0 inside).
//! Every parent's sphere holds its children's spheres, so
//! `d(c, S_parent) ≤ d(c, S_child)`, and errors grow up the hierarchy: a
//! child of an acceptable node is acceptable. Along every path from a root
//! to a needle the acceptable nodes are therefore a tail, and the per-node
//! test the GPU makes (acceptable, parent not) picks exactly the node the
//! top-down walk stops at ([`PrototypeRecord::cut_seen_from`](super::PrototypeRecord::cut_seen_from)).
//! Inside one placement every node takes the placement's error: the
//! placement is the unit of detail, as the issue asks.
//!
//! ## Rounding
//!
//! The distances are `f32`: `|c − centre| − radius` is off by a few units in
//! the last place of the larger operand. Each parent sphere is grown by
//! [`SPHERE_MARGIN`] of the tree's radius beyond what holds its children,
//! which covers that rounding for a camera within [`VIEW_RANGE`] tree radii
//! of the tree; farther away every node takes the tree sphere's error (the
//! spheres then differ by less than `1/VIEW_RANGE` in distance), so the
//! test is exact at any distance.

use super::needle::WoodSegment;
use super::prototype::Placement;
use glam::Vec3;

/// Growth of each parent sphere beyond its children's, as a fraction of
/// the tree sphere's radius (`2⁻¹²`): 60 times the rounding of a distance
/// from a camera [`VIEW_RANGE`] radii away.
pub const SPHERE_MARGIN: f32 = 1.0 / 4096.0;

/// Farthest a camera may be from the tree's sphere, in its radii, for the
/// nodes to take their own spheres' errors; beyond it they all take the
/// tree sphere's.
pub const VIEW_RANGE: f32 = 256.0;

/// A bounding sphere, in the frame of whatever it bounds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sphere {
    /// Centre.
    pub center: Vec3,
    /// Radius (≥ 0).
    pub radius: f32,
}

impl Sphere {
    /// A sphere holding every point (the centre of their bounding box and
    /// the farthest of them), grown by `pad`; `None` without points or
    /// with a non-finite one.
    pub fn around_points(points: impl IntoIterator<Item = Vec3> + Clone, pad: f32) -> Option<Self> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for p in points.clone() {
            if !p.is_finite() {
                return None;
            }
            lo = lo.min(p);
            hi = hi.max(p);
        }
        if lo.x > hi.x {
            return None;
        }
        let center = 0.5 * (lo + hi);
        let radius = points.into_iter().map(|p| p.distance(center)).fold(0.0, f32::max);
        Some(Self {
            center,
            radius: radius + pad.max(0.0),
        })
    }

    /// The smallest sphere holding both spheres.
    pub fn enclosing(&self, other: &Sphere) -> Sphere {
        let gap = other.center - self.center;
        let distance = gap.length();
        if distance + other.radius <= self.radius {
            return *self;
        }
        if distance + self.radius <= other.radius {
            return *other;
        }
        let radius = 0.5 * (distance + self.radius + other.radius);
        // distance > |r₁ − r₂| ≥ 0 here, so the direction exists.
        let center = self.center + gap * ((radius - self.radius) / distance);
        Sphere { center, radius }
    }

    /// A sphere holding a wood segment: round its midpoint, half its
    /// length plus its wider radius (the shaders bound a segment the same
    /// way).
    pub fn around_wood(segment: &WoodSegment) -> Self {
        Self {
            center: 0.5 * (segment.start + segment.end),
            radius: 0.5 * segment.start.distance(segment.end) + segment.start_radius.max(segment.end_radius),
        }
    }

    /// The sphere grown by `margin`.
    pub fn grown(&self, margin: f32) -> Sphere {
        Sphere {
            center: self.center,
            radius: self.radius + margin,
        }
    }

    /// Distance from `point` to the sphere's nearest point, 0 inside, as
    /// the shaders compute it (`max(length(p − c) − r, 0)`).
    pub fn distance_from(&self, point: Vec3) -> f32 {
        ((point - self.center).length() - self.radius).max(0.0)
    }

    /// The sphere once `placement` moves, turns and scales it.
    pub fn placed(&self, placement: &Placement) -> Sphere {
        Sphere {
            center: placement.place_point(self.center),
            radius: self.radius * placement.scale,
        }
    }

    /// `[x, y, z, radius]`, as the GPU stores it.
    pub fn to_array(&self) -> [f32; 4] {
        self.center.extend(self.radius).to_array()
    }
}

/// Where one view sees a tree from: the camera in the tree's own frame and
/// the spatial error per metre of distance (tree metres;
/// [`ViewParams::error_per_distance`](super::ViewParams::error_per_distance)
/// over the tree's scale cancels out, as both are in the tree's frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewPoint {
    /// The camera, tree metres.
    pub camera: Vec3,
    /// Spatial error per metre of distance (`e = k · d`, `k ≥ 0`).
    pub error_per_metre: f32,
}

impl ViewPoint {
    /// The view's point and slope; a negative or NaN slope counts as 0.
    pub fn new(camera: Vec3, error_per_metre: f32) -> Self {
        Self {
            camera,
            error_per_metre: if error_per_metre > 0.0 { error_per_metre } else { 0.0 },
        }
    }

    /// `true` when the camera is farther than [`VIEW_RANGE`] radii from
    /// `tree`: every node then takes `tree`'s error.
    pub fn beyond_range(&self, tree: &Sphere) -> bool {
        tree.distance_from(self.camera) > VIEW_RANGE * tree.radius
    }

    /// Spatial error of what `sphere` bounds, seen from the camera:
    /// `k · d(camera, sphere)`.
    pub fn spatial_error(&self, sphere: &Sphere) -> f32 {
        self.error_per_metre * sphere.distance_from(self.camera)
    }

    /// Spatial error of a node bounded by `sphere` in a tree bounded by
    /// `tree`: its own sphere's, or the tree's for a camera
    /// [`beyond_range`](Self::beyond_range) (as `conifer_cull.wgsl` decides).
    pub fn node_error(&self, tree: &Sphere, sphere: &Sphere) -> f32 {
        if self.beyond_range(tree) {
            self.spatial_error(tree)
        } else {
            self.spatial_error(sphere)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn contains(outer: &Sphere, inner: &Sphere) -> bool {
        outer.center.distance(inner.center) + inner.radius <= outer.radius * (1.0 + 1e-6) + 1e-6
    }

    #[test]
    fn enclosing_holds_both_and_is_tight() {
        let a = Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
        };
        let b = Sphere {
            center: Vec3::new(4.0, 0.0, 0.0),
            radius: 2.0,
        };
        let both = a.enclosing(&b);
        assert!(contains(&both, &a) && contains(&both, &b));
        assert!((both.radius - 3.5).abs() < 1e-6, "{both:?}");
        assert_eq!(both.center, Vec3::new(2.5, 0.0, 0.0));
        // One inside the other: the outer one, unchanged.
        let small = Sphere {
            center: Vec3::new(0.5, 0.0, 0.0),
            radius: 0.2,
        };
        assert_eq!(a.enclosing(&small), a);
        assert_eq!(small.enclosing(&a), a);
        assert_eq!(a.enclosing(&a), a);
    }

    #[test]
    fn distance_is_zero_inside_and_grows_outside() {
        let s = Sphere {
            center: Vec3::new(1.0, 2.0, 3.0),
            radius: 2.0,
        };
        assert_eq!(s.distance_from(s.center), 0.0);
        assert_eq!(s.distance_from(Vec3::new(2.0, 2.0, 3.0)), 0.0);
        assert!((s.distance_from(Vec3::new(1.0, 2.0, 8.0)) - 3.0).abs() < 1e-6);
        let view = ViewPoint::new(Vec3::new(1.0, 2.0, 8.0), 0.5);
        assert!((view.spatial_error(&s) - 1.5).abs() < 1e-6);
        assert_eq!(ViewPoint::new(Vec3::ZERO, f32::NAN).error_per_metre, 0.0);
        assert!(!view.beyond_range(&s));
        assert!(ViewPoint::new(Vec3::splat(1e4), 1.0).beyond_range(&s));
    }

    #[test]
    fn around_points_holds_them() {
        let points = [Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 3.0, -1.0)];
        let s = Sphere::around_points(points, 0.1).unwrap();
        for p in points {
            assert!(p.distance(s.center) + 0.1 <= s.radius + 1e-6);
        }
        assert!(Sphere::around_points(std::iter::empty::<Vec3>(), 0.0).is_none());
        assert!(Sphere::around_points([Vec3::NAN], 0.0).is_none());
    }
}
