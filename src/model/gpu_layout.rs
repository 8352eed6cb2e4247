//! GPU-ready arrays of a record, free of Bevy, and the CPU reference of
//! what the vertex shader (`conifer_lod.wgsl`) does with them.
//!
//! All instances of a species share these buffers: the cut is chosen per
//! vertex on the GPU from the instance's spatial error, using the fact that
//! node `k` is in the cut at `e` iff `error(k) ≤ e < parent_error(k)`.
//!
//! * **Lines** (a `LineList`): every original and merged line, two vertices
//!   each, with `[error, parent_error, width, kind]` per vertex, where
//!   `width` is the line's equivalent width (`2R` for an original line, the
//!   summed side area of its needles over its length for a merged line).
//! * **Prisms** (a `TriangleList`): every needle as an `Lmax`-slot prism
//!   whose vertices carry only a code (needle index, ring slot, end, cap);
//!   the needle's cylinder comes from a storage buffer. For `m < Lmax`
//!   sides, slot `k` moves to corner `⌊k·m/Lmax⌋`, which collapses the
//!   unused side quads and cap triangles to zero area and leaves exactly
//!   the `m`-sided prism of [`super::prism::append_prism`].
//!   A prism is drawn while `e < 2R` (below its line's error).

use super::metric::{line_error, prism_sides, relative_error};
use super::needle::{Needle, WoodSegment};
use super::prism::{TriangleMesh, append_prism};
use super::record::LodRecord;
use glam::Vec3;
use std::f32::consts::TAU;

/// `kind` of an original line in [`LineBuffers::lod`].
pub const KIND_ORIGINAL_LINE: f32 = 0.0;
/// `kind` of a merged line in [`LineBuffers::lod`] ([`line_bands`] stores
/// the merge depth instead, also ≥ 1).
pub const KIND_MERGED_LINE: f32 = 1.0;

/// Vertex arrays of all lines (original and merged) of a record.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineBuffers {
    /// Line ends, two per line, tree-local metres.
    pub positions: Vec<[f32; 3]>,
    /// Normals of the ends (the needles' normals).
    pub normals: Vec<[f32; 3]>,
    /// Per vertex `[error, parent_error, width, kind]`; a root's parent
    /// error is `f32::MAX`.
    pub lod: Vec<[f32; 4]>,
}

impl LineBuffers {
    /// Number of lines.
    pub fn line_count(&self) -> usize {
        self.positions.len() / 2
    }
}

/// The line buffers of `record`: original lines first (needle order), then
/// merged lines, sorted by parent error descending within each part, so that
/// coarse views touch a prefix.
pub fn line_buffers(record: &LodRecord) -> LineBuffers {
    let mut buffers = LineBuffers::default();
    for node in drawn_line_nodes(record) {
        let error = record.node_error(node);
        let parent_error = record.parent_error(node).min(f32::MAX);
        let [(a, na), (b, nb)] = record.node_ends(node);
        let length = a.distance(b).max(1e-9);
        let (width, kind) = if (node as usize) < record.needle_count() {
            (2.0 * record.needles[node as usize].radius, KIND_ORIGINAL_LINE)
        } else {
            (record.node_needle_area(node) / length, KIND_MERGED_LINE)
        };
        for (p, normal) in [(a, na), (b, nb)] {
            buffers.positions.push(p.to_array());
            buffers.normals.push(normal.to_array());
            buffers.lod.push([error, parent_error, width, kind]);
        }
    }
    buffers
}

/// The nodes [`line_buffers`] draws, in its order: original lines, then
/// merged lines, each by parent error descending; nodes whose parent error
/// is not above their own (never in a cut) are left out.
fn drawn_line_nodes(record: &LodRecord) -> Vec<u32> {
    let mut nodes: Vec<u32> = (0..record.node_count() as u32).collect();
    let n = record.needle_count() as u32;
    nodes.sort_by(|&a, &b| {
        (a >= n)
            .cmp(&(b >= n))
            .then(record.parent_error(b).total_cmp(&record.parent_error(a)))
            .then(a.cmp(&b))
    });
    nodes.retain(|&node| record.parent_error(node).min(f32::MAX) > record.node_error(node));
    nodes
}

