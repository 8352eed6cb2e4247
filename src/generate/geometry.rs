//! Small vector helpers of the grower (directions, frames, bending).

use glam::Vec3;

/// World up (+Y).
pub(crate) const UP: Vec3 = Vec3::Y;

/// The golden angle (radians): the divergence between successive leaves or
/// branches of a spiral phyllotaxis.
pub(crate) const GOLDEN_ANGLE: f32 = 2.399_963_2;

/// The unit vector perpendicular to `axis` closest to `preferred` (any
/// perpendicular when `preferred` is parallel to `axis`). `axis` is unit.
pub(crate) fn perpendicular_toward(axis: Vec3, preferred: Vec3) -> Vec3 {
    (preferred - axis * preferred.dot(axis))
        .try_normalize()
        .unwrap_or_else(|| axis.any_orthonormal_vector())
}

/// The unit direction at angle `polar` from the unit `axis`, turned by
/// `azimuth` around it, azimuth 0 pointing toward `reference`.
pub(crate) fn cone_direction(axis: Vec3, reference: Vec3, polar: f32, azimuth: f32) -> Vec3 {
    let e1 = perpendicular_toward(axis, reference);
    let e2 = axis.cross(e1);
    let (sin_p, cos_p) = polar.sin_cos();
    let (sin_a, cos_a) = azimuth.sin_cos();
    (axis * cos_p + (e1 * cos_a + e2 * sin_a) * sin_p).normalize()
}

/// `dir` pulled toward `pull` by `amount` (0 = unchanged), renormalised.
pub(crate) fn bend(dir: Vec3, pull: Vec3, amount: f32) -> Vec3 {
    (dir + pull * amount).try_normalize().unwrap_or(dir)
}

/// `dir` bent toward (positive `amount`) or away from world up, kept at
/// least ~14° off the vertical so that "sideways" stays defined along a branch.
pub(crate) fn bend_vertically(dir: Vec3, amount: f32) -> Vec3 {
    const MAX_UP: f32 = 0.97;
    let bent = bend(dir, UP, amount);
    if bent.y.abs() <= MAX_UP {
        return bent;
    }
    let flat = Vec3::new(bent.x, 0.0, bent.z)
        .try_normalize()
        .or_else(|| Vec3::new(dir.x, 0.0, dir.z).try_normalize())
        .unwrap_or(Vec3::X);
    flat * (1.0 - MAX_UP * MAX_UP).sqrt() + UP * MAX_UP.copysign(bent.y)
}

/// The horizontal unit vector at `azimuth` radians around +Y (0 = +X).
pub(crate) fn horizontal(azimuth: f32) -> Vec3 {
    let (sin_a, cos_a) = azimuth.sin_cos();
    Vec3::new(cos_a, 0.0, sin_a)
}

/// The direction `angle_from_vertical` radians down from +Y toward `azimuth`.
pub(crate) fn from_vertical(angle_from_vertical: f32, azimuth: f32) -> Vec3 {
    let (sin_v, cos_v) = angle_from_vertical.sin_cos();
    horizontal(azimuth) * sin_v + UP * cos_v
}

/// `vector` rotated by `angle` around the unit `axis` (right-handed).
pub(crate) fn rotate_around(vector: Vec3, axis: Vec3, angle: f32) -> Vec3 {
    let (sin_a, cos_a) = angle.sin_cos();
    vector * cos_a + axis.cross(vector) * sin_a + axis * axis.dot(vector) * (1.0 - cos_a)
}
