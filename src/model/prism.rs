//! Prism tessellation of a needle (paper, §3.1): the cylinder of a needle
//! drawn as an `m`-sided prism, rebuilt from the cylinder at load time rather
//! than stored.

use super::metric::{MIN_PRISM_SIDES, line_error};
use super::needle::{Needle, WoodSegment};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::f32::consts::TAU;

/// Factor between a wood line's error (`2·r_max`) and the error where it is
/// dropped: there its coverage `2r/e` is below 1/64 (about 4 of 255 grey
/// levels on a one-pixel line), so it leaves without a visible pop.
pub const WOOD_LINE_FADE: f32 = 64.0;

/// A wood segment's error `2·r_max`: it is a prism below, a wood line from
/// it on, until [`WOOD_LINE_FADE`] times that.
pub fn wood_segment_error(segment: &WoodSegment) -> f32 {
    line_error(segment.start_radius.max(segment.end_radius))
}

/// Triangles of one capped `sides`-sided prism: `2m` for the sides plus
/// `m − 2` for each of the two caps.
pub fn prism_triangle_count(sides: u8) -> u32 {
    let m = sides.max(MIN_PRISM_SIDES) as u32;
    2 * m + 2 * (m - 2)
}

/// Vertices of an `Lmax`-slot prism as the plugin's vertex shader draws it,
/// without indices: three a triangle of [`prism_triangle_count`]
/// (`Lmax` side quads and two `(Lmax − 2)`-triangle caps).
pub fn prism_slot_vertices(max_sides: u8) -> u32 {
    3 * prism_triangle_count(max_sides)
}

/// Vertices of one capped prism: the sides use smooth radial normals (two
/// rings of `m`), each cap has its own flat ring of `m`.
pub fn prism_vertex_count(sides: u8) -> u32 {
    4 * sides.max(MIN_PRISM_SIDES) as u32
}

/// An indexed triangle list with per-vertex normals.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriangleMesh {
    /// Vertex positions, metres.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals.
    pub normals: Vec<Vec3>,
    /// Counter-clockwise triangles (seen from outside), three indices each.
    pub indices: Vec<u32>,
}

impl TriangleMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// `true` when there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// `true` when the mesh is consistent: one normal per position, whole
    /// triangles, every index in range, every number finite.
    pub fn is_valid(&self) -> bool {
        self.normals.len() == self.positions.len()
            && self.indices.len().is_multiple_of(3)
            && self.indices.iter().all(|&i| (i as usize) < self.positions.len())
            && self.positions.iter().chain(&self.normals).all(|v| v.is_finite())
    }

    /// Appends `other`, renumbering its indices.
    pub fn append(&mut self, other: &TriangleMesh) {
        let first = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.indices.extend(other.indices.iter().map(|&i| first + i));
    }
}

/// How far an `m`-sided prism's corners must lie from its axis, in radii,
/// for its silhouette to be as wide as its cylinder's `2R` on average over
/// the turns about the axis: `π / (m · sin(π/m))`. A convex polygon's
/// width averaged over directions is its perimeter over π (Cauchy), and
/// the polygon inscribed in the circle (corners at `R`) is narrower: its
/// mean width is `2R · m·sin(π/m)/π`, 2.55 % short at 8 sides, 17 % at 3.
/// 1 for a circle (`m` → ∞); `sides` below 3 counts as 3.
pub fn round_silhouette_scale(sides: u8) -> f32 {
    let m = f32::from(sides.max(MIN_PRISM_SIDES));
    std::f32::consts::PI / (m * (std::f32::consts::PI / m).sin())
}