/// Bands the plugin splits a species' lines into ([`line_bands`]).
pub const LINE_BANDS: usize = 12;

/// Lines the vertex shader runs on at spatial error `e`: those of every band
/// that [`BandErrors::may_draw`] (the plugin hides the others), out of all.
pub fn lines_processed(bands: &[LineBand], e: f32) -> u64 {
    bands
        .iter()
        .filter(|band| band.errors.may_draw(e, e))
        .map(|band| band.buffers.line_count() as u64)
        .sum()
}

/// Merge depth of every node: 0 for an original line, one more than its
/// deepest child for a merged line.
pub fn merge_depths(record: &LodRecord) -> Vec<u32> {
    let mut depth = vec![0u32; record.node_count()];
    // Children come before their parents, so one pass in node order suffices.
    for node in 0..record.node_count() as u32 {
        let parent = record.parent(node);
        if parent != super::record::NO_PARENT {
            depth[parent as usize] = depth[parent as usize].max(depth[node as usize] + 1);
        }
    }
    depth
}

/// A slice of a record's lines whose parent errors fall in one geometric
/// band, drawn as its own mesh so that a view draws (and runs the vertex
/// shader on) only the bands that can hold part of its cut.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineBand {
    /// The band's lines, as in [`line_buffers`], with the merged lines'
    /// `kind` set to their merge depth (≥ 1).
    pub buffers: LineBuffers,
    /// The span of its lines' error intervals.
    pub errors: BandErrors,
}

impl LineBand {
    /// Appends a line (its two ends, position and normal, and its
    /// `[error, parent_error, width, kind]`), widening the band's span.
    fn push_line(&mut self, ends: [(Vec3, Vec3); 2], lod: [f32; 4]) {
        self.errors.min_error = self.errors.min_error.min(lod[0]);
        self.errors.max_parent_error = self.errors.max_parent_error.max(lod[1]);
        for (position, normal) in ends {
            self.buffers.positions.push(position.to_array());
            self.buffers.normals.push(normal.to_array());
            self.buffers.lod.push(lod);
        }
    }
}

/// The span of a band's error intervals: what the CPU needs to know whether
/// a band can draw anything at a spatial error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandErrors {
    /// Smallest error of the band's lines.
    pub min_error: f32,
    /// Largest parent error of the band's lines (`f32::MAX` for roots).
    pub max_parent_error: f32,
}

impl Default for BandErrors {
    /// The empty span: draws at no error.
    fn default() -> Self {
        Self {
            min_error: f32::INFINITY,
            max_parent_error: 0.0,
        }
    }
}

impl BandErrors {
    /// Whether some line of the band can be in the cut for a spatial error
    /// in `[min_e, max_e]` (conservative: `false` means nothing is drawn).
    pub fn may_draw(&self, min_e: f32, max_e: f32) -> bool {
        min_e < self.max_parent_error && max_e >= self.min_error
    }
}

