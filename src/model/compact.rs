//! The compact GPU layout of a species (render path v2), free of Bevy, and
//! the CPU reference of what its compute pass and vertex shaders do with it
//! (`src/plugin/render/conifer_compact.wgsl`, `conifer_cull.wgsl`).
//!
//! No vertex attributes and no index buffers derived from needles: the
//! vertex shader pulls everything from four storage arrays, 32 bytes a
//! needle or so.
//!
//! * **Needles**, 16 bytes: both ends as three 16-bit codes on the species'
//!   [`PositionGrid`], the error of the needle's original line (`2R`) as a
//!   16-bit logarithmic code rounded up ([`log_encode_at_least`]), and its
//!   parent's error code. Sorted by line-error code descending, so the
//!   needles a view draws as prisms (`e < 2R`) are a prefix. A prism's
//!   radius is half the decoded line error (at most 0.049 % wide), and its
//!   ring is oriented by [`ring_basis`] from the axis alone.
//! * **Original lines**, 4 bytes: needle indices sorted by parent error code
//!   descending, so the lines whose parent error is above the view's are a
//!   prefix.
//! * **Merged lines**, 12 bytes: two needle-end references (needle index
//!   · 2 + 1 at the tip, 24 bits each), the equivalent width (summed needle
//!   side area over length, a 16-bit logarithmic code split over the
//!   references' top bytes), and the error and parent error codes. Sorted by
//!   parent error code descending.
//! * **Wood**: segments as `f32` (32 bytes, sorted by `2·r_max`
//!   descending) and an imported wood mesh on its own grid (12 bytes a
//!   vertex, `u32` indices).
//!
//! ## The cut in code space
//!
//! A view's spatial error `e` becomes the threshold code `c`, the largest
//! code whose value is `≤ e` ([`threshold_code`]). A node is in the cut iff
//! `code(error) ≤ c < code(parent error)`; because codes round errors up and
//! rounding up is monotone, this is exactly the record's cut at
//! `log_decode(c)` ([`LodRecord::cut`]), so every needle is stood for once
//! whatever `c` the GPU computes. A needle is a prism iff `c < code(2R)`.
//! With every array sorted as above, what a view can draw of a tree is a
//! prefix of each array ([`CompactSpecies::prefixes`]): the compute pass
//! finds the prefix lengths by binary search and writes them as indirect
//! draw counts, and the vertex shader keeps the primitives of the prefix
//! whose own interval holds `c` (a binary merge forest has fewer internal
//! nodes above a cut than nodes in it, so a prefix holds at most twice the
//! cut's lines).

use super::gpu_layout::WOOD_LINE_FADE;
use super::metric::line_error;
use super::quantize::{LOG_CODE_MAX, LOG_CODE_MIN, PositionGrid, log_decode, log_encode_at_least, log_encode_nearest};
use super::record::{Cut, LodRecord, NO_PARENT};
use super::{file, metric};
use glam::Vec3;

/// Most needles a compact species holds: a needle-end reference is 24 bits.
pub const MAX_COMPACT_NEEDLES: usize = 1 << 23;

/// Parent error code of a root: above every threshold code.
pub const ROOT_PARENT_CODE: u16 = u16::MAX;

/// The largest threshold code ([`threshold_code`] clamps to it), below
/// [`ROOT_PARENT_CODE`] so that roots are always in reach.
pub const MAX_THRESHOLD_CODE: u16 = u16::MAX - 1;

/// `ln(LOG_CODE_MIN)` as the shaders use it.
pub const LOG_CODE_LN_MIN: f32 = -20.723_267;

/// The ratio of neighbouring logarithmic codes, as a natural logarithm
/// (`ln(LOG_CODE_MAX / LOG_CODE_MIN) / 65534`), as the shaders use it.
pub const LOG_CODE_LN_STEP: f32 = 4.919_002_5e-4;

/// Why a record has no compact layout.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CompactError {
    /// More needles than a 24-bit end reference addresses.
    #[error("the record has {0} needles; the compact GPU layout holds at most 8,388,608")]
    TooManyNeedles(usize),
    /// An error or width above [`LOG_CODE_MAX`], or a position no grid
    /// covers (beyond 65 km, or not finite).
    #[error("the record's {0} are out of the GPU layout's range")]
    OutOfRange(&'static str),
}

