//! Flattened fern-like sprays of scale leaves (cypresses): a main axis
//! nodding at its tip, with alternate side branchlets lying in the spray
//! plane, longest at the base. Every piece becomes a foliage site of the
//! spray's group; the scale leaves are placed on them later.

use glam::Vec3;

use super::geometry::{UP, bend, perpendicular_toward, rotate_around};
use super::params::SprayParams;
use super::random::TreeRng;
use super::skeleton::FoliageSite;

/// Pieces of the main axis (its nodding curve).
const AXIS_PIECES: usize = 3;

/// Where a spray starts and what its sites inherit.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SprayStart {
    pub origin: Vec3,
    /// Unit direction of the spray's main axis at its base.
    pub direction: Vec3,
    /// The spray's phyllotaxy group key.
    pub group_key: u32,
    /// Needle survival factor of the shoot it grows on.
    pub weight_scale: f32,
    pub vigor: f32,
    /// Age of the shoot's needles, years.
    pub age: f32,
}

/// Adds the sites of one spray.
pub(crate) fn grow_spray(sites: &mut Vec<FoliageSite>, rng: &mut TreeRng, params: &SprayParams, start: SprayStart) {
    let SprayStart {
        origin,
        direction,
        group_key,
        weight_scale,
        vigor,
        age,
    } = start;
    let length = rng.range(params.length) * vigor.min(1.0);
    let roll = params.roll * rng.signed();
    let normal = rotate_around(perpendicular_toward(direction, UP), direction, roll);
    let side = normal.cross(direction);
    let axis = nodding_axis(origin, direction, side, length, params.droop);
    let mut site = |start: Vec3, end: Vec3, up: Vec3| {
        sites.push(FoliageSite {
            start,
            end,
            up,
            weight: start.distance(end) * weight_scale,
            group_key,
            vigor,
            age,
        });
    };
    for &(start, end, up) in &axis {
        site(start, end, up);
    }
    let piece_length = length / AXIS_PIECES as f32;
    let mut along = params.pinna_spacing * (0.5 + 0.5 * rng.unit());
    let mut left = rng.chance(0.5);
    while along < 0.92 * length {
        let t = along / length;
        let (start, end, up) = axis[((along / piece_length) as usize).min(AXIS_PIECES - 1)];
        let dir = (end - start).normalize_or(direction);
        let base = start + dir * (along % piece_length);
        let pinna_side = if left { side } else { -side };
        let angle = rng.jitter(params.pinna_angle, 0.15);
        let pinna_dir = (dir * angle.cos() + pinna_side * angle.sin()).normalize();
        let pinna_length = length * params.pinna_length * (1.0 - t).powf(0.8) * rng.jitter(1.0, 0.2);
        if pinna_length > 0.003 {
            site(base, base + pinna_dir * pinna_length, up);
        }
        along += rng.jitter(params.pinna_spacing, 0.2);
        left = !left;
    }
}

/// The spray's main axis as `(start, end, plane normal)` pieces, bending
/// out of its plane toward the ground by `droop` radians in all.
fn nodding_axis(
    origin: Vec3,
    direction: Vec3,
    side: Vec3,
    length: f32,
    droop: f32,
) -> [(Vec3, Vec3, Vec3); AXIS_PIECES] {
    let piece = length / AXIS_PIECES as f32;
    let mut pieces = [(origin, origin, UP); AXIS_PIECES];
    let (mut pos, mut dir) = (origin, direction);
    for slot in &mut pieces {
        let normal = dir.cross(side).normalize_or(UP);
        let end = pos + dir * piece;
        *slot = (pos, end, normal);
        pos = end;
        dir = bend(dir, -normal, droop / AXIS_PIECES as f32);
    }
    pieces
}
