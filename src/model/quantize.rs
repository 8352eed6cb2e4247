//! Quantization of what a record stores (formats 4 and 6), so a needle costs
//! 18 bytes on disk and the same codes can feed the GPU.
//!
//! * Needle ends: 16 bits an axis on a [`PositionGrid`] over the prototype's
//!   own box, whose step is a power of two (a few micrometres for a shoot).
//! * Radii and errors: a 16-bit logarithmic code ([`log_decode`]), 0.049 %
//!   apart from 1 nm to 100 km. A radius takes the nearest code; a merged
//!   line's error the smallest code at or above it and at or above its
//!   children's, so "parent error ≥ child error" and with it the exact
//!   partition of every cut survive quantization.
//! * Normals: the 4-byte octahedral code of [`super::file::snap_normal`].
//! * The wood mesh of imported trees: positions on a grid over the mesh
//!   ([`quantize_mesh`]; a tenth of a millimetre for a tree's trunk).
//! * Placements (format 6): the rotation as its three smaller quaternion
//!   components, 20 bits each ([`RotationCode`]); the translation on a
//!   fixed grid of [`TRANSLATION_STEP`] (7.6 µm), 24 bits an axis
//!   ([`TranslationCode`]); the scale as it is. A placement moved by `d`
//!   raises the level-2 errors above it by `2d` (its lines and the ends of
//!   the merged lines over it each move by at most `d`).
//!
//! The bake quantizes its output ([`PrototypeRecord::quantized`]), so writing
//! and reading a baked record is exact, and quantizing twice changes
//! nothing.

use super::file::snap_normal;
use super::merge::MergedLine;
use super::needle::{Needle, bounds};
use super::prism::TriangleMesh;
use super::prototype::{Placement, Prototype, PrototypeRecord};
use super::record::RecordInvalid;
use glam::{Quat, Vec3};

/// Codes a grid spans over the prototype's box, measured from the grid's
/// origin; the codes up to `u16::MAX` are a margin, so that the box of
/// quantized points never needs a coarser step than the one they were
/// quantized on.
const GRID_SPAN_CODES: f32 = 65_531.0;

/// The finest grid step, metres (2⁻⁴⁰ ≈ 0.9 pm): the step of a box with no
/// extent.
const MIN_GRID_STEP: f32 = 9.094_947e-13;

/// Two ulps of an `f32`, relative (2⁻²²).
const F32_GRID_ULPS: f32 = 2.384_185_8e-7;

/// The farthest a stored needle end may lie from its prototype's origin,
/// metres (65 km: grid origins then stay exact in `f32`).
pub const MAX_GRID_COORDINATE: f32 = 65_000.0;

/// Grid origins are multiples of this (2⁻⁸ m ≈ 3.9 mm), so a record
/// stores them as small integers ([`PositionGrid::to_codes`]).
pub const GRID_ORIGIN_UNIT: f32 = 0.003_906_25;

/// A grid of 65,536 positions an axis: `origin + code · step`, with `step`
/// a power of two (the same on every axis), at least two `f32` ulps of the
/// box's coordinates, and `origin` a multiple of both `step` and
/// [`GRID_ORIGIN_UNIT`], so that grid points are exact `f32` values and a
/// grid costs 7 bytes or so to store.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionGrid {
    /// Position of code 0, metres.
    pub origin: Vec3,
    /// Distance between neighbouring codes, metres.
    pub step: f32,
}

impl PositionGrid {
    /// The grid covering `points` (`None` when there are none, one is not
    /// finite, or one lies more than [`MAX_GRID_COORDINATE`] from the origin). Every point quantizes to
    /// within `step / 2` a coordinate of itself.
    pub fn covering(points: impl IntoIterator<Item = Vec3>) -> Option<Self> {
        let (lo, hi) = bounds(points)?;
        if !(lo.is_finite() && hi.is_finite()) || lo.abs().max(hi.abs()).max_element() > MAX_GRID_COORDINATE {
            return None;
        }
        let finest = lo.abs().max(hi.abs()).max_element() * F32_GRID_ULPS;
        let mut step = power_of_two_at_least(((hi - lo).max_element() / GRID_SPAN_CODES).max(finest));
        // The origin snaps down, which widens the span: settle the step.
        loop {
            let unit = step.max(GRID_ORIGIN_UNIT);
            let origin = (lo / unit).floor() * unit;
            let needed = power_of_two_at_least(((hi - origin).max_element() / GRID_SPAN_CODES).max(finest));
            if needed <= step {
                return Some(Self { origin, step });
            }
            step = needed;
        }
    }