/// The lines of `record` split into at most `max_bands` bands by parent
/// error, geometrically spaced (ratio ≥ 2) from the smallest line error up,
/// plus a wood line per wood segment (`kind` [`KIND_WOOD_LINE`], drawn for
/// `2·r_max ≤ e < 2·r_max·WOOD_LINE_FADE`).
///
/// Every line of [`line_buffers`] is in exactly one band. At spatial error
/// `e` the lines of a band whose parent errors lie below `e` are all too
/// fine and the band is skipped; bands above hold only the cut's ancestors,
/// so a view processes a small multiple of its cut instead of every line.
pub fn line_bands(record: &LodRecord, max_bands: usize) -> Vec<LineBand> {
    let all = line_buffers(record);
    let max_bands = max_bands.max(1);
    let depths = merge_depths(record);
    let lines = all.line_count();
    if lines == 0 && record.wood.is_empty() {
        return Vec::new();
    }
    let lod = |line: usize| all.lod[2 * line];
    let base = (0..lines).map(|l| lod(l)[0]).fold(f32::INFINITY, f32::min);
    let base = if base.is_finite() { base.max(1e-9) } else { 1e-3 };
    let top = (0..lines)
        .map(|l| lod(l)[1])
        .filter(|&p| p < f32::MAX)
        .fold(base, f32::max);
    let span = (top / base).max(1.0);
    let ratio = span.powf(1.0 / max_bands as f32).max(2.0);
    let band_of = |parent_error: f32| -> usize {
        if parent_error >= f32::MAX {
            return max_bands - 1;
        }
        let k = ((parent_error / base).max(1.0).ln() / ratio.ln()).floor();
        (k.max(0.0) as usize).min(max_bands - 1)
    };
    let nodes = drawn_line_nodes(record);
    debug_assert_eq!(nodes.len(), lines);
    let mut bands = vec![LineBand::default(); max_bands];
    for (line, &node) in nodes.iter().enumerate() {
        let [error, parent_error, width, kind] = lod(line);
        let kind = if kind == KIND_MERGED_LINE {
            depths[node as usize].max(1) as f32
        } else {
            kind
        };
        let end = |v: usize| (Vec3::from(all.positions[v]), Vec3::from(all.normals[v]));
        bands[band_of(parent_error)].push_line([end(2 * line), end(2 * line + 1)], [error, parent_error, width, kind]);
    }
    // Wood: a segment thinner than the error is a line of its mean
    // diameter, fading out (coverage 2r/e) until it is dropped at
    // WOOD_LINE_FADE times its error.
    for segment in &record.wood {
        let error = wood_segment_error(segment);
        if error.is_nan() || error <= 0.0 || segment.start == segment.end {
            continue;
        }
        let parent_error = error * WOOD_LINE_FADE;
        let normal = (segment.end - segment.start)
            .normalize_or_zero()
            .any_orthonormal_vector();
        bands[band_of(parent_error)].push_line(
            [(segment.start, normal), (segment.end, normal)],
            [
                error,
                parent_error,
                segment.start_radius + segment.end_radius,
                KIND_WOOD_LINE,
            ],
        );
    }
    bands.retain(|band| band.buffers.line_count() > 0);
    bands
}

/// Bytes a species occupies in GPU buffers, as the plugin uploads it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct GpuBytes {
    /// Needle prisms: the per-needle storage buffer, vertex codes and indices.
    pub prisms: u64,
    /// Line bands: position, normal and `[error, parent_error, width, kind]`
    /// per vertex, two vertices per line.
    pub lines: u64,
    /// Wood prisms: the per-segment storage buffer, codes and indices.
    pub wood: u64,
}

impl GpuBytes {
    /// All of it.
    pub fn total(&self) -> u64 {
        self.prisms + self.lines + self.wood
    }
}

/// The GPU footprint of `record`'s buffers ([`prism_buffers`],
/// [`line_bands`] with [`LINE_BANDS`], [`wood_prism_buffers`]).
pub fn gpu_bytes(record: &LodRecord) -> GpuBytes {
    let prism_bytes = |b: &PrismBuffers| (b.needles.len() * 16 + b.codes.len() * 4 + b.indices.len() * 4) as u64;
    let lines = line_bands(record, LINE_BANDS)
        .iter()
        .map(|band| (band.buffers.positions.len() * (12 + 12 + 16)) as u64)
        .sum();
    GpuBytes {
        prisms: prism_buffers(record).as_ref().map_or(0, prism_bytes),
        lines,
        wood: wood_prism_buffers(record).as_ref().map_or(0, prism_bytes),
    }
}

/// A random order of `count` items (a permutation of `0..count` from a
/// seeded stream): item `i` is kept by a sample of `k` when `order[i] < k`,
/// so samples of growing size are nested and a dolly does not reshuffle.
pub fn sampling_order(count: usize, seed: u64) -> Vec<u32> {
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    let mut ranks: Vec<u32> = (0..count as u32).collect();
    let mut stream = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    ranks.shuffle(&mut stream);
    ranks
}