/// A species' compact GPU arrays (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct CompactSpecies {
    /// The grid of the needles' ends.
    pub grid: PositionGrid,
    /// `Lmax`: most prism sides.
    pub max_sides: u8,
    /// Four words a needle, sorted by line-error code descending.
    pub needles: Vec<[u32; 4]>,
    /// The record's needle index of each compact needle.
    pub needle_source: Vec<u32>,
    /// Compact needle indices of the original lines that can be in a cut,
    /// sorted by parent error code descending.
    pub original_lines: Vec<u32>,
    /// Three words a merged line that can be in a cut, sorted by parent
    /// error code descending.
    pub merged_lines: Vec<[u32; 3]>,
    /// The record's node id of each merged line.
    pub merged_source: Vec<u32>,
    /// Wood segments `[start, r_start, end, r_end]`, sorted by `2·r_max`
    /// descending.
    pub wood_segments: Vec<[f32; 8]>,
    /// The grid of the wood mesh's positions.
    pub wood_grid: PositionGrid,
    /// Wood mesh vertices: `x | y << 16`, `z`, octahedral normal.
    pub wood_vertices: Vec<[u32; 3]>,
    /// Wood mesh triangles, three vertex indices each.
    pub wood_indices: Vec<u32>,
    /// Smallest and largest merged-line error code (debug colours).
    pub merged_code_range: [u16; 2],
}

/// Bytes of each compact array.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CompactBytes {
    /// Needles (16 bytes each).
    pub needles: u64,
    /// Original-line order (4 bytes each).
    pub original_lines: u64,
    /// Merged lines (12 bytes each).
    pub merged_lines: u64,
    /// Wood segments, wood mesh vertices and indices.
    pub wood: u64,
}

impl CompactBytes {
    /// All of it.
    pub fn total(&self) -> u64 {
        self.needles + self.original_lines + self.merged_lines + self.wood
    }
}

/// How many entries of each sorted array a view at one threshold code can
/// draw from (the indirect draw counts of the compute pass).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Prefixes {
    /// Needles that are prisms (`c < code(2R)`).
    pub prisms: u32,
    /// The original lines to draw from: needles `[prisms, needles)` (the
    /// lines whose own code is `≤ c`) when `original_from_needles`, else
    /// the first `original_lines` of the parent-sorted order (the lines
    /// whose parent code is above `c`), whichever is shorter.
    pub original_lines: u32,
    /// Whether the original lines are the needles after the prisms.
    pub original_from_needles: bool,
    /// Merged lines whose parent error code is above `c`.
    pub merged_lines: u32,
    /// Wood segments that are prisms (`e < 2·r_max`).
    pub wood_prisms: u32,
    /// Wood segments drawn as prisms or lines (`e < 64 · 2·r_max`).
    pub wood_lines: u32,
}

/// A needle-end reference: compact needle `needle`, at its tip or base.
pub fn end_reference(needle: u32, tip: bool) -> u32 {
    needle << 1 | tip as u32
}

/// The largest logarithmic code whose value is `≤ e`, at most
/// [`MAX_THRESHOLD_CODE`]; 0 for NaN, negative or tiny `e`.
pub fn threshold_code(e: f32) -> u16 {
    if e.is_nan() || e < LOG_CODE_MIN {
        return 0;
    }
    if e >= LOG_CODE_MAX {
        return MAX_THRESHOLD_CODE;
    }
    let mut code = log_encode_at_least(e).unwrap_or(MAX_THRESHOLD_CODE);
    if log_decode(code) > e {
        code -= 1;
    }
    code.min(MAX_THRESHOLD_CODE)
}

/// [`threshold_code`] as the compute shader computes it, in `f32` from the
/// logarithm (it may differ from the exact code by one, which moves the
/// cut by 0.049 % of the error and keeps it an exact partition).
pub fn shader_threshold_code(e: f32) -> u16 {
    // NaN fails every comparison: it lands here too.
    if e.is_nan() || e < LOG_CODE_MIN {
        return 0;
    }
    let steps = ((e.ln() - LOG_CODE_LN_MIN) / LOG_CODE_LN_STEP).floor() + 1.0;
    steps.clamp(0.0, MAX_THRESHOLD_CODE as f32) as u16
}

/// A logarithmic code's value as the shaders decode it (`f32`).
pub fn shader_log_decode(code: u32) -> f32 {
    if code == 0 {
        0.0
    } else {
        (LOG_CODE_LN_MIN + (code - 1) as f32 * LOG_CODE_LN_STEP).exp()
    }
}