    /// Whether the grid can be used: finite origin, finite positive step.
    pub fn is_valid(&self) -> bool {
        self.origin.is_finite() && self.step.is_finite() && self.step > 0.0
    }

    /// The origin in [`GRID_ORIGIN_UNIT`]s, and the step's power of two, as
    /// a record stores them.
    pub fn to_codes(&self) -> ([i32; 3], i8) {
        (
            (self.origin / GRID_ORIGIN_UNIT).round().to_array().map(|c| c as i32),
            self.step.log2().round() as i8,
        )
    }

    /// The grid of [`PositionGrid::to_codes`]' output (`None` for a step
    /// outside 2⁻⁴⁰ … 2²⁰ m).
    pub fn from_codes(origin: [i32; 3], step_exponent: i8) -> Option<Self> {
        if !(-40..=20).contains(&step_exponent) {
            return None;
        }
        Some(Self {
            origin: Vec3::new(origin[0] as f32, origin[1] as f32, origin[2] as f32) * GRID_ORIGIN_UNIT,
            step: 2f32.powi(i32::from(step_exponent)),
        })
    }

    /// The nearest grid point's codes (clamped to the grid).
    pub fn encode(&self, point: Vec3) -> [u16; 3] {
        let codes = ((point - self.origin) / self.step).round();
        codes.to_array().map(|c| c.clamp(0.0, f32::from(u16::MAX)) as u16)
    }

    /// The grid point of `codes`.
    pub fn decode(&self, codes: [u16; 3]) -> Vec3 {
        self.origin + Vec3::new(f32::from(codes[0]), f32::from(codes[1]), f32::from(codes[2])) * self.step
    }

    /// `decode(encode(point))`.
    pub fn snap(&self, point: Vec3) -> Vec3 {
        self.decode(self.encode(point))
    }
}

/// Codes on each side of zero of a rotation component: `2¹⁹ − 1`, so zero
/// and ±1/√2 are exact.
const ROTATION_HALF_CODES: i64 = (1 << 19) - 1;

/// Largest magnitude of a unit quaternion's three smaller components.
const ROTATION_COMPONENT_MAX: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// A unit quaternion in 8 bytes ("smallest three"): which component is the
/// largest in magnitude (2 bits, made positive by negating the quaternion,
/// which is the same rotation) and the other three in order, 20 bits each,
/// `(code − (2¹⁹ − 1)) · (1/√2) / (2¹⁹ − 1)`; the largest is rebuilt as
/// `√(1 − Σ others²)`. Components are 6.7 × 10⁻⁷ apart at most, so a
/// rotation moves a point 1 m away by under 3 µm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RotationCode(pub u64);

impl RotationCode {
    /// The code of the nearest representable rotation (`None` for a
    /// non-finite or zero quaternion). The encoded three components stay
    /// strictly below the rebuilt largest, so decoding and encoding again
    /// gives the same code.
    pub fn encode(rotation: Quat) -> Option<Self> {
        if !rotation.is_finite() || rotation.length_squared() == 0.0 {
            return None;
        }
        let q = rotation.normalize().to_array().map(f64::from);
        let largest = (0..4)
            .max_by(|&a, &b| q[a].abs().total_cmp(&q[b].abs()).then(b.cmp(&a)))
            .expect("four components");
        let sign = if q[largest] < 0.0 { -1.0 } else { 1.0 };
        let mut codes = [0i64; 3];
        for (slot, i) in (0..4).filter(|&i| i != largest).enumerate() {
            let scaled = (sign * q[i] / ROTATION_COMPONENT_MAX * ROTATION_HALF_CODES as f64).round() as i64;
            codes[slot] = scaled.clamp(-ROTATION_HALF_CODES, ROTATION_HALF_CODES);
        }
        // Near ties, rounding may leave a small component at or above the
        // rebuilt largest one: move it one code towards zero until not.
        loop {
            let code = Self::pack(largest, codes);
            let decoded = code.decode().to_array();
            let rebuilt = decoded[largest];
            let offender = (0..4)
                .filter(|&i| i != largest)
                .position(|i| decoded[i].abs() >= rebuilt);
            match offender {
                None => return Some(code),
                Some(slot) => codes[slot] -= codes[slot].signum(),
            }
        }
    }