/// The paper's rejected alternative to merging (§3): a random sample of the
/// original lines, `keep` of the record's needles (those with
/// `order[i] < keep`), each drawn once it is a line (`2R ≤ e`) and never
/// merged, its width (hence opacity) scaled by `needles / keep` so that the
/// sample covers as much as all lines would. Wood lines are added as in
/// [`line_bands`], so only the needles differ from the LOD's lines.
///
/// `order` must have one entry per needle ([`sampling_order`]); `keep` is
/// clamped to `1..=needles`.
pub fn sampled_line_band(record: &LodRecord, order: &[u32], keep: usize) -> LineBand {
    let needles = record.needle_count();
    let keep = keep.clamp(1, needles.max(1));
    let scale = needles as f32 / keep as f32;
    let mut band = LineBand::default();
    for (i, needle) in record.needles.iter().enumerate() {
        if order.get(i).is_none_or(|&rank| rank as usize >= keep) {
            continue;
        }
        let error = line_error(needle.radius);
        band.push_line(
            [(needle.base, needle.normal), (needle.tip, needle.normal)],
            [error, f32::MAX, error * scale, KIND_ORIGINAL_LINE],
        );
    }
    for segment in &record.wood {
        let error = wood_segment_error(segment);
        if error.is_nan() || error <= 0.0 || segment.start == segment.end {
            continue;
        }
        let normal = (segment.end - segment.start)
            .normalize_or_zero()
            .any_orthonormal_vector();
        band.push_line(
            [(segment.start, normal), (segment.end, normal)],
            [
                error,
                error * WOOD_LINE_FADE,
                segment.start_radius + segment.end_radius,
                KIND_WOOD_LINE,
            ],
        );
    }
    band
}

/// Whether a line vertex with `lod = [error, parent_error, ..]` is drawn at
/// spatial error `e` (the shader's test).
pub fn line_visible(lod: [f32; 4], e: f32) -> bool {
    lod[0] <= e && e < lod[1]
}

/// Bits of a prism vertex code holding the ring slot.
pub const SLOT_BITS: u32 = 6;
/// Bit of a prism vertex code set for the tip end.
pub const TIP_BIT: u32 = 1 << SLOT_BITS;
/// Bit of a prism vertex code set for a cap vertex.
pub const CAP_BIT: u32 = 1 << (SLOT_BITS + 1);
/// Shift of the needle index in a prism vertex code.
pub const NEEDLE_SHIFT: u32 = 8;

/// Prism buffers of a record: a per-needle storage buffer and one mesh of
/// `Lmax`-slot prisms whose vertices are codes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PrismBuffers {
    /// Three `vec4`s per needle: `(base, R)`, `(tip, R_tip)`, `(normal, 0)`
    /// (`R_tip = R` for a needle; wood segments taper).
    pub needles: Vec<[f32; 4]>,
    /// Vertex codes: `needle << 8 | cap << 7 | tip << 6 | slot`.
    pub codes: Vec<u32>,
    /// Triangle indices into `codes`.
    pub indices: Vec<u32>,
    /// `Lmax`.
    pub max_sides: u8,
}

/// Most needles a prism buffer can address (24 bits of needle index).
pub const MAX_PRISM_NEEDLES: usize = 1 << 24;

/// The prism buffers of `record` (`None` with more than
/// [`MAX_PRISM_NEEDLES`] needles).
pub fn prism_buffers(record: &LodRecord) -> Option<PrismBuffers> {
    let cylinders = record
        .needles
        .iter()
        .map(|n| (n.base, n.tip, n.radius, n.radius, n.normal));
    prism_buffers_of(cylinders, record.needle_count(), record.max_sides)
}

/// Factor between a wood line's error (`2·r_max`) and the error where it is
/// dropped: there its coverage `2r/e` is below 1/64 (about 4 of 255 grey
/// levels on a one-pixel line), so it leaves without a visible pop.
pub const WOOD_LINE_FADE: f32 = 64.0;

/// A wood segment's error `2·r_max`: it is a prism below, a wood line from it on.
pub fn wood_segment_error(segment: &WoodSegment) -> f32 {
    line_error(segment.start_radius.max(segment.end_radius))
}

/// `kind` of a wood line (a branch segment thinner than the error) in
/// [`line_bands`].
pub const KIND_WOOD_LINE: f32 = -1.0;