/// An orthonormal pair perpendicular to the unit `axis` (Duff et al.,
/// *Building an Orthonormal Basis, Revisited*, JCGT 2017), as the shader
/// builds a prism's ring.
pub fn ring_basis(axis: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(axis.z);
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    (
        Vec3::new(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x),
        Vec3::new(b, sign + axis.y * axis.y * a, -axis.y),
    )
}

/// Which ring slot, end (`true` at the tip) and cap vertex `local` of an
/// `Lmax`-slot prism drawn without indices is: the shader's
/// `prism_corner`, in the triangle order and winding of
/// [`super::prism::append_prism`] (side quads, then the base and tip caps).
pub fn prism_corner(local: u32, max_sides: u8) -> (u32, bool, bool) {
    let m = u32::from(max_sides.max(3));
    if local < 6 * m {
        let (quad, j) = (local / 6, local % 6);
        let next = (quad + 1) % m;
        let slot = if matches!(j, 1 | 2 | 4) { next } else { quad };
        return (slot, matches!(j, 2 | 4 | 5), false);
    }
    let t = local - 6 * m;
    let fan = 3 * (m - 2);
    let at_tip = t >= fan;
    let (k, j) = ((t % fan) / 3 + 1, t % 3);
    let slot = match j {
        0 => 0,
        _ if (j == 1) == at_tip => k,
        _ => k + 1,
    };
    (slot, at_tip, true)
}

fn code_at_least(value: f32, what: &'static str) -> Result<u16, CompactError> {
    log_encode_at_least(value.max(0.0)).ok_or(CompactError::OutOfRange(what))
}

fn parent_code(record: &LodRecord, node: u32) -> Result<u16, CompactError> {
    if record.parent(node) == NO_PARENT {
        return Ok(ROOT_PARENT_CODE);
    }
    Ok(code_at_least(record.parent_error(node), "errors")?.min(MAX_THRESHOLD_CODE))
}

impl CompactSpecies {
    /// The compact layout of `record`.
    pub fn build(record: &LodRecord) -> Result<Self, CompactError> {
        let n = record.needle_count();
        if n > MAX_COMPACT_NEEDLES {
            return Err(CompactError::TooManyNeedles(n));
        }
        let grid = PositionGrid::covering(record.needles.iter().flat_map(|x| [x.base, x.tip]))
            .ok_or(CompactError::OutOfRange("needle positions"))?;
        let mut line_codes = Vec::with_capacity(n);
        for needle in &record.needles {
            line_codes.push(code_at_least(line_error(needle.radius), "needle radii")?.min(MAX_THRESHOLD_CODE));
        }
        // Needles by line-error code descending (prisms are a prefix).
        let mut needle_source: Vec<u32> = (0..n as u32).collect();
        needle_source.sort_by_key(|&i| (std::cmp::Reverse(line_codes[i as usize]), i));
        let mut compact_of = vec![0u32; n];
        for (k, &i) in needle_source.iter().enumerate() {
            compact_of[i as usize] = k as u32;
        }
        let mut needles = Vec::with_capacity(n);
        let mut original = Vec::new();
        for (k, &i) in needle_source.iter().enumerate() {
            let needle = &record.needles[i as usize];
            let [bx, by, bz] = grid.encode(needle.base).map(u32::from);
            let [tx, ty, tz] = grid.encode(needle.tip).map(u32::from);
            let own = line_codes[i as usize];
            let parent = parent_code(record, i)?;
            needles.push([
                bx | by << 16,
                bz | tx << 16,
                ty | tz << 16,
                u32::from(own) | u32::from(parent) << 16,
            ]);
            if parent > own {
                original.push((parent, k as u32));
            }
        }
        original.sort_by_key(|&(parent, k)| (std::cmp::Reverse(parent), k));
        let mut merged = Vec::new();
        let mut merged_code_range = [u16::MAX, 0];
        for (m, line) in record.merged.iter().enumerate() {
            let node = (n + m) as u32;
            let own = code_at_least(line.error, "errors")?.min(MAX_THRESHOLD_CODE);
            merged_code_range = [merged_code_range[0].min(own), merged_code_range[1].max(own)];
            let parent = parent_code(record, node)?;
            if parent <= own {
                continue;
            }
            let [(a, _), (b, _)] = record.node_ends(node);
            let length = a.distance(b).max(1e-9);
            let width = log_encode_nearest((record.node_needle_area(node) / length).min(LOG_CODE_MAX))
                .ok_or(CompactError::OutOfRange("line widths"))?;
            let end = |e: u32| end_reference(compact_of[(e / 2) as usize], e % 2 == 1);
            let words = [
                end(line.ends[0]) | u32::from(width & 0xff) << 24,
                end(line.ends[1]) | u32::from(width >> 8) << 24,
                u32::from(own) | u32::from(parent) << 16,
            ];
            merged.push((parent, node, words));
        }
        merged.sort_by_key(|&(parent, node, _)| (std::cmp::Reverse(parent), node));
        if merged_code_range[0] > merged_code_range[1] {
            merged_code_range = [0, 0];
        }
        let mut wood_segments: Vec<[f32; 8]> = record
            .wood
            .iter()
            .filter(|w| w.is_valid())
            .map(|w| {
                [
                    w.start.x,
                    w.start.y,
                    w.start.z,
                    w.start_radius,
                    w.end.x,
                    w.end.y,
                    w.end.z,
                    w.end_radius,
                ]
            })
            .collect();
        wood_segments.sort_by(|a, b| b[3].max(b[7]).total_cmp(&a[3].max(a[7])));
        let mesh = &record.wood_mesh;
        let wood_grid = if mesh.positions.is_empty() {
            PositionGrid {
                origin: Vec3::ZERO,
                step: 1.0,
            }
        } else {
            PositionGrid::covering(mesh.positions.iter().copied()).ok_or(CompactError::OutOfRange("wood mesh"))?
        };
        let wood_vertices = mesh
            .positions
            .iter()
            .zip(&mesh.normals)
            .map(|(&p, &normal)| {
                let [x, y, z] = wood_grid.encode(p).map(u32::from);
                [x | y << 16, z, u32::from_le_bytes(file::encode_normal(normal))]
            })
            .collect();
        Ok(Self {
            grid,
            max_sides: record.max_sides,
            needles,
            needle_source,
            original_lines: original.into_iter().map(|(_, k)| k).collect(),
            merged_source: merged.iter().map(|&(_, node, _)| node).collect(),
            merged_lines: merged.into_iter().map(|(_, _, words)| words).collect(),
            wood_segments,
            wood_grid,
            wood_vertices,
            wood_indices: mesh.indices.clone(),
            merged_code_range,
        })
    }