    fn pack(largest: usize, codes: [i64; 3]) -> Self {
        let mut bits = (largest as u64) << 60;
        for (slot, code) in codes.iter().enumerate() {
            bits |= ((code + ROTATION_HALF_CODES) as u64) << (40 - 20 * slot);
        }
        Self(bits)
    }

    /// The rotation of this code. A code whose three components exceed
    /// unit length (only a corrupt file holds one) gives a quaternion that
    /// is not unit, which [`Placement::is_valid`] refuses.
    pub fn decode(self) -> Quat {
        let largest = (self.0 >> 60 & 3) as usize;
        let mut q = [0f64; 4];
        let mut squares = 0.0;
        for (slot, i) in (0..4).filter(|&i| i != largest).enumerate() {
            let code = (self.0 >> (40 - 20 * slot) & 0xF_FFFF) as i64;
            q[i] = (code - ROTATION_HALF_CODES) as f64 * ROTATION_COMPONENT_MAX / ROTATION_HALF_CODES as f64;
            squares += q[i] * q[i];
        }
        q[largest] = (1.0 - squares).max(0.0).sqrt();
        Quat::from_array(q.map(|c| c as f32))
    }

    /// The code as the record stores it (little-endian).
    pub fn to_bytes(self) -> [u8; 8] {
        self.0.to_le_bytes()
    }

    /// The code of [`RotationCode::to_bytes`]' output.
    pub fn from_bytes(bytes: [u8; 8]) -> Self {
        Self(u64::from_le_bytes(bytes))
    }
}

/// Distance between neighbouring placement translations, metres
/// (2⁻¹⁷ ≈ 7.6 µm: a translation moves by 3.8 µm an axis at most).
pub const TRANSLATION_STEP: f32 = 1.0 / 131_072.0;

/// Largest translation code magnitude (24-bit signed).
const TRANSLATION_CODE_MAX: i32 = (1 << 23) - 1;

/// Farthest a translation may reach on an axis to be stored on the grid
/// (about 64 m); a placement beyond it is stored as `f32`s.
pub const MAX_GRID_TRANSLATION: f32 = TRANSLATION_CODE_MAX as f32 * TRANSLATION_STEP;

/// A translation as three 24-bit signed multiples of [`TRANSLATION_STEP`].
/// Every code decodes to an exact `f32`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TranslationCode(pub [i32; 3]);

impl TranslationCode {
    /// The nearest grid point's code (`None` beyond
    /// [`MAX_GRID_TRANSLATION`] or for a non-finite translation).
    pub fn encode(translation: Vec3) -> Option<Self> {
        let codes = (translation / TRANSLATION_STEP).round();
        if !codes.is_finite() || codes.abs().max_element() > TRANSLATION_CODE_MAX as f32 {
            return None;
        }
        Some(Self(codes.to_array().map(|c| c as i32)))
    }

    /// The grid point.
    pub fn decode(self) -> Vec3 {
        Vec3::from_array(self.0.map(|c| c as f32)) * TRANSLATION_STEP
    }

    /// The code as the record stores it: 3 bytes an axis, little-endian
    /// two's complement.
    pub fn to_bytes(self) -> [u8; 9] {
        let mut bytes = [0u8; 9];
        for (axis, code) in self.0.iter().enumerate() {
            bytes[3 * axis..3 * axis + 3].copy_from_slice(&code.to_le_bytes()[..3]);
        }
        bytes
    }

    /// The code of [`TranslationCode::to_bytes`]' output.
    pub fn from_bytes(bytes: [u8; 9]) -> Self {
        Self(std::array::from_fn(|axis| {
            let b = &bytes[3 * axis..3 * axis + 3];
            // Sign-extend the 24-bit value.
            i32::from_le_bytes([b[0], b[1], b[2], 0]) << 8 >> 8
        }))
    }
}

/// The codes format 6 stores `placement`'s rotation and translation on
/// (the nearest ones); `None` for the identity (stored as a prototype id)
/// and for a placement that keeps its `f32`s (a translation beyond
/// [`MAX_GRID_TRANSLATION`], or a non-finite number).
pub fn placement_codes(placement: &Placement) -> Option<(RotationCode, TranslationCode)> {
    if placement.is_identity() {
        return None;
    }
    RotationCode::encode(placement.rotation).zip(TranslationCode::encode(placement.translation))
}