/// The record's wood segments as `Lmax`-slot prisms, in the layout of
/// [`prism_buffers`] (the tip's `w` holds the tip radius: segments taper).
/// A segment is a prism while `e < 2·r_max` and a wood line above.
/// `None` with more than [`MAX_PRISM_NEEDLES`] segments.
pub fn wood_prism_buffers(record: &LodRecord) -> Option<PrismBuffers> {
    let cylinders = record.wood.iter().map(|w| {
        let axis = (w.end - w.start).normalize_or_zero();
        let normal = if axis == Vec3::ZERO {
            Vec3::X
        } else {
            axis.any_orthonormal_vector()
        };
        (w.start, w.end, w.start_radius, w.end_radius, normal)
    });
    prism_buffers_of(cylinders, record.wood.len(), record.max_sides)
}

/// Prism buffers of `count` (tapered) cylinders `(base, tip, base radius,
/// tip radius, normal)`.
fn prism_buffers_of(
    cylinders: impl Iterator<Item = (Vec3, Vec3, f32, f32, Vec3)>,
    count: usize,
    max_sides: u8,
) -> Option<PrismBuffers> {
    if count > MAX_PRISM_NEEDLES {
        return None;
    }
    let m = max_sides as u32;
    // The index pattern of one prism with Lmax sides, from the CPU tessellator.
    let unit = Needle {
        base: Vec3::ZERO,
        tip: Vec3::Y,
        radius: 1.0,
        normal: Vec3::X,
        group: 0,
    };
    let mut pattern = TriangleMesh::default();
    append_prism(&mut pattern, &unit, max_sides);
    let per_needle = pattern.positions.len() as u32;
    let mut buffers = PrismBuffers {
        max_sides,
        ..Default::default()
    };
    buffers.needles.reserve(3 * count);
    buffers.codes.reserve(per_needle as usize * count);
    buffers.indices.reserve(pattern.indices.len() * count);
    for (i, (base, tip, base_radius, tip_radius, normal)) in cylinders.enumerate() {
        buffers.needles.push([base.x, base.y, base.z, base_radius]);
        buffers.needles.push([tip.x, tip.y, tip.z, tip_radius]);
        buffers.needles.push([normal.x, normal.y, normal.z, 0.0]);
        let first = buffers.codes.len() as u32;
        // append_prism's vertex order: base ring, tip ring, base cap, tip cap.
        for flags in [0, TIP_BIT, CAP_BIT, CAP_BIT | TIP_BIT] {
            for slot in 0..m {
                buffers.codes.push(((i as u32) << NEEDLE_SHIFT) | flags | slot);
            }
        }
        buffers.indices.extend(pattern.indices.iter().map(|&k| first + k));
    }
    Some(buffers)
}

/// Position and normal of a prism vertex of `needle` drawn with `sides`
/// sides, from its code (the shader's computation, on the CPU).
pub fn prism_vertex(needle: &Needle, code: u32, sides: u8, max_sides: u8) -> (Vec3, Vec3) {
    let slot = code & ((1 << SLOT_BITS) - 1);
    let at_tip = code & TIP_BIT != 0;
    let cap = code & CAP_BIT != 0;
    let m = sides.clamp(3, max_sides) as u32;
    let corner = slot * m / max_sides as u32;
    let angle = TAU * corner as f32 / m as f32;
    let axis = (needle.tip - needle.base).normalize_or_zero();
    let u = (needle.normal - axis * needle.normal.dot(axis)).normalize_or_zero();
    let u = if u == Vec3::ZERO {
        axis.any_orthonormal_vector()
    } else {
        u
    };
    let v = axis.cross(u);
    let radial = u * angle.cos() + v * angle.sin();
    let end = if at_tip { needle.tip } else { needle.base };
    let normal = match (cap, at_tip) {
        (false, _) => radial,
        (true, true) => axis,
        (true, false) => -axis,
    };
    (end + radial * needle.radius, normal)
}

/// Side count the shader draws for a needle of radius `radius` at spatial
/// error `e`, or `None` when the needle is a line (`e ≥ 2R`).
pub fn shader_prism_sides(radius: f32, e: f32, max_sides: u8) -> Option<u8> {
    (e < line_error(radius)).then(|| prism_sides(relative_error(e, radius), max_sides))
}