/// Appends the open truncated cone of a wood segment with `sides` sides
/// (at least 3) and smooth normals tilted by the taper. A degenerate
/// segment appends nothing.
pub fn append_wood_segment(mesh: &mut TriangleMesh, segment: &WoodSegment, sides: u32) {
    let sides = sides.max(MIN_PRISM_SIDES as u32);
    let axis = segment.end - segment.start;
    let Some(direction) = axis.try_normalize() else {
        return;
    };
    let u = direction.any_orthonormal_vector();
    let v = direction.cross(u);
    // The cone's normal tilts by the slope of its radius.
    let slope = (segment.start_radius - segment.end_radius) / axis.length();
    let first = mesh.positions.len() as u32;
    for (centre, radius) in [(segment.start, segment.start_radius), (segment.end, segment.end_radius)] {
        for k in 0..sides {
            let angle = TAU * k as f32 / sides as f32;
            let radial = u * angle.cos() + v * angle.sin();
            mesh.positions.push(centre + radial * radius);
            mesh.normals.push((radial + direction * slope).normalize());
        }
    }
    for k in 0..sides {
        let next = (k + 1) % sides;
        let (b0, b1, t0, t1) = (first + k, first + next, first + sides + k, first + sides + next);
        mesh.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
}

/// An orthonormal frame `(u, v)` around a needle's axis, `u` as close as
/// possible to the needle's normal so a 3-sided prism shows a flat face to it.
fn radial_frame(axis: Vec3, normal: Vec3) -> (Vec3, Vec3) {
    let u = (normal - axis * normal.dot(axis)).normalize_or_zero();
    let u = if u == Vec3::ZERO {
        axis.any_orthonormal_vector()
    } else {
        u
    };
    (u, axis.cross(u))
}

/// Appends the capped `sides`-sided prism of `needle` to `mesh`: the polygon
/// inscribed in the needle's circle (radius `R`) swept from base to tip.
/// Side vertices carry smooth radial normals so the prism shades round.
///
/// `sides` below 3 is raised to 3. A needle with a degenerate axis appends
/// nothing.
pub fn append_prism(mesh: &mut TriangleMesh, needle: &Needle, sides: u8) {
    let m = sides.max(MIN_PRISM_SIDES) as u32;
    let axis_vec = needle.tip - needle.base;
    let Some(axis) = axis_vec.try_normalize() else {
        return;
    };
    let (u, v) = radial_frame(axis, needle.normal);
    let first = mesh.positions.len() as u32;
    let ring = |k: u32| {
        let angle = TAU * k as f32 / m as f32;
        u * angle.cos() + v * angle.sin()
    };
    // Side rings: base ring at first..first+m, tip ring at first+m..first+2m.
    for end in [needle.base, needle.tip] {
        for k in 0..m {
            let radial = ring(k);
            mesh.positions.push(end + radial * needle.radius);
            mesh.normals.push(radial);
        }
    }
    for k in 0..m {
        let next = (k + 1) % m;
        let (b0, b1) = (first + k, first + next);
        let (t0, t1) = (first + m + k, first + m + next);
        mesh.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
    // Caps: base ring faces -axis, tip ring faces +axis.
    for (end, normal) in [(needle.base, -axis), (needle.tip, axis)] {
        let cap = mesh.positions.len() as u32;
        for k in 0..m {
            mesh.positions.push(end + ring(k) * needle.radius);
            mesh.normals.push(normal);
        }
        for k in 1..m - 1 {
            if normal == axis {
                mesh.indices.extend_from_slice(&[cap, cap + k, cap + k + 1]);
            } else {
                mesh.indices.extend_from_slice(&[cap, cap + k + 1, cap + k]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::metric::prism_error;

    fn needle() -> Needle {
        Needle {
            base: Vec3::new(0.1, 0.2, 0.3),
            tip: Vec3::new(0.1, 0.25, 0.34),
            radius: 0.0008,
            normal: Vec3::X,
            group: 0,
        }
    }

    #[test]
    fn counts_match_the_mesh() {
        for sides in 3..=12u8 {
            let mut mesh = TriangleMesh::default();
            append_prism(&mut mesh, &needle(), sides);
            assert_eq!(mesh.triangle_count() as u32, prism_triangle_count(sides));
            assert_eq!(mesh.positions.len() as u32, prism_vertex_count(sides));
            assert!(mesh.indices.iter().all(|&i| (i as usize) < mesh.positions.len()));
        }
    }

    #[test]
    fn vertices_lie_on_the_cylinder_and_faces_within_the_prism_error() {
        let n = needle();
        let axis = (n.tip - n.base).normalize();
        for sides in 3..=10u8 {
            let mut mesh = TriangleMesh::default();
            append_prism(&mut mesh, &n, sides);
            for p in &mesh.positions {
                let d = *p - n.base;
                let radial = (d - axis * d.dot(axis)).length();
                assert!((radial - n.radius).abs() < 1e-6);
            }
            // Mid-point of a side edge: its distance to the circle is the prism error.
            let mid = (mesh.positions[0] + mesh.positions[1]) * 0.5 - n.base;
            let radial = (mid - axis * mid.dot(axis)).length();
            assert!((n.radius - radial - prism_error(n.radius, sides)).abs() < 1e-6);
        }
    }

    #[test]
    fn triangles_face_outwards() {
        let n = needle();
        let mut mesh = TriangleMesh::default();
        append_prism(&mut mesh, &n, 5);
        let centre = (n.base + n.tip) * 0.5;
        for tri in mesh.indices.chunks(3) {
            let [a, b, c] = [0, 1, 2].map(|i| mesh.positions[tri[i] as usize]);
            let face = (b - a).cross(c - a);
            let out = (a + b + c) / 3.0 - centre;
            assert!(face.dot(out) > 0.0);
        }
    }

    /// A prism whose corners lie `round_silhouette_scale` radii out has
    /// the cylinder's silhouette width on average: measured by projecting
    /// its corners across 3,600 turns about the axis.
    #[test]
    fn scaled_prisms_are_as_wide_as_their_cylinder_on_average() {
        for sides in [3u8, 4, 5, 8, 16] {
            let scale = round_silhouette_scale(sides);
            let m = u32::from(sides);
            let turns = 3_600;
            let mean_width: f32 = (0..turns)
                .map(|t| {
                    let direction = TAU * t as f32 / turns as f32;
                    let across = (0..m).map(|k| scale * (TAU * k as f32 / m as f32 - direction).cos());
                    let (lo, hi) = across.fold((f32::MAX, f32::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)));
                    hi - lo
                })
                .sum::<f32>()
                / turns as f32;
            assert!((mean_width - 2.0).abs() < 1e-3, "{sides} sides: {mean_width}");
        }
        assert!((round_silhouette_scale(8) - 1.0262).abs() < 1e-4);
        assert_eq!(round_silhouette_scale(0), round_silhouette_scale(3));
    }

    #[test]
    fn degenerate_needle_appends_nothing() {
        let mut n = needle();
        n.tip = n.base;
        let mut mesh = TriangleMesh::default();
        append_prism(&mut mesh, &n, 6);
        assert!(mesh.positions.is_empty() && mesh.indices.is_empty());
    }
}