/// `placement` as format 6 stores it: rotation and translation snapped to
/// their codes ([`placement_codes`]), scale and the rest as they are; the
/// placements without codes stay as they are. Snapping twice changes
/// nothing.
pub fn quantize_placement(placement: &Placement) -> Placement {
    placement_codes(placement).map_or(*placement, |(rotation, translation)| Placement {
        rotation: rotation.decode(),
        translation: translation.decode(),
        ..*placement
    })
}

/// `|a − ±b|`, `b`'s sign aligned with `a`'s (the same rotation either
/// way), in `f64`: for unit quaternions `‖R(a) − R(b)‖ ≤ 2 |a − ±b|`.
pub fn quat_chord(a: Quat, b: Quat) -> f64 {
    let (a, b) = (a.as_dquat(), b.as_dquat());
    let b = if a.dot(b) < 0.0 { -b } else { b };
    (a - b).length()
}

/// The farthest any point within `reach` of its prototype's origin moves
/// when `from` becomes `to` (the same prototype and scale): the
/// translation's move plus `2 |Δq| · scale · reach` ([`quat_chord`]).
pub fn placement_move(from: &Placement, to: &Placement, reach: f32) -> f32 {
    let chord = quat_chord(from.rotation, to.rotation);
    let shift = (from.translation.as_dvec3() - to.translation.as_dvec3()).length();
    (shift + 2.0 * chord * f64::from(from.scale) * f64::from(reach)) as f32
}

/// The smallest power of two ≥ `x` (at least [`MIN_GRID_STEP`]).
fn power_of_two_at_least(x: f32) -> f32 {
    if x.is_nan() || x <= MIN_GRID_STEP {
        return MIN_GRID_STEP;
    }
    let mut step = 2f32.powi(x.log2().ceil() as i32);
    while step < x {
        step *= 2.0;
    }
    while step * 0.5 >= x {
        step *= 0.5;
    }
    step
}

/// Smallest non-zero value of the logarithmic code, metres.
pub const LOG_CODE_MIN: f32 = 1e-9;
/// Largest value of the logarithmic code, metres.
pub const LOG_CODE_MAX: f32 = 1e5;

fn log_step() -> f64 {
    (f64::from(LOG_CODE_MAX).ln() - f64::from(LOG_CODE_MIN).ln()) / f64::from(u16::MAX - 1)
}

/// The value of a logarithmic code: 0 for code 0, else
/// `LOG_CODE_MIN · r^(code − 1)` with `r = (LOG_CODE_MAX/LOG_CODE_MIN)^(1/65534)`
/// (neighbouring codes 0.049 % apart). Strictly increasing in `code`.
pub fn log_decode(code: u16) -> f32 {
    // Every code's value, computed once (256 KiB): decoding is in the
    // inner loops of the compact layout's build.
    static VALUES: std::sync::OnceLock<Box<[f32]>> = std::sync::OnceLock::new();
    VALUES.get_or_init(|| (0..=u16::MAX).map(log_value).collect())[usize::from(code)]
}

/// [`log_decode`] computed.
fn log_value(code: u16) -> f32 {
    if code == 0 {
        return 0.0;
    }
    (f64::from(LOG_CODE_MIN).ln() + f64::from(code - 1) * log_step()).exp() as f32
}

/// The code whose value is nearest to `value` in ratio (0 for 0; `None`
/// for NaN, a negative value or one above [`LOG_CODE_MAX`]). A positive
/// value never gets code 0.
pub fn log_encode_nearest(value: f32) -> Option<u16> {
    let code = log_code_near(value)?;
    if code == 0 {
        return Some(0);
    }
    // The nearer of the neighbours, compared in ratio.
    let ratio = |c: u16| (f64::from(log_decode(c)) / f64::from(value)).ln().abs();
    let mut best = code;
    for candidate in [code.saturating_sub(1).max(1), code.saturating_add(1)] {
        if ratio(candidate) < ratio(best) {
            best = candidate;
        }
    }
    Some(best)
}