/// PCG hash (Jarzynski and Olano, *Hash Functions for GPU Rendering*,
/// JCGT 2020), as `conifer_line_shadow.wgsl` computes it.
pub fn pcg_hash(value: u32) -> u32 {
    let state = value.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// CPU reference of the lines' shadow test (`conifer_line_shadow.wgsl`):
/// whether the fragment at shadow-map texel `texel` of line `line` of
/// instance `tree`, whose opacity is `alpha`, writes depth. It does with
/// probability `alpha`, independently between lines and trees, so a
/// line's shadow covers what its blended colour covers and overlapping
/// lines compose as `1 − Π(1 − aᵢ)`.
pub fn shadow_texel_kept(texel: [u32; 2], line: u32, tree: u32, alpha: f32) -> bool {
    let h = pcg_hash(texel[0] ^ pcg_hash(texel[1] ^ pcg_hash(line ^ pcg_hash(tree))));
    (h >> 8) as f32 * (1.0 / 16_777_216.0) < alpha
}

#[cfg(test)]
mod tests {

    #[test]
    fn hashed_shadow_texels_cover_the_line_opacity() {
        let kept = |line: u32, tree: u32, alpha: f32| {
            (0..256u32)
                .flat_map(|y| (0..256u32).map(move |x| [x, y]))
                .filter(|&t| shadow_texel_kept(t, line, tree, alpha))
                .count() as f32
                / 65_536.0
        };
        for alpha in [0.0, 0.05, 0.3, 0.5, 0.9, 1.0] {
            let fraction = kept(17, 3, alpha);
            assert!((fraction - alpha).abs() < 0.01, "alpha {alpha}: {fraction}");
        }
        // Overlapping lines are independent: together they cover what
        // blending them gives, 1 − Π(1 − aᵢ).
        let alphas = [0.3f32, 0.5, 0.2];
        let covered = (0..256u32)
            .flat_map(|y| (0..256u32).map(move |x| [x, y]))
            .filter(|&t| {
                alphas
                    .iter()
                    .enumerate()
                    .any(|(line, &a)| shadow_texel_kept(t, line as u32, 9, a))
            })
            .count() as f32
            / 65_536.0;
        let blended = 1.0 - alphas.iter().map(|a| 1.0 - a).product::<f32>();
        assert!((covered - blended).abs() < 0.01, "{covered} vs {blended}");
        // The same line of another tree uses other texels.
        let same = (0..65_536u32)
            .filter(|&i| {
                let t = [i % 256, i / 256];
                shadow_texel_kept(t, 5, 1, 0.5) == shadow_texel_kept(t, 5, 2, 0.5)
            })
            .count() as f32
            / 65_536.0;
        assert!((same - 0.5).abs() < 0.02, "{same}");
    }
    use super::*;
    use crate::model::{BakeOptions, TreeInput, WoodSegment, bake};

    fn record() -> LodRecord {
        let mut needles = Vec::new();
        for g in 0..30u32 {
            let t = g as f32 * 0.7;
            let base = Vec3::new(t.cos(), g as f32 * 0.05, t.sin()) * 0.5;
            for k in 0..4 {
                let dir = Vec3::new(t.cos() + 0.1 * k as f32, 0.5, t.sin()).normalize();
                needles.push(Needle {
                    base,
                    tip: base + dir * 0.04,
                    radius: 0.0005 + 0.0001 * k as f32,
                    normal: dir.any_orthonormal_vector(),
                    group: g,
                });
            }
        }
        let wood = (0..6)
            .map(|k| WoodSegment {
                start: Vec3::Y * k as f32 * 0.3,
                end: Vec3::Y * (k + 1) as f32 * 0.3,
                start_radius: 0.05 / (k + 1) as f32,
                end_radius: 0.05 / (k + 2) as f32,
            })
            .collect();
        bake(
            &TreeInput {
                needles,
                wood,
                ..Default::default()
            },
            &BakeOptions::default(),
            &(),
        )
        .unwrap()
    }

    #[test]
    fn visible_lines_are_exactly_the_cut() {
        let record = record();
        let buffers = line_buffers(&record);
        let ranges = record.part_ranges();
        let mut probes = vec![0.0, ranges.original_lines.min, ranges.original_lines.max];
        let merged = ranges.merged_lines.unwrap();
        for k in 0..=20 {
            probes.push(merged.min + (merged.max - merged.min) * k as f32 / 20.0);
        }
        probes.push(merged.max * 10.0);
        for e in probes {
            let cut = record.cut(e);
            let stats = record.cut_stats(&cut);
            let mut drawn = 0;
            for pair in buffers.lod.chunks(2) {
                assert_eq!(line_visible(pair[0], e), line_visible(pair[1], e));
                drawn += line_visible(pair[0], e) as u64;
            }
            assert_eq!(drawn, stats.line_segments, "e = {e}");
            let prisms = record
                .needles
                .iter()
                .filter(|n| shader_prism_sides(n.radius, e, record.max_sides).is_some());
            assert_eq!(prisms.count() as u64, stats.prisms, "e = {e}");
        }
    }

    #[test]
    fn bands_partition_the_lines_and_keep_the_cut() {
        let record = record();
        let all = line_buffers(&record);
        for max_bands in [1, 3, 12] {
            let bands = line_bands(&record, max_bands);
            assert!(!bands.is_empty() && bands.len() <= max_bands);
            let total: usize = bands.iter().map(|b| b.buffers.line_count()).sum();
            assert_eq!(total, all.line_count() + record.wood.len());
            let mut probes: Vec<f32> = all.lod.iter().flat_map(|l| [l[0], l[1].min(1e30)]).collect();
            probes.extend([0.0, 1e30]);
            for e in probes {
                let cut_lines = record.cut_stats(&record.cut(e)).line_segments;
                let mut drawn = 0u64;
                for band in &bands {
                    let in_band = band
                        .buffers
                        .lod
                        .chunks(2)
                        .filter(|p| p[0][3] != KIND_WOOD_LINE && line_visible(p[0], e))
                        .count() as u64;
                    // A band that may not draw draws nothing.
                    if !band.errors.may_draw(e, e) {
                        assert_eq!(in_band, 0, "e = {e}");
                    }
                    drawn += in_band;
                }
                assert_eq!(drawn, cut_lines, "e = {e}");
            }
        }
    }

    #[test]
    fn wood_is_a_prism_below_its_error_and_a_fading_line_above() {
        let record = record();
        let prisms = wood_prism_buffers(&record).unwrap();
        assert_eq!(prisms.needles.len(), 3 * record.wood.len());
        let per_segment = prisms.codes.len() / record.wood.len();
        assert_eq!(
            per_segment,
            prism_buffers(&record).unwrap().codes.len() / record.needle_count()
        );
        let bands = line_bands(&record, 6);
        for (k, segment) in record.wood.iter().enumerate() {
            // Tapered: the tip's w holds the end radius.
            assert_eq!(prisms.needles[3 * k][3], segment.start_radius);
            assert_eq!(prisms.needles[3 * k + 1][3], segment.end_radius);
            let error = line_error(segment.start_radius.max(segment.end_radius));
            let drawn_at = |e: f32| {
                bands
                    .iter()
                    .flat_map(|b| b.buffers.lod.chunks(2).map(|p| p[0]))
                    .filter(|lod| lod[3] == KIND_WOOD_LINE && lod[0] == error && line_visible(*lod, e))
                    .count()
            };
            assert_eq!(drawn_at(error * 0.99), 0);
            assert_eq!(drawn_at(error), 1);
            assert_eq!(drawn_at(error * (WOOD_LINE_FADE - 1.0)), 1);
            assert_eq!(drawn_at(error * WOOD_LINE_FADE), 0);
        }
    }

    #[test]
    fn merged_lines_carry_their_depth() {
        let record = record();
        let depths = merge_depths(&record);
        let n = record.needle_count();
        assert!(depths[..n].iter().all(|&d| d == 0));
        for (k, line) in record.merged.iter().enumerate() {
            let [a, b] = line.children.map(|c| depths[c as usize]);
            assert_eq!(depths[n + k], a.max(b) + 1);
        }
        for band in line_bands(&record, 4) {
            for lod in &band.buffers.lod {
                assert!(lod[3] == KIND_ORIGINAL_LINE || lod[3] == KIND_WOOD_LINE || lod[3] >= 1.0);
            }
        }
    }

    #[test]
    fn slot_prisms_collapse_to_the_cpu_prisms() {
        let record = record();
        let buffers = prism_buffers(&record).unwrap();
        let per_needle = buffers.codes.len() / record.needle_count();
        let tris_per_needle = buffers.indices.len() / 3 / record.needle_count();
        for (i, needle) in record.needles.iter().enumerate().take(5) {
            for sides in 3..=record.max_sides {
                let mut cpu = TriangleMesh::default();
                append_prism(&mut cpu, needle, sides);
                let triangles = |positions: &dyn Fn(u32) -> Vec3, indices: &[u32]| {
                    let mut out: Vec<[[i64; 3]; 3]> = indices
                        .chunks(3)
                        .filter_map(|t| {
                            let [a, b, c] = [positions(t[0]), positions(t[1]), positions(t[2])];
                            ((b - a).cross(c - a).length() > 1e-12).then(|| {
                                let mut tri = [a, b, c].map(|p| (p * 1e7).round().as_i64vec3().to_array());
                                let start = (0..3).min_by_key(|&k| tri[k]).unwrap();
                                tri.rotate_left(start);
                                tri
                            })
                        })
                        .collect();
                    out.sort();
                    out
                };
                let expected = triangles(&|k| cpu.positions[k as usize], &cpu.indices);
                let first = i * tris_per_needle * 3;
                let gpu_indices = &buffers.indices[first..first + tris_per_needle * 3];
                let gpu = triangles(
                    &|k| prism_vertex(needle, buffers.codes[k as usize], sides, record.max_sides).0,
                    gpu_indices,
                );
                assert_eq!(gpu, expected, "needle {i}, {sides} sides");
                assert!(gpu_indices.iter().all(|&k| (k as usize) / per_needle == i));
            }
        }
    }

    #[test]
    fn sampled_band_keeps_a_nested_sample_with_scaled_width() {
        let record = record();
        let n = record.needle_count();
        let order = sampling_order(n, 7);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..n as u32).collect::<Vec<_>>(), "a permutation");
        assert_eq!(order, sampling_order(n, 7), "deterministic");
        let wood_lines = record.wood.len();
        let small = sampled_line_band(&record, &order, n / 4);
        let large = sampled_line_band(&record, &order, n / 2);
        assert_eq!(small.buffers.line_count(), n / 4 + wood_lines);
        assert_eq!(large.buffers.line_count(), n / 2 + wood_lines);
        // Nested: every needle line of the small sample is in the large one.
        let needle_lines = |band: &LineBand| -> Vec<[f32; 3]> {
            (0..band.buffers.line_count())
                .filter(|&l| band.buffers.lod[2 * l][3] == KIND_ORIGINAL_LINE)
                .map(|l| band.buffers.positions[2 * l])
                .collect()
        };
        let big = needle_lines(&large);
        assert!(needle_lines(&small).iter().all(|p| big.contains(p)));
        // Width scaled by needles / keep; drawn from the line error on, never merged.
        for l in 0..small.buffers.line_count() {
            let [error, parent, width, kind] = small.buffers.lod[2 * l];
            if kind == KIND_ORIGINAL_LINE {
                assert_eq!(parent, f32::MAX);
                assert!((width - error * 4.0).abs() <= 1e-6 * width);
            }
        }
        // Keep is clamped: 0 keeps one needle, more than all keeps all.
        assert_eq!(
            sampled_line_band(&record, &order, 0).buffers.line_count(),
            1 + wood_lines
        );
        assert_eq!(
            sampled_line_band(&record, &order, 10 * n).buffers.line_count(),
            n + wood_lines
        );
    }

    #[test]
    fn gpu_bytes_add_up_the_buffers() {
        let record = record();
        let bytes = gpu_bytes(&record);
        let prisms = prism_buffers(&record).unwrap();
        assert_eq!(
            bytes.prisms,
            (prisms.needles.len() * 16 + prisms.codes.len() * 4 + prisms.indices.len() * 4) as u64
        );
        let lines: usize = line_bands(&record, LINE_BANDS)
            .iter()
            .map(|b| b.buffers.line_count())
            .sum();
        assert_eq!(bytes.lines, (lines * 2 * 40) as u64);
        assert!(bytes.wood > 0);
        assert_eq!(bytes.total(), bytes.prisms + bytes.lines + bytes.wood);
    }
}