    /// Bytes of the arrays.
    pub fn bytes(&self) -> CompactBytes {
        CompactBytes {
            needles: 16 * self.needles.len() as u64,
            original_lines: 4 * self.original_lines.len() as u64,
            merged_lines: 12 * self.merged_lines.len() as u64,
            wood: 32 * self.wood_segments.len() as u64
                + 12 * self.wood_vertices.len() as u64
                + 4 * self.wood_indices.len() as u64,
        }
    }

    /// Line-error code (`2R`, rounded up) of compact needle `k`.
    pub fn needle_line_code(&self, k: u32) -> u16 {
        (self.needles[k as usize][3] & 0xffff) as u16
    }

    /// Parent error code of compact needle `k`'s original line.
    pub fn needle_parent_code(&self, k: u32) -> u16 {
        (self.needles[k as usize][3] >> 16) as u16
    }

    /// Both ends of compact needle `k`, as the shader decodes them.
    pub fn needle_ends(&self, k: u32) -> [Vec3; 2] {
        let [w0, w1, w2, _] = self.needles[k as usize];
        let lo = |w: u32| (w & 0xffff) as u16;
        let hi = |w: u32| (w >> 16) as u16;
        [
            self.grid.decode([lo(w0), hi(w0), lo(w1)]),
            self.grid.decode([hi(w1), lo(w2), hi(w2)]),
        ]
    }

    /// The radius the shader gives compact needle `k`'s prism: half its
    /// decoded line error.
    pub fn needle_radius(&self, k: u32) -> f32 {
        0.5 * shader_log_decode(u32::from(self.needle_line_code(k)))
    }

    /// The end a reference points at.
    pub fn end_position(&self, reference: u32) -> Vec3 {
        self.needle_ends((reference & 0x00ff_ffff) >> 1)[(reference & 1) as usize]
    }

    /// `(error code, parent error code)` of merged line `m`.
    pub fn merged_codes(&self, m: usize) -> (u16, u16) {
        let w = self.merged_lines[m][2];
        ((w & 0xffff) as u16, (w >> 16) as u16)
    }

    /// Equivalent width of merged line `m`, metres, as the shader decodes it.
    pub fn merged_width(&self, m: usize) -> f32 {
        let [a, b, _] = self.merged_lines[m];
        shader_log_decode(a >> 24 | (b >> 24) << 8)
    }

