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
use super::needle::Needle;
use super::prism::{TriangleMesh, append_prism};
use super::record::LodRecord;
use glam::Vec3;
use std::f32::consts::TAU;

/// `kind` of an original line in [`LineBuffers::lod`].
pub const KIND_ORIGINAL_LINE: f32 = 0.0;
/// `kind` of a merged line in [`LineBuffers::lod`].
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
    let mut nodes: Vec<u32> = (0..record.node_count() as u32).collect();
    let n = record.needle_count() as u32;
    nodes.sort_by(|&a, &b| {
        (a >= n)
            .cmp(&(b >= n))
            .then(record.parent_error(b).total_cmp(&record.parent_error(a)))
            .then(a.cmp(&b))
    });
    let mut buffers = LineBuffers::default();
    for node in nodes {
        let error = record.node_error(node);
        let parent_error = record.parent_error(node).min(f32::MAX);
        if parent_error <= error {
            continue; // never in any cut
        }
        let [(a, na), (b, nb)] = record.node_ends(node);
        let length = a.distance(b).max(1e-9);
        let (width, kind) = if node < n {
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
    /// Three `vec4`s per needle: `(base, R)`, `(tip, 0)`, `(normal, 0)`.
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
    if record.needle_count() > MAX_PRISM_NEEDLES {
        return None;
    }
    let max_sides = record.max_sides;
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
    buffers.needles.reserve(3 * record.needle_count());
    buffers.codes.reserve(per_needle as usize * record.needle_count());
    buffers.indices.reserve(pattern.indices.len() * record.needle_count());
    for (i, needle) in record.needles.iter().enumerate() {
        buffers
            .needles
            .push([needle.base.x, needle.base.y, needle.base.z, needle.radius]);
        buffers.needles.push([needle.tip.x, needle.tip.y, needle.tip.z, 0.0]);
        buffers
            .needles
            .push([needle.normal.x, needle.normal.y, needle.normal.z, 0.0]);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{BakeOptions, TreeInput, bake};

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
        bake(
            &TreeInput {
                needles,
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
}