/// The smallest code whose value is ≥ `value` (`None` for NaN, a negative
/// value or one above [`LOG_CODE_MAX`]).
pub fn log_encode_at_least(value: f32) -> Option<u16> {
    let mut code = log_code_near(value)?;
    while code > 0 && log_decode(code - 1) >= value {
        code -= 1;
    }
    while log_decode(code) < value {
        code = code.checked_add(1)?;
    }
    Some(code)
}

/// A code within one of the answer, from the logarithm.
fn log_code_near(value: f32) -> Option<u16> {
    if !(0.0..=LOG_CODE_MAX).contains(&value) {
        return None;
    }
    if value == 0.0 {
        return Some(0);
    }
    if value <= LOG_CODE_MIN {
        return Some(1);
    }
    let steps = (f64::from(value).ln() - f64::from(LOG_CODE_MIN).ln()) / log_step();
    Some((steps.round() as u32 + 1).min(u32::from(u16::MAX)) as u16)
}

/// A needle as the record stores it: ends on `grid`, radius on the
/// logarithmic code, normal on the octahedral code. A needle whose ends
/// would meet gets its tip one step away along its longest axis.
pub fn quantize_needle(needle: &Needle, grid: &PositionGrid) -> Option<Needle> {
    let base = grid.encode(needle.base);
    let mut tip = grid.encode(needle.tip);
    if tip == base {
        let d = needle.tip - needle.base;
        let axis = d.abs().max_position();
        tip[axis] = if d[axis] >= 0.0 && tip[axis] < u16::MAX {
            tip[axis] + 1
        } else {
            tip[axis].saturating_sub(1)
        };
        if tip == base {
            tip[axis] += 1;
        }
    }
    let radius = log_decode(log_encode_nearest(needle.radius)?.max(1));
    Some(Needle {
        base: grid.decode(base),
        tip: grid.decode(tip),
        radius,
        normal: snap_normal(needle.normal),
        group: needle.group,
    })
}

/// The grid a prototype's needles are stored on: its needles' box.
pub fn prototype_grid(needles: &[Needle]) -> Option<PositionGrid> {
    PositionGrid::covering(needles.iter().flat_map(|n| [n.base, n.tip]))
}

/// Merged lines with their errors as stored, and how much each was raised.
struct QuantizedLines {
    lines: Vec<MergedLine>,
    /// `stored error − baked error` of each line.
    raised: Vec<f32>,
}

/// Errors of merged lines as stored: each the smallest code at or above its
/// error raised by its children's own raise (a merged line's error bounds
/// the distance to a child's line plus the child's error, so a child whose
/// error grew by `d` needs its parent's to grow by `d` too), and at or above
/// its children's stored errors. `child(c, raised)` gives a child's stored
/// error and raise (`raised`: the lines already done).
fn quantize_errors(
    lines: &[MergedLine],
    first_id: u32,
    child: impl Fn(u32, &[f32]) -> (f32, f32),
) -> Result<QuantizedLines, RecordInvalid> {
    let mut out = QuantizedLines {
        lines: Vec::with_capacity(lines.len()),
        raised: Vec::with_capacity(lines.len()),
    };
    for line in lines {
        let (mut floor, mut raise) = (0.0f32, 0.0f32);
        for c in line.children {
            if c >= first_id + out.lines.len() as u32 {
                return Err(RecordInvalid::BadReference(out.lines.len()));
            }
            let (error, raised) = child(c, &out.raised);
            floor = floor.max(error);
            raise = raise.max(raised);
        }
        let wanted = floor.max(line.error + raise);
        let code = log_encode_at_least(wanted).ok_or(RecordInvalid::NonFinite("merged line errors (above 100 km)"))?;
        let error = log_decode(code);
        out.raised.push((error - line.error).max(0.0));
        out.lines.push(MergedLine { error, ..*line });
    }
    Ok(out)
}

/// `mesh` with its positions on the grid over them, as format 4 stores it
/// (normals on their octahedral code). `None` when a position lies beyond
/// [`MAX_GRID_COORDINATE`] or is not finite.
pub fn quantize_mesh(mesh: &TriangleMesh) -> Option<TriangleMesh> {
    quantize_mesh_on_grid(mesh).map(|(mesh, _)| mesh)
}