    /// The prefix of every array a view at threshold code `code` and spatial
    /// error `e` draws from (binary searches, as the compute pass does).
    pub fn prefixes(&self, code: u16, e: f32) -> Prefixes {
        let prisms = self.needles.partition_point(|w| (w[3] & 0xffff) as u16 > code);
        let original = self
            .original_lines
            .partition_point(|&k| self.needle_parent_code(k) > code);
        let merged = self.merged_lines.partition_point(|w| (w[2] >> 16) as u16 > code);
        let wood_error = |w: &[f32; 8]| line_error(w[3].max(w[7]));
        let after_prisms = self.needles.len() - prisms;
        Prefixes {
            prisms: prisms as u32,
            original_lines: original.min(after_prisms) as u32,
            original_from_needles: after_prisms < original,
            merged_lines: merged as u32,
            wood_prisms: self.wood_segments.partition_point(|w| e < wood_error(w)) as u32,
            wood_lines: self
                .wood_segments
                .partition_point(|w| e < WOOD_LINE_FADE * wood_error(w)) as u32,
        }
    }

    /// What the vertex shaders draw at threshold code `code`: the prefixes'
    /// primitives whose own interval holds `code`, as a [`Cut`] in the
    /// record's needle and node ids, prisms with the side count the shader
    /// gives them at spatial error `e`.
    pub fn drawn(&self, code: u16, e: f32) -> Cut {
        let p = self.prefixes(code, e);
        let mut cut = Cut::default();
        for k in 0..p.prisms {
            let radius = self.needle_radius(k);
            let sides = metric::prism_sides(metric::relative_error(e, radius), self.max_sides);
            cut.prisms.push((self.needle_source[k as usize], sides));
        }
        let original: Vec<u32> = if p.original_from_needles {
            (p.prisms..p.prisms + p.original_lines).collect()
        } else {
            self.original_lines[..p.original_lines as usize].to_vec()
        };
        for k in original {
            if self.needle_line_code(k) <= code && code < self.needle_parent_code(k) {
                cut.original_lines.push(self.needle_source[k as usize]);
            }
        }
        for m in 0..p.merged_lines as usize {
            if self.merged_codes(m).0 <= code {
                cut.merged_lines.push(self.merged_source[m]);
            }
        }
        cut
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};
    use crate::model::{BakeOptions, bake};

    fn record(needles: usize, seed: u64) -> LodRecord {
        let options = GenerateOptions {
            seed,
            target_needles: Some(needles),
        };
        bake(&generate(Species::ScotsPine, &options), &BakeOptions::default(), &()).expect("bake")
    }

    #[test]
    fn shader_constants_match_the_code() {
        assert!((LOG_CODE_LN_MIN - LOG_CODE_MIN.ln()).abs() < 1e-5);
        let step = ((f64::from(LOG_CODE_MAX) / f64::from(LOG_CODE_MIN)).ln() / 65534.0) as f32;
        assert!((LOG_CODE_LN_STEP / step - 1.0).abs() < 1e-6, "{step}");
        for code in [1u16, 1000, 30_000, 50_000, 65_534] {
            let exact = log_decode(code);
            assert!((shader_log_decode(u32::from(code)) / exact - 1.0).abs() < 1e-3);
        }
    }

    #[test]
    fn threshold_codes_bracket_the_error() {
        for e in [1e-8f32, 3.3e-6, 1e-4, 0.0123, 0.5, 7.0, 123.0] {
            let c = threshold_code(e);
            assert!(log_decode(c) <= e && e < log_decode(c + 1), "{e}");
            assert!(shader_threshold_code(e).abs_diff(c) <= 1, "{e}");
        }
        assert_eq!(threshold_code(f32::NAN), 0);
        assert_eq!(threshold_code(-1.0), 0);
        assert_eq!(threshold_code(f32::INFINITY), MAX_THRESHOLD_CODE);
        assert_eq!(shader_threshold_code(f32::NAN), 0);
        assert_eq!(shader_threshold_code(f32::INFINITY), MAX_THRESHOLD_CODE);
    }

