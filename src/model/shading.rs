//! How a line is lit: as the cylinder (or bundle of cylinders) it stands
//! for, not as a flat strip facing the viewer. CPU reference of the line
//! fragment shader's `cylinder_lighting` (`conifer_compact.wgsl`).
//!
//! A pixel covered by a thin cylinder sees the radiance of its visible half
//! averaged over the cylinder's projected width. With `s ∈ [−1, 1]` the
//! offset across that width, the surface normal there is
//! `n(s) = √(1 − s²)·t + s·b`, where `t` is the direction to the viewer
//! made perpendicular to the axis and `b = axis × t`; a uniform measure in
//! `s` is the pixel's average. The shader evaluates Bevy's BRDF at the
//! four Gauss–Legendre nodes of `s` ([`ACROSS_NODES`]).

use glam::Vec3;
use std::f32::consts::PI;

/// The four-point Gauss–Legendre rule on `[−1, 1]`: offsets across a
/// cylinder's projected width and their weights (summing to 2), as the
/// shader's `across_offset` and `across_weight`.
pub const ACROSS_NODES: [(f32, f32); 4] = [
    (-0.861_136_3, 0.347_854_85),
    (-0.339_981_04, 0.652_145_15),
    (0.339_981_04, 0.652_145_15),
    (0.861_136_3, 0.347_854_85),
];

/// The frame of a cylinder's visible half: the normal facing the viewer
/// and the sideways one (`axis × toward`), both unit vectors, as the
/// shader's `facing_axis` turns a line's cylinder and a prism's ring. A
/// cylinder seen along its axis gets the ring normal of
/// [`super::compact::ring_basis`].
pub fn visible_frame(axis: Vec3, to_viewer: Vec3) -> (Vec3, Vec3) {
    let axis = axis.try_normalize().unwrap_or(Vec3::Y);
    let across = to_viewer - axis * axis.dot(to_viewer);
    let toward = if across.length_squared() >= 1e-12 * to_viewer.length_squared().max(1e-30) {
        across.normalize()
    } else {
        super::compact::ring_basis(axis).0
    };
    (toward, axis.cross(toward))
}

/// The average over a cylinder's projected width of `radiance(n)`, the
/// radiance leaving its surface where the normal is `n`, by the shader's
/// four-point rule.
pub fn across_average(axis: Vec3, to_viewer: Vec3, radiance: impl Fn(Vec3) -> f32) -> f32 {
    let (toward, side) = visible_frame(axis, to_viewer);
    0.5 * ACROSS_NODES
        .iter()
        .map(|&(s, w)| w * radiance((1.0 - s * s).max(0.0).sqrt() * toward + s * side))
        .sum::<f32>()
}

/// The exact average over a cylinder's projected width of the Lambert
/// factor `max(n·L, 0)`, for unit `to_light` `L` (Kajiya and Kay 1989,
/// integrated over the visible half): `|L⊥| · (sin φ + (π − φ) cos φ) / 4`,
/// where `L⊥` is the light direction perpendicular to the axis and `φ` the
/// angle between it and the viewer's. π/4 lit from the viewer, 0 from
/// behind; a strip facing the viewer would show `|L⊥| cos φ`, up to 4/π
/// brighter.
pub fn cylinder_lambert(axis: Vec3, to_viewer: Vec3, to_light: Vec3) -> f32 {
    let (toward, side) = visible_frame(axis, to_viewer);
    let axis = toward.cross(side);
    let across = to_light - axis * axis.dot(to_light);
    let length = across.length();
    if length < 1e-12 {
        return 0.0;
    }
    let phi = (across.dot(toward) / length).clamp(-1.0, 1.0).acos();
    length * (phi.sin() + (PI - phi) * phi.cos()) / 4.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn direction() -> impl Strategy<Value = Vec3> {
        (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0)
            .prop_filter("not zero", |(x, y, z)| x * x + y * y + z * z > 0.01)
            .prop_map(|(x, y, z)| Vec3::new(x, y, z).normalize())
    }

    #[test]
    fn lambert_average_has_the_known_values() {
        let (axis, viewer) = (Vec3::Y, Vec3::Z);
        assert!((cylinder_lambert(axis, viewer, Vec3::Z) - PI / 4.0).abs() < 1e-6);
        assert!(cylinder_lambert(axis, viewer, -Vec3::Z).abs() < 1e-6);
        assert!(cylinder_lambert(axis, viewer, Vec3::Y).abs() < 1e-6);
        // From the side, half the visible width is lit: ∫ cos over a quarter.
        assert!((cylinder_lambert(axis, viewer, Vec3::X) - 0.25).abs() < 1e-6);
    }

    proptest! {
        /// The shader's four normals average the Lambert factor to within
        /// 0.03 of the exact integral (the kink where `n·L` turns negative
        /// is what a four-point rule misses), and a line lit like a strip
        /// facing the viewer would be up to 4/π brighter.
        #[test]
        fn four_normals_average_the_cylinder(axis in direction(), viewer in direction(), light in direction()) {
            let exact = cylinder_lambert(axis, viewer, light);
            let quadrature = across_average(axis, viewer, |n| n.dot(light).max(0.0));
            prop_assert!((quadrature - exact).abs() < 0.03, "{quadrature} vs {exact}");
            let (toward, _) = visible_frame(axis, viewer);
            prop_assert!(toward.dot(light).max(0.0) <= exact * 4.0 / PI + 0.03);
        }
    }
}