/// [`quantize_mesh`], and the grid used (a unit grid for a mesh without
/// positions).
fn quantize_mesh_on_grid(mesh: &TriangleMesh) -> Option<(TriangleMesh, PositionGrid)> {
    let normals = mesh.normals.iter().map(|&n| snap_normal(n)).collect();
    let grid = if mesh.positions.is_empty() {
        PositionGrid {
            origin: Vec3::ZERO,
            step: 1.0,
        }
    } else {
        PositionGrid::covering(mesh.positions.iter().copied())?
    };
    Some((
        TriangleMesh {
            positions: mesh.positions.iter().map(|&p| grid.snap(p)).collect(),
            normals,
            indices: mesh.indices.clone(),
        },
        grid,
    ))
}

/// A quantized record and the grids its positions lie on: one per
/// prototype, and the wood mesh's.
pub(crate) struct QuantizedRecord {
    pub record: PrototypeRecord,
    pub prototype_grids: Vec<PositionGrid>,
    pub mesh_grid: PositionGrid,
}

impl PrototypeRecord {
    /// The record as the file stores it: needles on their prototype's
    /// [`PositionGrid`], radii and errors on the logarithmic code (errors
    /// rounded up, never below a child's), normals on the octahedral code.
    /// The wood mesh's positions go on their grid ([`quantize_mesh`]);
    /// placements on their codes ([`quantize_placement`], level-2 errors
    /// raised by twice how far each moved); wood segments are kept as they
    /// are.
    /// Quantizing a quantized record returns it unchanged.
    pub fn quantized(&self) -> Result<PrototypeRecord, RecordInvalid> {
        Ok(self.quantized_on_grids()?.record)
    }