    #[test]
    fn prism_corners_follow_the_cpu_tessellation() {
        use crate::model::gpu_layout::{CAP_BIT, SLOT_BITS, TIP_BIT, prism_buffers};
        for max_sides in [3u8, 4, 7, 8, 12] {
            let mut record = record(200, 3);
            record.max_sides = max_sides;
            let buffers = prism_buffers(&record).unwrap();
            let per_prism = buffers.indices.len() / record.needle_count();
            assert_eq!(per_prism as u32, 12 * u32::from(max_sides) - 12);
            for (local, &index) in buffers.indices[..per_prism].iter().enumerate() {
                let code = buffers.codes[index as usize];
                let expected = (code & ((1 << SLOT_BITS) - 1), code & TIP_BIT != 0, code & CAP_BIT != 0);
                assert_eq!(
                    prism_corner(local as u32, max_sides),
                    expected,
                    "Lmax {max_sides}, vertex {local}"
                );
            }
        }
    }

    #[test]
    fn ring_basis_is_orthonormal() {
        for axis in [
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.3, -0.4, 0.5).normalize(),
        ] {
            let (u, v) = ring_basis(axis);
            assert!((u.length() - 1.0).abs() < 1e-5 && (v.length() - 1.0).abs() < 1e-5);
            assert!(u.dot(v).abs() < 1e-5 && u.dot(axis).abs() < 1e-5 && v.dot(axis).abs() < 1e-5);
        }
    }

    #[test]
    fn drawn_set_is_the_record_cut_at_the_decoded_threshold() {
        let record = record(3000, 5);
        let compact = CompactSpecies::build(&record).unwrap();
        let ranges = record.part_ranges();
        let top = ranges.merged_lines.map_or(ranges.original_lines.max, |r| r.max);
        let mut e = ranges.cylinders.min * 0.5;
        while e < top * 4.0 {
            for code in [threshold_code(e), shader_threshold_code(e)] {
                let threshold = log_decode(code);
                let drawn = compact.drawn(code, e).sorted();
                let mut expected = record.cut(threshold);
                // Side counts follow the view's own error.
                for (needle, sides) in &mut expected.prisms {
                    let radius =
                        compact.needle_radius(compact.needle_source.iter().position(|s| s == needle).unwrap() as u32);
                    *sides = metric::prism_sides(metric::relative_error(e, radius), record.max_sides);
                }
                assert_eq!(drawn, expected.sorted(), "e = {e}");
                assert!(record.coverage(&drawn).iter().all(|&c| c == 1), "e = {e}");
            }
            e *= 1.37;
        }
    }

    #[test]
    fn prefixes_hold_at_most_twice_the_cut() {
        let record = record(4000, 9);
        let compact = CompactSpecies::build(&record).unwrap();
        let ranges = record.part_ranges();
        let top = ranges.merged_lines.map_or(ranges.original_lines.max, |r| r.max);
        let mut e = ranges.cylinders.min * 0.5;
        let mut worst = 0.0f64;
        while e < top * 2.0 {
            let code = threshold_code(e);
            let p = compact.prefixes(code, e);
            let cut = compact.drawn(code, e);
            let drawn = (cut.prisms.len() + cut.original_lines.len() + cut.merged_lines.len()) as f64;
            let processed = f64::from(p.prisms + p.original_lines + p.merged_lines);
            worst = worst.max(processed / drawn.max(1.0));
            e *= 1.21;
        }
        assert!(worst <= 2.0, "prefix / cut = {worst}");
    }

    #[test]
    fn bytes_per_needle_are_compact() {
        let record = record(8000, 2);
        let compact = CompactSpecies::build(&record).unwrap();
        let per_needle = compact.bytes().total() as f64 / record.needle_count() as f64;
        assert!(per_needle <= 36.0, "{per_needle} B/needle");
        // Decoded ends lie within half a grid step of the record's.
        for k in 0..compact.needles.len() as u32 {
            let needle = &record.needles[compact.needle_source[k as usize] as usize];
            let [a, b] = compact.needle_ends(k);
            assert!(a.distance(needle.base) <= compact.grid.step && b.distance(needle.tip) <= compact.grid.step);
            assert!((compact.needle_radius(k) / needle.radius - 1.0).abs() < 2e-3);
        }
    }

    #[test]
    fn too_many_needles_and_bad_positions_are_errors() {
        let mut record = record(200, 1);
        let mut needles = record.needles.clone();
        needles[0].tip = Vec3::new(1e6, 0.0, 0.0);
        record = LodRecord::from_parts(
            record.name.clone(),
            needles,
            record.merged.clone(),
            record.wood.clone(),
            record.wood_mesh.clone(),
            record.material,
            record.max_sides,
            record.bake.clone(),
        )
        .unwrap();
        assert_eq!(
            CompactSpecies::build(&record),
            Err(CompactError::OutOfRange("needle positions"))
        );
    }
}