    /// [`PrototypeRecord::quantized`], with the grids it used (the record
    /// file stores the codes on these).
    pub(crate) fn quantized_on_grids(&self) -> Result<QuantizedRecord, RecordInvalid> {
        let mut prototypes = Vec::with_capacity(self.prototypes.len());
        let mut prototype_grids = Vec::with_capacity(self.prototypes.len());
        for (k, prototype) in self.prototypes.iter().enumerate() {
            let problem = |problem: RecordInvalid| RecordInvalid::Prototype {
                prototype: k,
                problem: Box::new(problem),
            };
            let grid = prototype_grid(&prototype.needles).ok_or(problem(RecordInvalid::NonFinite(
                "needle ends (more than 65 km from the prototype's origin)",
            )))?;
            let needles = prototype
                .needles
                .iter()
                .map(|n| quantize_needle(n, &grid))
                .collect::<Option<Vec<_>>>()
                .ok_or(problem(RecordInvalid::NonFinite("needle radii (above 100 km)")))?;
            let n = needles.len() as u32;
            let quantized = quantize_errors(&prototype.merged, n, |c, raised| {
                if c < n {
                    (super::metric::line_error(needles[c as usize].radius), 0.0)
                } else {
                    let k = (c - n) as usize;
                    (0.0, raised[k])
                }
            })
            .map_err(problem)?;
            // A merged child's stored error is its own: the raise carries it.
            let root_raise = quantized.raised.last().copied().unwrap_or(0.0);
            prototypes.push((
                Prototype {
                    needles,
                    merged: quantized.lines,
                },
                root_raise,
            ));
            prototype_grids.push(grid);
        }
        let placements: Vec<Placement> = self.placements.iter().map(quantize_placement).collect();
        // How far each prototype's needle ends reach from its origin.
        let reaches: Vec<f32> = prototypes
            .iter()
            .map(|(prototype, _)| {
                prototype
                    .needles
                    .iter()
                    .flat_map(|n| [n.base.length(), n.tip.length()])
                    .fold(0.0, f32::max)
            })
            .collect();
        let placed = placements.len() as u32;
        let placed_child = |p: u32| -> (f32, f32) {
            let (baked, stored) = (&self.placements[p as usize], &placements[p as usize]);
            let k = stored.prototype as usize;
            prototypes.get(k).map_or((0.0, 0.0), |(prototype, raise)| {
                let moved = placement_move(baked, stored, reaches[k]);
                (
                    prototype.node_error(prototype.root()) * stored.scale,
                    raise * stored.scale + 2.0 * moved,
                )
            })
        };
        let tree = quantize_errors(&self.tree_merged, placed, |c, raised| {
            if c < placed {
                placed_child(c)
            } else {
                (0.0, raised[(c - placed) as usize])
            }
        })?;
        let prototypes: Vec<Prototype> = prototypes.into_iter().map(|(p, _)| p).collect();
        let tree_merged = tree.lines;
        let (wood_mesh, mesh_grid) = quantize_mesh_on_grid(&self.wood_mesh).ok_or(RecordInvalid::BadWoodMesh)?;
        let mut record = PrototypeRecord::from_parts(
            self.name.clone(),
            prototypes,
            placements,
            tree_merged,
            self.wood.clone(),
            wood_mesh,
            self.material,
            self.max_sides,
            self.bake.clone(),
        )?;
        // Baked from the needles as stored: quantizing keeps it.
        record.impostor = self.impostor.clone();
        record.line_calibration = self.line_calibration;
        Ok(QuantizedRecord {
            record,
            prototype_grids,
            mesh_grid,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn log_codes_are_strictly_increasing_and_fine() {
        let mut previous = log_decode(0);
        for code in 1..=u16::MAX {
            let value = log_decode(code);
            assert!(value > previous, "code {code}");
            if code > 1 {
                assert!(value / previous < 1.000_5, "code {code}: {}", value / previous);
            }
            previous = value;
        }
        assert!((log_decode(1) - LOG_CODE_MIN).abs() < 1e-15);
        assert!((log_decode(u16::MAX) / LOG_CODE_MAX - 1.0).abs() < 1e-4);
    }

    #[test]
    fn codes_of_code_values_are_themselves() {
        for code in (0..=u16::MAX).step_by(7).chain([1, 2, u16::MAX - 1, u16::MAX]) {
            let value = log_decode(code);
            assert_eq!(log_encode_nearest(value), Some(code));
            assert_eq!(log_encode_at_least(value), Some(code));
        }
        assert_eq!(log_encode_at_least(f32::NAN), None);
        assert_eq!(log_encode_at_least(-1.0), None);
        assert_eq!(log_encode_at_least(2e5), None);
        assert_eq!(log_encode_nearest(0.0), Some(0));
        assert_eq!(log_encode_nearest(1e-12), Some(1));
    }

    #[test]
    fn power_of_two_steps() {
        assert_eq!(power_of_two_at_least(0.3), 0.5);
        assert_eq!(power_of_two_at_least(0.5), 0.5);
        assert_eq!(power_of_two_at_least(0.500_001), 1.0);
        assert_eq!(power_of_two_at_least(0.0), MIN_GRID_STEP);
        assert_eq!(power_of_two_at_least(f32::NAN), MIN_GRID_STEP);
    }

    #[test]
    fn rotation_codes_keep_exact_rotations_and_refuse_non_finite_ones() {
        for q in [
            Quat::IDENTITY,
            Quat::from_rotation_y(std::f32::consts::PI),
            Quat::from_xyzw(0.5, 0.5, 0.5, 0.5),
            Quat::from_xyzw(
                0.0,
                std::f32::consts::FRAC_1_SQRT_2,
                0.0,
                std::f32::consts::FRAC_1_SQRT_2,
            ),
        ] {
            let code = RotationCode::encode(q).unwrap();
            let decoded = code.decode();
            assert!(quat_chord(decoded, q) < 2e-6, "{q} vs {decoded}");
            assert_eq!(RotationCode::encode(decoded), Some(code));
            assert_eq!(RotationCode::from_bytes(code.to_bytes()), code);
        }
        assert_eq!(RotationCode::encode(Quat::IDENTITY).unwrap().decode(), Quat::IDENTITY);
        assert_eq!(RotationCode::encode(Quat::from_xyzw(f32::NAN, 0.0, 0.0, 1.0)), None);
        assert_eq!(RotationCode::encode(Quat::from_xyzw(0.0, 0.0, 0.0, 0.0)), None);
        // Three components at their largest code are beyond unit length: the
        // rebuilt quaternion is not a unit one.
        let corrupt = RotationCode(u64::MAX >> 2).decode();
        assert!((corrupt.length() - 1.0).abs() > 0.1, "{corrupt}");
    }

    #[test]
    fn translation_codes_are_24_bit_signed() {
        for t in [
            Vec3::ZERO,
            Vec3::new(-0.001, 12.5, 63.9),
            Vec3::splat(-MAX_GRID_TRANSLATION),
            Vec3::splat(MAX_GRID_TRANSLATION),
        ] {
            let code = TranslationCode::encode(t).unwrap();
            assert_eq!(TranslationCode::from_bytes(code.to_bytes()), code);
            assert!((code.decode() - t).abs().max_element() <= TRANSLATION_STEP * 0.5);
            assert_eq!(TranslationCode::encode(code.decode()), Some(code));
        }
        assert_eq!(TranslationCode::encode(Vec3::new(0.0, 64.1, 0.0)), None);
        assert_eq!(TranslationCode::encode(Vec3::new(f32::INFINITY, 0.0, 0.0)), None);
        // Beyond the grid a placement keeps its translation (and rotation).
        let far = Placement {
            translation: Vec3::new(100.0, 0.0, 0.0),
            rotation: Quat::from_rotation_z(0.3),
            ..Placement::identity(0)
        };
        assert_eq!(quantize_placement(&far), far);
    }

    proptest! {
        #[test]
        fn rotation_codes_are_within_micro_radians_and_stable(q in prop::array::uniform4(-1.0f32..1.0)) {
            let q = Quat::from_array(q);
            prop_assume!(q.length() > 0.1);
            let q = q.normalize();
            let code = RotationCode::encode(q).unwrap();
            let decoded = code.decode();
            prop_assert!((decoded.length() - 1.0).abs() < 1e-6);
            // The angle between them is about twice the chord.
            prop_assert!(quat_chord(decoded, q) < 2e-6, "{}", quat_chord(decoded, q));
            prop_assert_eq!(RotationCode::encode(decoded), Some(code));
        }

        #[test]
        fn placement_moves_bound_how_far_points_move(
            q in prop::array::uniform4(-1.0f32..1.0),
            t in prop::array::uniform3(-60.0f32..60.0),
            scale in 0.1f32..5.0,
            points in prop::collection::vec(prop::array::uniform3(-1.0f32..1.0), 1..20),
        ) {
            let q = Quat::from_array(q);
            prop_assume!(q.length() > 0.1);
            let placement = Placement {
                rotation: q.normalize(),
                translation: Vec3::from(t),
                scale,
                ..Placement::identity(0)
            };
            let snapped = quantize_placement(&placement);
            prop_assert_eq!(quantize_placement(&snapped), snapped);
            let points: Vec<Vec3> = points.into_iter().map(Vec3::from).collect();
            let reach = points.iter().map(|p| p.length()).fold(0.0, f32::max);
            let bound = placement_move(&placement, &snapped, reach);
            // A few micrometres, and f32 rounding of the placed points aside,
            // no point moves further.
            prop_assert!(bound < 2e-5 * (1.0 + scale), "{}", bound);
            for p in points {
                let moved = placement.place_point(p).distance(snapped.place_point(p));
                prop_assert!(moved <= bound + 2e-5, "{} > {}", moved, bound);
            }
        }

        #[test]
        fn log_codes_bound_their_values(value in 1e-9f32..1e5) {
            let up = log_encode_at_least(value).unwrap();
            prop_assert!(log_decode(up) >= value);
            prop_assert!(up == 0 || log_decode(up - 1) < value);
            let near = log_encode_nearest(value).unwrap();
            let ratio = log_decode(near) / value;
            prop_assert!((0.999_75..=1.000_25).contains(&ratio), "{}", ratio);
        }

        #[test]
        fn grids_hold_their_points_and_snapping_is_stable(
            points in prop::collection::vec(prop::array::uniform3(-30.0f32..30.0), 1..40),
            spread in 1e-4f32..1.0,
        ) {
            let points: Vec<Vec3> = points.iter().map(|p| Vec3::from(*p) * spread).collect();
            let grid = PositionGrid::covering(points.iter().copied()).unwrap();
            prop_assert!(grid.is_valid());
            let (origin, exponent) = grid.to_codes();
            prop_assert_eq!(PositionGrid::from_codes(origin, exponent), Some(grid));
            let snapped: Vec<Vec3> = points.iter().map(|&p| grid.snap(p)).collect();
            for (p, s) in points.iter().zip(&snapped) {
                // Half a step, plus the rounding of `p − origin` in f32.
                let slack = Vec3::splat(grid.step * 0.5 + p.abs().max_element() * 1e-6);
                prop_assert!((*p - *s).abs().cmple(slack).all(), "{} vs {}", p, s);
            }
            // The grid of the snapped points snaps them to themselves.
            let again = PositionGrid::covering(snapped.iter().copied()).unwrap();
            for s in &snapped {
                prop_assert_eq!(again.snap(*s), *s);
            }
        }
    }
}
