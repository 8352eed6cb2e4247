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
//!   ring faces the view ([`prism_ring`]).
//! * **Original lines**, 4 bytes: needle indices sorted by parent error code
//!   descending, so the lines whose parent error is above the view's are a
//!   prefix.
//! * **Merged lines**, 12 bytes: two needle-end references (needle index
//!   · 2 + 1 at the tip, 24 bits each), in the references' top bytes the
//!   equivalent width (summed needle side area over length: the top 12
//!   bits of its 16-bit logarithmic code, 0.8 % a step) and the needles'
//!   alignment with the line (4 bits, [`shading::AxisSpread::alignment`],
//!   what lights the line as its bundle), and the error and parent error
//!   codes. Sorted by parent error code descending.
//! * **Wood**, 16 bytes a segment: both ends as 16-bit codes on the
//!   wood's own grid and both radii as 16-bit logarithmic codes rounded
//!   up to an even code, their low bits whether the segment's start and end
//!   go on into another segment of the same branch ([`wood_joints`]),
//!   sorted by the larger radius descending; an imported wood mesh on the
//!   same grid (12 bytes a vertex, `u32` indices).
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

use super::metric::line_error;
use super::needle::WoodSegment;
use super::prism::{TriangleMesh, WOOD_LINE_FADE};
use super::prototype::{Placement, PrototypeRecord};
use super::quantize::{LOG_CODE_MAX, LOG_CODE_MIN, PositionGrid, log_decode, log_encode_at_least, log_encode_nearest};
use super::raster::LineJoints;
use super::record::{Cut, LodRecord, NO_PARENT};
use super::shading::{self, AxisSpread};
use super::view::{Sphere, ViewPoint};
use super::{file, metric};
use glam::Vec3;
use std::collections::HashMap;

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
    /// A prototype record whose prototypes are not shared did not flatten
    /// for the flat layout.
    #[error("the record does not flatten: {0}")]
    Flatten(#[from] super::record::RecordInvalid),
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
    /// Each prototype's merged lines again, as indices into
    /// `merged_lines` sorted by their own error code ascending (empty for
    /// a flat species): a view close to a placement draws the lines it
    /// reaches from this order, a far one from the parent-sorted one
    /// ([`CompactPrototype::merged_by_own`]). The GPU reads it after
    /// `original_lines`, in the same buffer.
    pub merged_by_own: Vec<u32>,
    /// Wood segments, four words each: both ends on `wood_grid` (16 bits a
    /// coordinate, `sx | sy << 16`, `sz | ex << 16`, `ey | ez << 16`) and
    /// their radii as even logarithmic codes rounded up (`start | end <<
    /// 16`), each code's low bit set where that end is joined
    /// ([`WOOD_JOINED_START`], [`WOOD_JOINED_END`]), sorted by the larger
    /// radius descending ([`CompactSpecies::wood_segment`] decodes one as
    /// the shaders do, [`CompactSpecies::wood_joints`] its joints).
    pub wood_segments: Vec<[u32; 4]>,
    /// The grid of the wood's positions: segment ends and mesh vertices.
    pub wood_grid: PositionGrid,
    /// Wood mesh vertices: `x | y << 16`, `z`, octahedral normal.
    pub wood_vertices: Vec<[u32; 3]>,
    /// Wood mesh triangles, three vertex indices each.
    pub wood_indices: Vec<u32>,
    /// Smallest and largest merged-line error code (debug colours).
    pub merged_code_range: [u16; 2],
    /// Entries of `needles`, `original_lines` and `merged_lines` that
    /// belong to the tree itself (all of them for a flat species); the
    /// prototypes' sections follow ([`CompactPrototype`]).
    pub tree_counts: [u32; 3],
    /// Shared prototypes (empty for a flat species).
    pub prototypes: Vec<CompactPrototype>,
    /// Where the prototypes stand, sorted by the parent error code of
    /// their root line descending: the placements a view expands are a
    /// prefix.
    pub placements: Vec<CompactPlacement>,
    /// Bounding spheres of the level-2 merged lines (tree metres, see
    /// [`super::view`]), in their order in `merged_lines`. Empty for a
    /// flat species.
    pub tree_spheres: Vec<Sphere>,
    /// For each of the tree's lines, the index in `tree_spheres` of its
    /// parent's sphere, or its nearest drawable ancestor's when the parent
    /// has its parent's error code and is left out ([`NO_SPHERE`] for a
    /// root).
    pub tree_line_parents: Vec<u32>,
    /// A sphere holding every node's sphere and the wood (tree metres); a
    /// view's tree-wide threshold code comes from its nearest point.
    pub tree_sphere: Sphere,
    /// Linear RGB the needles take where no placement gives them an age
    /// (the tree's own lines, a flat species, the impostor):
    /// [`super::color::far_needle_color`], or a flat record's needle colour.
    pub far_needle_color: Vec3,
}

/// A root's parent sphere index: no parent.
pub const NO_SPHERE: u32 = u32::MAX;

/// One shared prototype of a placed species: its sections of the compact
/// arrays, on its own grid, and how its placements' threshold codes are
/// binned into draws.
#[derive(Clone, Debug, PartialEq)]
pub struct CompactPrototype {
    /// The grid of its needles' ends (prototype metres).
    pub grid: PositionGrid,
    /// Its bounding sphere (prototype metres): placed, a placement's.
    pub sphere: Sphere,
    /// First entry and length of its needles (sorted by line-error code
    /// descending within the section).
    pub needles: [u32; 2],
    /// First entry and length of its original-line order (needle indices
    /// into the whole array).
    pub original_lines: [u32; 2],
    /// First entry and length of its merged lines (end references into the
    /// whole needle array).
    pub merged_lines: [u32; 2],
    /// First entry of its merged lines in [`CompactSpecies::merged_by_own`]
    /// (as many as `merged_lines[1]`).
    pub merged_by_own: u32,
    /// Lower edges of bands 1… (ascending; `u16::MAX` past the last
    /// needed): chosen by [`band_edges`] so that no placement of a band
    /// processes more than a bounded multiple of its own prefixes.
    pub band_edges: [u16; PLACED_BANDS as usize - 1],
    /// The upper side of its needles ([`super::color::upper_side`]): which
    /// way a placement's needles show their undersides.
    pub upper_side: Vec3,
}

/// A placement of a placed species, as the GPU reads it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompactPlacement {
    /// The prototype's index in [`CompactSpecies::prototypes`].
    pub prototype: u32,
    /// Rotation, translation and uniform scale (see [`Placement`]).
    pub transform: Placement,
    /// Error code of the level-2 parent of the placement's root line
    /// ([`ROOT_PARENT_CODE`] without one): a view expands the placement iff
    /// its threshold code is below it.
    pub parent_code: u16,
    /// Index in [`CompactSpecies::tree_spheres`] of that parent's sphere,
    /// or its nearest drawable ancestor's ([`NO_SPHERE`] for a root).
    pub parent_sphere: u32,
    /// The record's placement index.
    pub source: u32,
}

/// Bands a prototype's placements are binned into by threshold code: one
/// instanced draw per prototype, band and part, each drawing the longest
/// prefix its placements need.
pub const PLACED_BANDS: u32 = 16;

/// Most prototypes a placed species holds (more, and the record is drawn flat).
pub const MAX_PLACED_PROTOTYPES: usize = 1024;

/// Most placements a placed species holds: a per-view entry packs the
/// placement index in 16 bits.
pub const MAX_PLACEMENTS: usize = 1 << 16;

/// Buckets of a view's expansion budget (per species: the placements a
/// view may expand, `ConiferLodSettings::max_expanded_placements`): a
/// tree's bucket is its threshold code's top bits ([`budget_bucket`]), so
/// a lower bucket is a tree seen with a smaller error (nearer), and the
/// budget goes to the lowest buckets first ([`budget_cutoff`]).
pub const BUDGET_BUCKETS: usize = 128;

/// Threshold code bits below a budget bucket: `65535 >> 9 = 127`, and a
/// bucket spans `512 · LOG_CODE_LN_STEP = 0.25` in `ln e` (errors within a
/// factor 1.29).
pub const BUDGET_BUCKET_SHIFT: u32 = 9;

/// The budget bucket of a tree at threshold code `code`.
pub fn budget_bucket(code: u16) -> usize {
    usize::from(code >> BUDGET_BUCKET_SHIFT)
}

/// Depth buckets of the order in which a camera draws the expanded
/// placements' lines: back to front, a bucket at a time. Blended lines
/// written in any other order mix the needles of a crown's whole depth in
/// a pixel, where a crown shows the ones the camera meets first.
pub const DEPTH_BUCKETS: u32 = 4096;

/// Depth buckets an octave of distance spans: a bucket is 0.36 % of its
/// distance deep (29 cm at 80 m, where a mature crown is 10–15 m across).
pub const DEPTH_BUCKETS_PER_OCTAVE: f32 = 192.0;

/// The distance (world metres) of the nearest depth bucket's far edge;
/// [`DEPTH_BUCKETS`] reach `0.05 · 2^(4096 / 192)` ≈ 130 km.
pub const DEPTH_NEAREST: f32 = 0.05;

/// The depth bucket of a placement whose prototype's sphere centre lies
/// `distance` world metres from the camera: logarithmic in distance, 0 up
/// to [`DEPTH_NEAREST`], [`DEPTH_BUCKETS`]` − 1` from about 130 km on, 0
/// for NaN. CPU reference of `compact_types.wgsl`'s `depth_bucket`.
pub fn depth_bucket(distance: f32) -> u32 {
    let octaves = (distance.max(DEPTH_NEAREST) / DEPTH_NEAREST).log2();
    if octaves.is_nan() {
        return 0;
    }
    (octaves * DEPTH_BUCKETS_PER_OCTAVE)
        .floor()
        .clamp(0.0, (DEPTH_BUCKETS - 1) as f32) as u32
}

/// The order in which a camera draws expanded placements at `distances`
/// from it (world metres): indices into `distances`, farthest bucket first
/// ([`depth_bucket`]), in their given order within a bucket (the GPU's
/// order within a bucket is whatever its atomics make it). CPU reference
/// of `conifer_cull.wgsl`'s depth ranks (`count_placements`,
/// `scan_placements`, `scatter_placements`).
pub fn back_to_front(distances: &[f32]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..distances.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(depth_bucket(distances[i])));
    order
}

/// The spatial error (tree metres) a directional light's cascade ranks a
/// tree by for its expansion budget: every tree of the cascade has the same
/// error (its texel), so the budget goes by the error the cascade's camera
/// sees the tree at, from its crown centre `distance` metres from that
/// camera less the wind's `reach` (world metres), at the camera's
/// `error_slope` (`2 / (P₁₁ · H)`), the tree's `pixel_error` and `scale`.
/// Its [`shader_threshold_code`] is the tree's [`budget_bucket`] code.
/// CPU reference of `conifer_cull.wgsl`'s `error_from` (a camera's error
/// for a tree, and a cascade's `budget_code`).
pub fn budget_error(distance: f32, reach: f32, error_slope: f32, pixel_error: f32, scale: f32) -> f32 {
    pixel_error.max(0.0) * (distance - reach).max(0.0) * error_slope / scale.max(1e-6)
}

/// Where a view's expansion budget of `capacity` entries runs out:
/// `(cutoff, base)`, the first bucket whose trees together no longer fit
/// after the buckets before it ([`BUDGET_BUCKETS`] when every tree fits)
/// and the entries those buckets take. Trees below the cutoff always
/// expand; trees above it never do (they draw their impostor or their
/// level-2 lines);
/// trees in it take what is left from `base` on, in the order the GPU
/// reaches them. `demand[b]` is the placements bucket `b`'s trees would
/// expand. CPU reference of `conifer_cull.wgsl`'s `budget_cutoff`.
pub fn budget_cutoff(demand: &[u32; BUDGET_BUCKETS], capacity: u32) -> (usize, u32) {
    let mut taken = 0u32;
    for (bucket, &d) in demand.iter().enumerate() {
        match taken.checked_add(d) {
            Some(sum) if sum <= capacity => taken = sum,
            _ => return (bucket, taken),
        }
    }
    (BUDGET_BUCKETS, taken)
}

/// Which of a view's trees expand their placements under a budget of
/// `capacity` entries: `trees` are each tree's threshold code and the
/// placements it would expand, in the order the GPU reaches them (in a
/// directional cascade the code of the tree's [`budget_error`]). A tree
/// that expands nothing is `true`. CPU reference of `conifer_cull.wgsl`'s
/// `budget_demand`, `budget_cutoff` and `expand_placements`.
pub fn budget_expands(trees: &[(u16, u32)], capacity: u32) -> Vec<bool> {
    let mut demand = [0u32; BUDGET_BUCKETS];
    for &(code, expanded) in trees {
        let bucket = &mut demand[budget_bucket(code)];
        *bucket = bucket.wrapping_add(expanded);
    }
    let (cutoff, base) = budget_cutoff(&demand, capacity);
    let mut in_cutoff = 0u32;
    trees
        .iter()
        .map(|&(code, expanded)| {
            let bucket = budget_bucket(code);
            if expanded == 0 || bucket < cutoff {
                return true;
            }
            if bucket > cutoff {
                return false;
            }
            let start = base.wrapping_add(in_cutoff);
            in_cutoff = in_cutoff.wrapping_add(expanded);
            start.checked_add(expanded).is_some_and(|end| end <= capacity)
        })
        .collect()
}

/// Bytes of each compact array.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CompactBytes {
    /// Needles (16 bytes each).
    pub needles: u64,
    /// Original-line order and the prototypes' merged lines by own code
    /// (4 bytes each).
    pub original_lines: u64,
    /// Merged lines (12 bytes each).
    pub merged_lines: u64,
    /// Wood segments, wood mesh vertices and indices.
    pub wood: u64,
    /// Prototype table (96 bytes each) and placements (48 bytes each).
    pub placements: u64,
    /// The level-2 lines' bounding spheres (16 bytes each) and their
    /// parents' sphere indices (4 bytes each), for view-dependent detail.
    pub spheres: u64,
}

impl CompactBytes {
    /// All of it.
    pub fn total(&self) -> u64 {
        self.needles + self.original_lines + self.merged_lines + self.wood + self.placements + self.spheres
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

/// The prefixes of one section of the arrays (the tree's or a prototype's)
/// at one threshold code.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SectionPrefixes {
    /// Needles that are prisms (`c < code(2R)`).
    pub prisms: u32,
    /// The section's needles after the prisms (original lines whose own
    /// code is `≤ c`).
    pub after_prisms: u32,
    /// Original lines whose parent code is above `c`.
    pub original_by_parent: u32,
    /// Merged lines whose parent code is above `c`.
    pub merged_lines: u32,
    /// Merged lines whose own code is `≤ c` (from the own-code order; the
    /// whole section where it has none, so it is never the shorter).
    pub merged_by_own: u32,
}

/// An expanded placement's line draw in a camera's back-to-front order
/// ([`CompactSpecies::entry_lines`]): `merged` lines from `merged_first`,
/// then `original` lines from `original_first`, in one draw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EntryLines {
    /// Its first merged line: in the GPU's line orders (the original-line
    /// order, then [`CompactSpecies::merged_by_own`]) where its draw takes
    /// the merged lines by own code, else in [`CompactSpecies::merged_lines`].
    pub merged_first: u32,
    /// Merged lines it draws.
    pub merged: u32,
    /// Its first original line: a needle where its draw takes the original
    /// lines from the needles after the prisms, else in
    /// [`CompactSpecies::original_lines`].
    pub original_first: u32,
    /// Original lines it draws.
    pub original: u32,
}

impl EntryLines {
    /// Lines of the draw.
    pub fn lines(&self) -> u32 {
        self.merged + self.original
    }

    /// The draw's first line (its first vertex over the vertices a line).
    pub fn first(&self) -> u32 {
        self.merged_first
    }

    /// The draw's split as the vertex shader reads it: the line its merged
    /// lines end at, and its first original line.
    pub fn split(&self) -> [u32; 2] {
        [self.merged_first + self.merged, self.original_first]
    }
}

impl SectionPrefixes {
    /// Whether the original lines are drawn from the needles after the
    /// prisms rather than from the parent-sorted order: the shorter range.
    pub fn original_from_needles(&self) -> bool {
        self.after_prisms < self.original_by_parent
    }

    /// Original lines a draw of these prefixes processes (the shorter range).
    pub fn original_lines(&self) -> u32 {
        self.after_prisms.min(self.original_by_parent)
    }

    /// Whether the merged lines are drawn from the own-code order rather
    /// than from the parent-sorted one: the shorter range.
    pub fn merged_from_own(&self) -> bool {
        self.merged_by_own < self.merged_lines
    }

    /// Merged lines a draw of these prefixes processes (the shorter range).
    pub fn merged(&self) -> u32 {
        self.merged_by_own.min(self.merged_lines)
    }

    /// Primitives a draw of these prefixes processes.
    pub fn total(&self) -> u32 {
        self.prisms + self.original_lines() + self.merged()
    }

    /// Vertices a draw of these prefixes processes, a prism taking
    /// `prism_vertices` and a line two.
    pub fn vertices(&self, prism_vertices: u32) -> u64 {
        u64::from(self.prisms) * u64::from(prism_vertices) + 2 * u64::from(self.original_lines() + self.merged())
    }

    /// Each prefix the longer of `self`'s and `other`'s (what one draw
    /// serving both needs).
    pub fn max(self, other: Self) -> Self {
        Self {
            prisms: self.prisms.max(other.prisms),
            after_prisms: self.after_prisms.max(other.after_prisms),
            original_by_parent: self.original_by_parent.max(other.original_by_parent),
            merged_lines: self.merged_lines.max(other.merged_lines),
            merged_by_own: self.merged_by_own.max(other.merged_by_own),
        }
    }
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
/// *Building an Orthonormal Basis, Revisited*, JCGT 2017): the shader's
/// ring of a prism seen along its axis.
pub fn ring_basis(axis: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(axis.z);
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    (
        Vec3::new(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x),
        Vec3::new(b, sign + axis.y * axis.y * a, -axis.y),
    )
}

/// The ring of a `sides`-sided prism round unit `axis` seen from
/// `toward` (the direction to the view), as the shader builds it: corner
/// `k`'s radial direction is `u·cos(2πk/m + phase) + v·sin(…)`, with `u`
/// toward the view across the axis and `v = axis × u`; the first corner
/// faces the view when `m` is odd and the phase is half a step when `m` is
/// 2 mod 4, so the silhouette is centred on the axis and as wide as an
/// inscribed `m`-gon gets (`2r·cos(π/2m)` for odd `m`, `2r` for even),
/// and an odd ring's corners stand `1/cos(π/2m)` radii from the axis
/// (the fourth value) so that it too is `2r` wide, the cylinder's: a
/// three-sided prism covers `r` on each side of its axis (inscribed, it
/// covered `0.87·r`: the young spruce's trunk, three-sided at 12 m, was a
/// column of pixels short of the reference's), rather than anywhere from
/// `1.5·r` to `√3·r` off centre, as a ring fixed to the needle would.
/// Returns `(u, v, phase, radius scale)`.
pub fn prism_ring(axis: Vec3, toward: Vec3, sides: u8) -> (Vec3, Vec3, f32, f32) {
    let m = u32::from(sides.max(3));
    let (u, v) = super::shading::visible_frame(axis, toward);
    let phase = if m % 4 == 2 {
        std::f32::consts::PI / m as f32
    } else {
        0.0
    };
    let scale = if m % 2 == 1 {
        1.0 / (std::f32::consts::PI / (2 * m) as f32).cos()
    } else {
        1.0
    };
    (u, v, phase, scale)
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

/// Threshold code of a node's error, rounded up and capped at
/// [`MAX_THRESHOLD_CODE`].
fn error_code(error: f32) -> Result<u16, CompactError> {
    Ok(code_at_least(error, "errors")?.min(MAX_THRESHOLD_CODE))
}

fn parent_code(record: &LodRecord, node: u32) -> Result<u16, CompactError> {
    if record.parent(node) == NO_PARENT {
        return Ok(ROOT_PARENT_CODE);
    }
    error_code(record.parent_error(node))
}

/// Error code and parent error code of merged node `node` of `record`,
/// rounded up (the parent's is [`ROOT_PARENT_CODE`] for a root): the line
/// can be in a cut iff the parent's is above its own.
fn merged_line_codes(record: &LodRecord, node: u32) -> Result<(u16, u16), CompactError> {
    Ok((error_code(record.node_error(node))?, parent_code(record, node)?))
}

/// Equivalent width code of merged node `node` of `record`: its needles'
/// summed side area over its length.
fn merged_line_width(record: &LodRecord, node: u32) -> Result<u16, CompactError> {
    let [(a, _), (b, _)] = record.node_ends(node);
    line_width_code(record.node_needle_area(node), a.distance(b))
}

/// Equivalent width code of a line of `length` standing for needles of
/// summed side area `area`.
fn line_width_code(area: f32, length: f32) -> Result<u16, CompactError> {
    log_encode_nearest((area / length.max(1e-9)).min(LOG_CODE_MAX)).ok_or(CompactError::OutOfRange("line widths"))
}

/// The [`AxisSpread`] of every merged line of `record` (index `m` for
/// node `needles + m`), children summed before parents.
fn merged_spreads(record: &LodRecord) -> Vec<AxisSpread> {
    let n = record.needle_count();
    let needle = |k: usize| {
        let x = &record.needles[k];
        AxisSpread::needle(x.base, x.tip, x.side_area())
    };
    let mut spreads: Vec<AxisSpread> = Vec::with_capacity(record.merged.len());
    for line in &record.merged {
        let [a, b] = line.children.map(|c| match (c as usize).checked_sub(n) {
            None => needle(c as usize),
            Some(m) => spreads[m],
        });
        spreads.push(a + b);
    }
    spreads
}

/// Bits of a merged line's width code kept: the top 12 of its 16.
const WIDTH_DROPPED_BITS: u32 = 4;

/// The three words of a merged line: its two end references, the top 12
/// bits of the width code in the first's top byte and the second's low
/// nibble of it, the alignment code in the second's top nibble, then its
/// own and parent codes.
fn merged_line_words(ends: [u32; 2], width: u16, alignment: f32, own: u16, parent: u16) -> [u32; 3] {
    let half = 1 << (WIDTH_DROPPED_BITS - 1);
    let kept = ((u32::from(width) + half) >> WIDTH_DROPPED_BITS).min(0xfff);
    [
        ends[0] | (kept & 0xff) << 24,
        ends[1] | (kept >> 8) << 24 | shading::alignment_code(alignment) << 28,
        u32::from(own) | u32::from(parent) << 16,
    ]
}

/// Wood segments sorted by their larger radius descending, their grid
/// (shared with the mesh), and the wood mesh on it.
type WoodLayout = (Vec<[u32; 4]>, PositionGrid, Vec<[u32; 3]>);

/// Set in a compact wood segment's fourth word (the low bit of its start
/// radius code) where its start is the end of another segment running on
/// in nearly its direction ([`wood_joints`]).
pub const WOOD_JOINED_START: u32 = 1;

/// Set in a compact wood segment's fourth word (the low bit of its end
/// radius code) where its end is the start of another segment running on
/// in nearly its direction ([`wood_joints`]).
pub const WOOD_JOINED_END: u32 = 1 << 16;

/// The bits of a compact wood segment's radius code that hold the radius
/// (its low bit is a joint's).
pub const WOOD_RADIUS_CODE_MASK: u32 = 0xfffe;

/// The cosine of the largest turn between a segment and the next one at
/// which the two still count as one strip (30°): a branch bends a few
/// degrees between its segments; a branch leaving another leaves at 40° or
/// more.
pub const WOOD_JOINT_MIN_COSINE: f32 = 0.866_025_4;

/// The larger of a compact wood segment's two radius codes.
fn wood_radius_code(w: &[u32; 4]) -> u32 {
    (w[3] & WOOD_RADIUS_CODE_MASK).max((w[3] >> 16) & WOOD_RADIUS_CODE_MASK)
}

/// Which ends of each segment (given by its ends' grid codes and its
/// larger radius) go on into another segment as one strip. An end is
/// joined where another segment starts exactly there (the same grid
/// point) turning from this one by at most 30° ([`WOOD_JOINT_MIN_COSINE`]),
/// and where the run of such segments behind the joint and the run ahead of
/// it are each at least as long as the wider segment's diameter; that
/// segment's start is joined with it. A wide wood line covers the pixels
/// owned by its joined ends by its strip extended [`JOINT_REACH`] pixels
/// past them ([`super::raster::joined_line_pixel_coverage`]), and it is
/// only wide (past one pixel) where a pixel is narrower than its
/// diameter: the run beyond reaches that far, and the extension does not
/// pass an open end (a trunk's first short pieces, a branch's tip).
///
/// [`JOINT_REACH`]: super::raster::JOINT_REACH
pub fn wood_joints(ends: &[[[u16; 3]; 2]], radii: &[f32], grid: &PositionGrid) -> Vec<LineJoints> {
    let points: Vec<[Vec3; 2]> = ends.iter().map(|e| [grid.decode(e[0]), grid.decode(e[1])]).collect();
    let length = |k: usize| points[k][0].distance(points[k][1]);
    let direction = |k: usize| (points[k][1] - points[k][0]).normalize_or_zero();
    let mut starting_at: HashMap<[u16; 3], Vec<usize>> = HashMap::new();
    let mut ending_at: HashMap<[u16; 3], Vec<usize>> = HashMap::new();
    for (k, e) in ends.iter().enumerate() {
        starting_at.entry(e[0]).or_default().push(k);
        ending_at.entry(e[1]).or_default().push(k);
    }
    // The segments that carry each segment on past its end (`ahead`) and
    // back past its start (`behind`), found once.
    let onward = |k: usize, at: [u16; 3], map: &HashMap<[u16; 3], Vec<usize>>| -> Vec<usize> {
        map.get(&at)
            .into_iter()
            .flatten()
            .copied()
            .filter(|&j| j != k && direction(k).dot(direction(j)) >= WOOD_JOINT_MIN_COSINE)
            .collect()
    };
    let ahead: Vec<Vec<usize>> = (0..ends.len()).map(|k| onward(k, ends[k][1], &starting_at)).collect();
    let behind: Vec<Vec<usize>> = (0..ends.len()).map(|k| onward(k, ends[k][0], &ending_at)).collect();
    // Whether the run from segment `k` on (through `ways`, ahead or
    // behind) reaches `needed` metres: its own length, then the longest
    // way on.
    let reaches = |k: usize, ways: &[Vec<usize>], needed: f32| -> bool {
        let mut run = 0.0;
        let mut here = k;
        for _ in 0..ends.len() {
            run += length(here);
            if run >= needed {
                return true;
            }
            match ways[here]
                .iter()
                .copied()
                .max_by(|&a, &b| length(a).total_cmp(&length(b)))
            {
                Some(next) => here = next,
                None => return false,
            }
        }
        false
    };
    let mut joints = vec![LineJoints::NONE; ends.len()];
    for k in 0..ends.len() {
        for &next in &ahead[k] {
            let needed = 2.0 * radii[k].max(radii[next]);
            if reaches(k, &behind, needed) && reaches(next, &ahead, needed) {
                joints[k].end = true;
                joints[next].start = true;
            }
        }
    }
    joints
}

fn wood_layout(wood: &[WoodSegment], mesh: &TriangleMesh) -> Result<WoodLayout, CompactError> {
    let valid: Vec<&WoodSegment> = wood.iter().filter(|w| w.is_valid()).collect();
    let points = valid
        .iter()
        .flat_map(|w| [w.start, w.end])
        .chain(mesh.positions.iter().copied());
    let wood_grid = if valid.is_empty() && mesh.positions.is_empty() {
        PositionGrid {
            origin: Vec3::ZERO,
            step: 1.0,
        }
    } else {
        PositionGrid::covering(points).ok_or(CompactError::OutOfRange("wood"))?
    };
    // Rounded up to an even code: the low bit is the joint's.
    let radius_code = |r: f32| {
        log_encode_at_least(r)
            .and_then(|code| code.checked_add(code & 1))
            .map(u32::from)
            .ok_or(CompactError::OutOfRange("wood radius"))
    };
    let ends: Vec<[[u16; 3]; 2]> = valid
        .iter()
        .map(|w| [wood_grid.encode(w.start), wood_grid.encode(w.end)])
        .collect();
    let radii: Vec<f32> = valid.iter().map(|w| w.start_radius.max(w.end_radius)).collect();
    let joints = wood_joints(&ends, &radii, &wood_grid);
    let mut wood_segments = Vec::with_capacity(valid.len());
    for ((w, [start, end]), joint) in valid.iter().zip(&ends).zip(&joints) {
        let [sx, sy, sz] = start.map(u32::from);
        let [ex, ey, ez] = end.map(u32::from);
        let mut radii = radius_code(w.start_radius)? | radius_code(w.end_radius)? << 16;
        if joint.start {
            radii |= WOOD_JOINED_START;
        }
        if joint.end {
            radii |= WOOD_JOINED_END;
        }
        wood_segments.push([sx | sy << 16, sz | ex << 16, ey | ez << 16, radii]);
    }
    // Stable: segments of one radius keep the record's order.
    wood_segments.sort_by_key(|w| std::cmp::Reverse(wood_radius_code(w)));
    let wood_vertices = mesh
        .positions
        .iter()
        .zip(&mesh.normals)
        .map(|(&p, &normal)| {
            let [x, y, z] = wood_grid.encode(p).map(u32::from);
            [x | y << 16, z, u32::from_le_bytes(file::encode_normal(normal))]
        })
        .collect();
    Ok((wood_segments, wood_grid, wood_vertices))
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
        let spreads = merged_spreads(record);
        for (m, line) in record.merged.iter().enumerate() {
            let node = (n + m) as u32;
            let (own, parent) = merged_line_codes(record, node)?;
            merged_code_range = [merged_code_range[0].min(own), merged_code_range[1].max(own)];
            if parent <= own {
                continue;
            }
            let width = merged_line_width(record, node)?;
            let [(a, _), (b, _)] = record.node_ends(node);
            let alignment = spreads[m].alignment(b - a);
            let end = |e: u32| end_reference(compact_of[(e / 2) as usize], e % 2 == 1);
            merged.push((
                parent,
                node,
                merged_line_words(line.ends.map(end), width, alignment, own, parent),
            ));
        }
        merged.sort_by_key(|&(parent, node, _)| (std::cmp::Reverse(parent), node));
        if merged_code_range[0] > merged_code_range[1] {
            merged_code_range = [0, 0];
        }
        let (wood_segments, wood_grid, wood_vertices) = wood_layout(&record.wood, &record.wood_mesh)?;
        let (original_len, merged_len) = (original.len() as u32, merged.len() as u32);
        Ok(Self {
            grid,
            max_sides: record.max_sides,
            needles,
            needle_source,
            original_lines: original.into_iter().map(|(_, k)| k).collect(),
            merged_source: merged.iter().map(|&(_, node, _)| node).collect(),
            merged_lines: merged.into_iter().map(|(_, _, words)| words).collect(),
            merged_by_own: Vec::new(),
            wood_segments,
            wood_grid,
            wood_vertices,
            wood_indices: record.wood_mesh.indices.clone(),
            merged_code_range,
            tree_counts: [n as u32, original_len, merged_len],
            prototypes: Vec::new(),
            placements: Vec::new(),
            tree_spheres: Vec::new(),
            tree_line_parents: Vec::new(),
            tree_sphere: Sphere::default(),
            far_needle_color: Vec3::from_slice(&record.material.needle_color[..3]),
        })
    }

    /// Bytes of the arrays.
    pub fn bytes(&self) -> CompactBytes {
        CompactBytes {
            needles: 16 * self.needles.len() as u64,
            original_lines: 4 * (self.original_lines.len() + self.merged_by_own.len()) as u64,
            merged_lines: 12 * self.merged_lines.len() as u64,
            wood: 16 * self.wood_segments.len() as u64
                + 12 * self.wood_vertices.len() as u64
                + 4 * self.wood_indices.len() as u64,
            placements: 96 * self.prototypes.len() as u64 + 48 * self.placements.len() as u64,
            spheres: 16 * self.tree_spheres.len() as u64 + 4 * self.tree_line_parents.len() as u64,
        }
    }

    /// Compact wood segment `s` as the shaders decode it: its ends (tree
    /// metres) and their radii.
    pub fn wood_segment(&self, s: usize) -> ([Vec3; 2], [f32; 2]) {
        let [w0, w1, w2, w3] = self.wood_segments[s];
        let start = self
            .wood_grid
            .decode([w0 & 0xffff, w0 >> 16, w1 & 0xffff].map(|c| c as u16));
        let end = self
            .wood_grid
            .decode([w1 >> 16, w2 & 0xffff, w2 >> 16].map(|c| c as u16));
        (
            [start, end],
            [
                shader_log_decode(w3 & WOOD_RADIUS_CODE_MASK),
                shader_log_decode((w3 >> 16) & WOOD_RADIUS_CODE_MASK),
            ],
        )
    }

    /// Which ends of compact wood segment `s` go on into another segment
    /// of its branch ([`wood_joints`]), as the shaders read them.
    pub fn wood_joints(&self, s: usize) -> LineJoints {
        let w3 = self.wood_segments[s][3];
        LineJoints {
            start: w3 & WOOD_JOINED_START != 0,
            end: w3 & WOOD_JOINED_END != 0,
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
        shader_log_decode(self.merged_width_code(m))
    }

    /// The 16-bit width code merged line `m` keeps (its low bits zero).
    pub fn merged_width_code(&self, m: usize) -> u32 {
        let [a, b, _] = self.merged_lines[m];
        (a >> 24 | ((b >> 24) & 0xf) << 8) << WIDTH_DROPPED_BITS
    }

    /// The alignment of merged line `m`'s needles with it, as the shader
    /// decodes it ([`AxisSpread::alignment`], to half a 4-bit step).
    pub fn merged_alignment(&self, m: usize) -> f32 {
        shading::alignment_from_code(self.merged_lines[m][1] >> 28)
    }

    /// The prefix of every tree-level array a view at threshold code `code`
    /// and spatial error `e` draws from (binary searches, as the compute
    /// pass does).
    pub fn prefixes(&self, code: u16, e: f32) -> Prefixes {
        let [needles, original, merged] = self.tree_counts;
        let section = self.section_prefixes([0, needles], [0, original], [0, merged], None, code);
        let wood_error = |w: &[u32; 4]| line_error(shader_log_decode(wood_radius_code(w)));
        Prefixes {
            prisms: section.prisms,
            original_lines: section.original_lines(),
            original_from_needles: section.original_from_needles(),
            merged_lines: section.merged_lines,
            wood_prisms: self.wood_segments.partition_point(|w| e < wood_error(w)) as u32,
            wood_lines: self
                .wood_segments
                .partition_point(|w| e < WOOD_LINE_FADE * wood_error(w)) as u32,
        }
    }

    /// The prefixes of prototype `k`'s sections at threshold code `code`.
    pub fn prototype_prefixes(&self, k: usize, code: u16) -> SectionPrefixes {
        let p = &self.prototypes[k];
        self.section_prefixes(p.needles, p.original_lines, p.merged_lines, Some(p.merged_by_own), code)
    }

    /// The line draw of an expanded placement of prototype `k` at
    /// threshold code `code` in a camera's back-to-front order: its merged
    /// lines, then its original lines. `from_needles` and `merged_by_own`
    /// are the choices of the instanced draw it belongs to (its prototype
    /// and band: [`SectionPrefixes::original_from_needles`],
    /// [`SectionPrefixes::merged_from_own`] at the band's lowest code).
    /// CPU reference of `conifer_cull.wgsl`'s `scatter_placements` and
    /// `conifer_compact.wgsl`'s `CONIFER_LINES_BY_ENTRY`.
    pub fn entry_lines(&self, k: usize, code: u16, from_needles: bool, merged_by_own: bool) -> EntryLines {
        let prototype = &self.prototypes[k];
        let own = self.prototype_prefixes(k, code);
        let (original_first, original) = if from_needles {
            (prototype.needles[0] + own.prisms, own.after_prisms)
        } else {
            (prototype.original_lines[0], own.original_by_parent)
        };
        // The GPU's line orders: the original lines', then the merged
        // lines' by own code.
        let (merged_first, merged) = if merged_by_own {
            (
                self.original_lines.len() as u32 + prototype.merged_by_own,
                own.merged_by_own,
            )
        } else {
            (prototype.merged_lines[0], own.merged_lines)
        };
        EntryLines {
            merged_first,
            merged,
            original_first,
            original,
        }
    }

    /// Binary searches of one section (`[first, length]` of each array;
    /// `merged_by_own`, the section's first entry of
    /// [`CompactSpecies::merged_by_own`], if it has that order).
    fn section_prefixes(
        &self,
        needles: [u32; 2],
        original: [u32; 2],
        merged: [u32; 2],
        merged_by_own: Option<u32>,
        code: u16,
    ) -> SectionPrefixes {
        let range = |[first, length]: [u32; 2]| first as usize..(first + length) as usize;
        let prisms = self.needles[range(needles)].partition_point(|w| (w[3] & 0xffff) as u16 > code) as u32;
        SectionPrefixes {
            prisms,
            after_prisms: needles[1] - prisms,
            original_by_parent: self.original_lines[range(original)]
                .partition_point(|&k| self.needle_parent_code(k) > code) as u32,
            merged_lines: self.merged_lines[range(merged)].partition_point(|w| (w[2] >> 16) as u16 > code) as u32,
            merged_by_own: match merged_by_own {
                Some(first) => self.merged_by_own[range([first, merged[1]])]
                    .partition_point(|&m| self.merged_codes(m as usize).0 <= code)
                    as u32,
                None => merged[1],
            },
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

/// Lower edges of a prototype's [`PLACED_BANDS`] bands: where to split its
/// threshold codes so that the instanced draw of a band, which processes
/// the longest of each prefix its placements need, costs no placement
/// more than `r` times its own prefixes, for the smallest `r` (within
/// 0.1 %) that [`PLACED_BANDS`] bands allow.
///
/// `codes` are ascending, start at 0, and every prefix is constant from
/// one to the next ([`CompactSpecies::prototype_codes`]); `prefixes[i]` is
/// the section's at `codes[i]`; `cost` weighs a draw of prefixes (its
/// vertices). Edges are codes of `codes`, ascending; the unused ones are
/// `u16::MAX` (above every threshold code). A band is a run of codes, and
/// a longer run never costs less, so greedily extending each band as far
/// as `r` allows gives the fewest bands for that `r`; `r` is bisected.
pub fn band_edges(
    codes: &[u16],
    prefixes: &[SectionPrefixes],
    cost: impl Fn(&SectionPrefixes) -> u64,
) -> [u16; PLACED_BANDS as usize - 1] {
    let needs: Vec<f64> = prefixes.iter().map(|p| cost(p).max(1) as f64).collect();
    let split = |ratio: f64| -> Vec<u16> {
        let mut edges = Vec::new();
        let Some(&first) = prefixes.first() else {
            return edges;
        };
        let (mut longest, mut least) = (first, needs[0]);
        for i in 1..prefixes.len().min(codes.len()) {
            let (joined, need) = (longest.max(prefixes[i]), least.min(needs[i]));
            if cost(&joined) as f64 > ratio * need {
                edges.push(codes[i]);
                (longest, least) = (prefixes[i], needs[i]);
            } else {
                (longest, least) = (joined, need);
            }
        }
        edges
    };
    let fits = |ratio: f64| split(ratio).len() < PLACED_BANDS as usize;
    let (mut lo, mut hi) = (1.0f64, needs.iter().fold(1.0f64, |a, &b| a.max(b)) + 1.0);
    if !fits(lo) {
        while hi / lo > 1.001 {
            let mid = (lo * hi).sqrt();
            if fits(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        lo = hi;
    }
    let edges = split(lo);
    std::array::from_fn(|b| edges.get(b).copied().unwrap_or(u16::MAX))
}

/// One instanced draw of a placed species' view (per prototype and band):
/// how many expanded placements it holds and the longest prefix of each of
/// the prototype's sections they need (what `conifer_cull.wgsl`'s
/// `count_placements` and `scan_placements` write).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlacedDraw {
    /// Expanded placements in the draw (its instance count).
    pub placements: u32,
    /// Each prefix the longest any of them needs (original lines from the
    /// needles after the fewest prisms or by parent code, the shorter).
    pub longest: SectionPrefixes,
}

impl PlacedDraw {
    /// Adds a placement needing `prefixes`.
    pub fn add(&mut self, prefixes: SectionPrefixes) {
        self.placements += 1;
        self.longest = self.longest.max(prefixes);
    }
}

/// What one view draws of a placed tree: the expanded placements with
/// their threshold codes and draws, as the compute passes find them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlacedView {
    /// `(placement index, threshold code, draw)` of each expanded placement.
    pub expanded: Vec<(u32, u16, usize)>,
    /// One draw per `prototype · PLACED_BANDS + band`
    /// ([`CompactSpecies::placed_draw_index`]).
    pub draws: Vec<PlacedDraw>,
}

impl CompactSpecies {
    /// The compact layout of a tree of shared prototypes: the tree's own
    /// section holds its level-2 merged lines (each with its two ends as a
    /// needle that is never drawn) and wood; each prototype's needles and
    /// level-1 lines are stored once, in its own frame, and placed by the
    /// GPU. The tree is never flattened: the level-2 lines' ends are placed
    /// from their prototypes and their areas are the placements' scaled
    /// ([`PrototypeRecord::tree_node_areas`]); node ids are those of
    /// [`PrototypeRecord::flatten`].
    ///
    /// A record whose prototypes are not shared (every placement its own
    /// prototype) or that has more than [`MAX_PLACED_PROTOTYPES`]
    /// prototypes or [`MAX_PLACEMENTS`] placements gets the flat layout
    /// ([`CompactSpecies::build`]) of its flattened tree.
    pub fn build_placed(record: &PrototypeRecord) -> Result<Self, CompactError> {
        let k_count = record.prototypes.len();
        let p_count = record.placements.len();
        if k_count >= p_count || k_count > MAX_PLACED_PROTOTYPES || p_count > MAX_PLACEMENTS {
            return Self::build(&record.flatten()?);
        }
        let level2_first = record.flat_tree_node(p_count as u32);
        let areas = record.tree_node_areas();
        let spreads = record.tree_node_spreads();
        // Code of level-2 node `node`'s parent, as `parent_code` gives the
        // flattened node's.
        let tree_parent_code = |node: u32| -> Result<u16, CompactError> {
            match record.tree_parent(node) {
                NO_PARENT => Ok(ROOT_PARENT_CODE),
                parent => error_code(record.tree_merged[parent as usize - p_count].error),
            }
        };
        // The tree's section: a pseudo-needle per drawable level-2 line,
        // holding its ends, with line-error code 0 (never a prism or an
        // original line).
        let mut ends = Vec::new();
        let mut lines = Vec::new();
        let mut merged_code_range = [u16::MAX, 0];
        for k in 0..record.tree_merged.len() as u32 {
            let node = p_count as u32 + k;
            let own = error_code(record.tree_merged[k as usize].error)?;
            let parent = tree_parent_code(node)?;
            merged_code_range = [merged_code_range[0].min(own), merged_code_range[1].max(own)];
            // A line whose error code equals its parent's is never in a cut
            // at one code; seen from a camera, its children test its
            // nearest drawable ancestor's sphere instead (below).
            if parent <= own {
                continue;
            }
            let [a, b] = record.tree_merged[k as usize]
                .ends
                .map(|e| record.endpoint_position(e).ok_or(CompactError::OutOfRange("line ends")));
            let (a, b) = (a?, b?);
            let width = line_width_code(areas[node as usize], a.distance(b))?;
            let alignment = spreads[node as usize].alignment(b - a);
            ends.push([a, b]);
            lines.push((parent, own, width, alignment, level2_first + k));
        }
        if merged_code_range[0] > merged_code_range[1] {
            merged_code_range = [0, 0];
        }
        let mut order: Vec<usize> = (0..lines.len()).collect();
        order.sort_by_key(|&i| (std::cmp::Reverse(lines[i].0), lines[i].4));
        let grid = PositionGrid::covering(ends.iter().flatten().copied().chain(std::iter::once(Vec3::ZERO)))
            .ok_or(CompactError::OutOfRange("needle positions"))?;
        let (wood_segments, wood_grid, wood_vertices) = wood_layout(&record.wood, &record.wood_mesh)?;
        let mut species = Self {
            grid,
            max_sides: record.max_sides,
            needles: Vec::new(),
            needle_source: Vec::new(),
            original_lines: Vec::new(),
            merged_lines: Vec::new(),
            merged_source: Vec::new(),
            merged_by_own: Vec::new(),
            wood_segments,
            wood_grid,
            wood_vertices,
            wood_indices: record.wood_mesh.indices.clone(),
            merged_code_range,
            tree_counts: [0; 3],
            prototypes: Vec::new(),
            placements: Vec::new(),
            tree_spheres: Vec::new(),
            tree_line_parents: Vec::new(),
            tree_sphere: record.tree_sphere(),
            far_needle_color: super::color::far_needle_color(record),
        };
        for (slot, &i) in order.iter().enumerate() {
            let (parent, own, width, alignment, node) = lines[i];
            let [a, b] = ends[i];
            let [ax, ay, az] = grid.encode(a).map(u32::from);
            let [bx, by, bz] = grid.encode(b).map(u32::from);
            species.needles.push([ax | ay << 16, az | bx << 16, by | bz << 16, 0]);
            species.needle_source.push(node);
            let slot = slot as u32;
            let ends = [end_reference(slot, false), end_reference(slot, true)];
            species
                .merged_lines
                .push(merged_line_words(ends, width, alignment, own, parent));
            species.merged_source.push(node);
        }
        species.merged_code_range = merged_code_range;
        species.tree_counts = [species.needles.len() as u32, 0, species.merged_lines.len() as u32];
        // Spheres, in the lines' order. A node's parent sphere is its
        // nearest drawable ancestor's: a line whose code equals its
        // parent's is left out of the arrays, and as the codes along such a
        // chain are equal, testing the drawable ancestor's sphere with the
        // node's parent code is testing that ancestor, whose sphere holds
        // the node's: the hierarchy without those lines is still monotone.
        let p_node = record.placements.len() as u32;
        let mut sphere_of = vec![NO_SPHERE; record.tree_merged.len()];
        for &i in &order {
            let k = (lines[i].4 - level2_first) as usize;
            sphere_of[k] = species.tree_spheres.len() as u32;
            species.tree_spheres.push(record.node_sphere(p_node + k as u32));
        }
        let parent_sphere = |node: u32| {
            let mut ancestor = record.tree_parent(node);
            while ancestor != NO_PARENT && sphere_of[(ancestor - p_node) as usize] == NO_SPHERE {
                ancestor = record.tree_parent(ancestor);
            }
            match ancestor {
                NO_PARENT => NO_SPHERE,
                ancestor => sphere_of[(ancestor - p_node) as usize],
            }
        };
        species.tree_line_parents = order
            .iter()
            .map(|&i| parent_sphere(p_node + lines[i].4 - level2_first))
            .collect();
        // The prototypes' sections, each built as a one-prototype record.
        for prototype in &record.prototypes {
            let alone = PrototypeRecord::from_parts(
                String::new(),
                vec![prototype.clone()],
                vec![Placement::identity(0)],
                Vec::new(),
                Vec::new(),
                Default::default(),
                record.material,
                record.max_sides,
                record.bake.clone(),
            )
            .and_then(|r| r.flatten())
            .map_err(|_| CompactError::OutOfRange("prototypes"))?;
            let section = Self::build(&alone)?;
            let needle_first = species.needles.len() as u32;
            if needle_first as usize + section.needles.len() > MAX_COMPACT_NEEDLES {
                return Err(CompactError::TooManyNeedles(
                    needle_first as usize + section.needles.len(),
                ));
            }
            let first = |len: usize, count: usize| [len as u32, count as u32];
            let merged_first = species.merged_lines.len() as u32;
            let mut by_own: Vec<u32> = (0..section.merged_lines.len() as u32).collect();
            by_own.sort_by_key(|&m| (section.merged_codes(m as usize).0, m));
            species.prototypes.push(CompactPrototype {
                grid: section.grid,
                sphere: record.prototype_sphere(species.prototypes.len()),
                needles: first(species.needles.len(), section.needles.len()),
                original_lines: first(species.original_lines.len(), section.original_lines.len()),
                merged_lines: first(species.merged_lines.len(), section.merged_lines.len()),
                merged_by_own: species.merged_by_own.len() as u32,
                // Filled in below, once the arrays hold the section.
                band_edges: [u16::MAX; PLACED_BANDS as usize - 1],
                upper_side: super::color::upper_side(&prototype.needles),
            });
            species.merged_by_own.extend(by_own.iter().map(|m| m + merged_first));
            species.needles.extend(&section.needles);
            species.needle_source.extend(&section.needle_source);
            species
                .original_lines
                .extend(section.original_lines.iter().map(|k| k + needle_first));
            species
                .merged_lines
                .extend(section.merged_lines.iter().map(|&[a, b, codes]| {
                    let shift = |w: u32| (w & 0xff00_0000) | ((w & 0x00ff_ffff) + 2 * needle_first);
                    [shift(a), shift(b), codes]
                }));
            species.merged_source.extend(&section.merged_source);
        }
        let prism_vertices = super::prism::prism_slot_vertices(species.max_sides);
        for k in 0..species.prototypes.len() {
            let codes = species.prototype_codes(k);
            let prefixes: Vec<SectionPrefixes> = codes.iter().map(|&c| species.prototype_prefixes(k, c)).collect();
            let edges = band_edges(&codes, &prefixes, |p| p.vertices(prism_vertices));
            species.prototypes[k].band_edges = edges;
        }
        // Placements by their root's parent code, descending.
        for (p, placement) in record.placements.iter().enumerate() {
            species.placements.push(CompactPlacement {
                prototype: placement.prototype,
                transform: *placement,
                parent_code: tree_parent_code(p as u32)?,
                parent_sphere: parent_sphere(p as u32),
                source: p as u32,
            });
        }
        species
            .placements
            .sort_by_key(|p| (std::cmp::Reverse(p.parent_code), p.source));
        Ok(species)
    }

    /// The threshold codes at which one of prototype `k`'s prefixes
    /// changes (its needles' and merged lines' own and parent codes, and
    /// 0), ascending: every prefix is constant between two of them.
    pub fn prototype_codes(&self, k: usize) -> Vec<u16> {
        let p = &self.prototypes[k];
        let needles = p.needles[0]..p.needles[0] + p.needles[1];
        let merged = p.merged_lines[0]..p.merged_lines[0] + p.merged_lines[1];
        let mut codes: Vec<u16> = std::iter::once(0)
            .chain(needles.flat_map(|n| [self.needle_line_code(n), self.needle_parent_code(n)]))
            .chain(merged.flat_map(|m| {
                let (own, parent) = self.merged_codes(m as usize);
                [own, parent]
            }))
            .filter(|&c| c <= MAX_THRESHOLD_CODE)
            .collect();
        codes.sort_unstable();
        codes.dedup();
        codes
    }

    /// Placements a view at threshold code `code` expands (a prefix).
    pub fn expanded_placements(&self, code: u16) -> u32 {
        self.placements.partition_point(|p| p.parent_code > code) as u32
    }

    /// The band of prototype `k` a placement at threshold code `code` is drawn in.
    pub fn placement_band(&self, k: usize, code: u16) -> u32 {
        self.prototypes[k]
            .band_edges
            .iter()
            .filter(|&&edge| edge <= code)
            .count() as u32
    }

    /// The draw (`prototype · PLACED_BANDS + band`) a placement of
    /// prototype `k` at threshold code `code` is drawn by.
    pub fn placed_draw_index(&self, k: usize, code: u16) -> usize {
        k * PLACED_BANDS as usize + self.placement_band(k, code) as usize
    }

    /// Spatial error (tree metres) of what `sphere` bounds, seen from
    /// `view`: its nearest point's, or the tree sphere's for a camera
    /// beyond [`super::view::VIEW_RANGE`] (as `conifer_cull.wgsl` computes it).
    pub fn sphere_error(&self, view: &ViewPoint, sphere: &Sphere) -> f32 {
        view.node_error(&self.tree_sphere, sphere)
    }

    /// Spatial error (tree metres) a view gives placement entry `j`: the
    /// tree's `e`, or from `seen`, its own sphere's.
    pub fn placement_error(&self, j: usize, e: f32, seen: Option<&ViewPoint>) -> f32 {
        let placement = &self.placements[j];
        match seen {
            None => e,
            Some(view) => {
                let sphere = self.prototypes[placement.prototype as usize]
                    .sphere
                    .placed(&placement.transform);
                self.sphere_error(view, &sphere)
            }
        }
    }

    /// `true` when a view seen from `seen` leaves placement entry `j`
    /// unexpanded although the tree's code (a lower bound of every node's)
    /// reaches it: its parent's sphere is far enough for the parent line.
    pub fn parent_accepted(&self, j: usize, seen: Option<&ViewPoint>, threshold: fn(f32) -> u16) -> bool {
        let placement = &self.placements[j];
        match seen {
            Some(view) if placement.parent_sphere != NO_SPHERE => {
                let sphere = self.tree_spheres[placement.parent_sphere as usize];
                threshold(self.sphere_error(view, &sphere)) >= placement.parent_code
            }
            _ => false,
        }
    }

    /// What the compute passes find for one tree at spatial error `e`
    /// (tree metres) and threshold code `code`: each expanded placement's
    /// own threshold code (`threshold(e / scale)`), and the per-draw counts
    /// and longest prefixes. Seen from `seen` (view-dependent detail), `e`
    /// and `code` are the tree sphere's; a placement whose parent is
    /// accepted at its own sphere's error is dropped, and each kept one
    /// takes its own sphere's error.
    pub fn placed_view(&self, code: u16, e: f32, threshold: fn(f32) -> u16, seen: Option<&ViewPoint>) -> PlacedView {
        let mut view = PlacedView {
            expanded: Vec::new(),
            draws: vec![PlacedDraw::default(); self.prototypes.len() * PLACED_BANDS as usize],
        };
        for j in 0..self.expanded_placements(code) {
            if self.parent_accepted(j as usize, seen, threshold) {
                continue;
            }
            let placement = &self.placements[j as usize];
            let c = threshold(self.placement_error(j as usize, e, seen) / placement.transform.scale);
            let k = placement.prototype as usize;
            let draw = self.placed_draw_index(k, c);
            view.draws[draw].add(self.prototype_prefixes(k, c));
            view.expanded.push((j, c, draw));
        }
        view
    }

    /// What the vertex shaders draw of a placed tree at threshold code
    /// `code` and spatial error `e`: the tree's level-2 lines and, for each
    /// expanded placement, its draw's prefixes filtered by the placement's
    /// own threshold code, as a [`Cut`] in `record.flatten()`'s ids; and
    /// how many primitives the draws processed. Seen from `seen`, each
    /// level-2 line is kept by its own and its parent's sphere's codes
    /// (see [`CompactSpecies::placed_view`] for the placements).
    pub fn placed_drawn(
        &self,
        record: &PrototypeRecord,
        code: u16,
        e: f32,
        threshold: fn(f32) -> u16,
        seen: Option<&ViewPoint>,
    ) -> (Cut, u64) {
        let mut cut = self.drawn(code, e);
        let tree = self.prefixes(code, e);
        if let Some(view) = seen {
            cut.merged_lines.clear();
            for m in 0..tree.merged_lines as usize {
                let (own, parent) = self.merged_codes(m);
                let own_code = threshold(self.sphere_error(view, &self.tree_spheres[m]));
                let parent_code = match self.tree_line_parents[m] {
                    NO_SPHERE => 0,
                    k => threshold(self.sphere_error(view, &self.tree_spheres[k as usize])),
                };
                if own <= own_code && parent_code < parent {
                    cut.merged_lines.push(self.merged_source[m]);
                }
            }
        }
        let mut processed = u64::from(tree.merged_lines);
        let view = self.placed_view(code, e, threshold, seen);
        for &(j, c, draw) in &view.expanded {
            let placement = &self.placements[j as usize];
            let prototype = &self.prototypes[placement.prototype as usize];
            let draw = view.draws[draw].longest;
            let name = |local: u32| record.flat_local(placement.source as usize, local);
            let placed_e = self.placement_error(j as usize, e, seen) / placement.transform.scale;
            let first_needle = prototype.needles[0];
            for i in 0..draw.prisms {
                let needle = first_needle + i;
                if c < self.needle_line_code(needle) {
                    let sides = metric::prism_sides(
                        metric::relative_error(placed_e, self.needle_radius(needle)),
                        self.max_sides,
                    );
                    cut.prisms.push((name(self.needle_source[needle as usize]), sides));
                }
            }
            let original: Vec<u32> = if draw.original_from_needles() {
                let first = first_needle + prototype.needles[1] - draw.after_prisms;
                (first..first + draw.after_prisms).collect()
            } else {
                let first = prototype.original_lines[0] as usize;
                self.original_lines[first..first + draw.original_by_parent as usize].to_vec()
            };
            for needle in original {
                if self.needle_line_code(needle) <= c && c < self.needle_parent_code(needle) {
                    cut.original_lines.push(name(self.needle_source[needle as usize]));
                }
            }
            let merged: Vec<usize> = if draw.merged_from_own() {
                let first = prototype.merged_by_own as usize;
                self.merged_by_own[first..first + draw.merged_by_own as usize]
                    .iter()
                    .map(|&m| m as usize)
                    .collect()
            } else {
                let first = prototype.merged_lines[0] as usize;
                (first..first + draw.merged_lines as usize).collect()
            };
            for m in merged {
                let (own, parent) = self.merged_codes(m);
                if own <= c && c < parent {
                    cut.merged_lines.push(name(self.merged_source[m]));
                }
            }
            processed += u64::from(draw.total());
        }
        (cut, processed)
    }
}

/// PCG hash (Jarzynski and Olano, *Hash Functions for GPU Rendering*,
/// JCGT 2020), as `conifer_compact.wgsl` computes it.
pub fn pcg_hash(value: u32) -> u32 {
    let state = value.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// CPU reference of the lines' shadow test (`conifer_compact.wgsl`):
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
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};
    use crate::model::prototype::PrototypeRecord;
    use crate::model::{BakeOptions, bake};

    fn record(needles: usize, seed: u64) -> LodRecord {
        let options = GenerateOptions {
            seed,
            target_needles: Some(needles),
            age: crate::generate::Age::Young,
        };
        bake(&generate(Species::ScotsPine, &options), &BakeOptions::default(), &()).expect("bake")
    }

    /// The needles a node of `record` stands for.
    fn node_needles(record: &LodRecord, node: u32) -> Vec<u32> {
        let n = record.needle_count() as u32;
        let mut stack = vec![node];
        let mut needles = Vec::new();
        while let Some(x) = stack.pop() {
            if x < n {
                needles.push(x);
            } else {
                stack.extend(record.merged[(x - n) as usize].children);
            }
        }
        needles
    }

    /// Every merged line keeps its width to 0.4 % (12 bits of its code)
    /// and its needles' alignment with it to half a 4-bit step, against
    /// the needles it stands for summed anew; on real trees the bundle
    /// those store lights a merged line closer to the mean of its needles'
    /// cylinders than the chord's cylinder alone (area-weighted mean
    /// |error| of the Lambert factor over views and suns round the tree).
    #[test]
    fn merged_lines_keep_their_width_and_their_needles_alignment() {
        let views = [
            Vec3::Z,
            Vec3::X,
            Vec3::new(-0.6, 0.5, -0.62).normalize(),
            Vec3::new(0.3, -0.8, 0.5).normalize(),
        ];
        let suns = [
            Vec3::Y,
            Vec3::new(0.9, 0.26, 0.0).normalize(),
            Vec3::new(-0.3, 0.4, -0.86).normalize(),
            Vec3::new(0.5, 0.7, 0.5).normalize(),
        ];
        for species in [Species::ScotsPine, Species::SilverFir, Species::NorwaySpruce] {
            let options = GenerateOptions {
                seed: 3,
                target_needles: Some(3000),
                age: crate::generate::Age::Young,
            };
            let record = bake(&generate(species, &options), &BakeOptions::default(), &()).expect("bake");
            let compact = CompactSpecies::build(&record).unwrap();
            assert!(compact.merged_lines.len() > 1000, "{species:?}");
            let (mut chord_error, mut bundle_error, mut weight) = (0.0f64, 0.0f64, 0.0f64);
            let mut aligned = [0usize; 16];
            for m in 0..compact.merged_lines.len() {
                let node = compact.merged_source[m];
                let [(a, _), (b, _)] = record.node_ends(node);
                let chord = b - a;
                let needles = node_needles(&record, node);
                let (mut area, mut moment) = (0.0f64, 0.0f64);
                for &k in &needles {
                    let x = &record.needles[k as usize];
                    let t = (x.tip - x.base).normalize();
                    area += f64::from(x.side_area());
                    moment += f64::from(x.side_area()) * f64::from(t.dot(chord.normalize()).powi(2));
                }
                let exact_alignment = (moment / area) as f32;
                let alignment = compact.merged_alignment(m);
                aligned[(alignment * 15.0).round() as usize] += 1;
                assert!(
                    (alignment - exact_alignment).abs() <= 0.5 / 15.0 + 1e-4,
                    "{species:?} line {m}: {alignment} vs {exact_alignment}"
                );
                let exact_width = record.node_needle_area(node) / chord.length();
                assert!(
                    (compact.merged_width(m) / exact_width - 1.0).abs() < 0.005,
                    "{species:?} line {m}: {} vs {exact_width}",
                    compact.merged_width(m)
                );
                for &v in &views {
                    for &l in &suns {
                        let (mut lit, mut lit_area) = (0.0f64, 0.0f64);
                        for &k in &needles {
                            let x = &record.needles[k as usize];
                            lit +=
                                f64::from(x.side_area()) * f64::from(shading::cylinder_lambert(x.tip - x.base, v, l));
                            lit_area += f64::from(x.side_area());
                        }
                        let exact = lit / lit_area;
                        chord_error += area * (f64::from(shading::cylinder_lambert(chord, v, l)) - exact).abs();
                        bundle_error +=
                            area * (f64::from(shading::bundle_lambert(chord, alignment, v, l)) - exact).abs();
                        weight += area;
                    }
                }
            }
            let (chord_error, bundle_error) = (chord_error / weight, bundle_error / weight);
            println!(
                "{species:?}: {} merged lines, alignment codes {aligned:?}, mean |error| chord {chord_error:.4}, bundle {bundle_error:.4}",
                compact.merged_lines.len()
            );
            assert!(
                bundle_error < 0.8 * chord_error,
                "{species:?}: {bundle_error} vs {chord_error}"
            );
        }
    }

    proptest::proptest! {
        /// The budget goes to the nearest trees: the trees that expand in
        /// buckets below the cutoff fit together, every tree of a lower
        /// bucket than one that expands expands too (but within the
        /// cutoff bucket, where the GPU's order decides), what the
        /// expanding trees take never passes the capacity, and a tree past
        /// the cutoff bucket would not have fitted after the buckets before
        /// it.
        #[test]
        fn the_budget_goes_to_the_nearest_trees(
            trees in proptest::collection::vec((0u16..=65534, 0u32..5000), 0..60),
            capacity in 0u32..40_000,
        ) {
            let expands = budget_expands(&trees, capacity);
            let mut demand = [0u32; BUDGET_BUCKETS];
            for &(code, expanded) in &trees {
                demand[budget_bucket(code)] += expanded;
            }
            let (cutoff, base) = budget_cutoff(&demand, capacity);
            let taken: u64 = trees.iter().zip(&expands).filter(|(_, e)| **e).map(|(t, _)| u64::from(t.1)).sum();
            proptest::prop_assert!(taken <= u64::from(capacity));
            proptest::prop_assert_eq!(u64::from(base), demand[..cutoff].iter().map(|&d| u64::from(d)).sum::<u64>());
            if cutoff < BUDGET_BUCKETS {
                proptest::prop_assert!(u64::from(base) + u64::from(demand[cutoff]) > u64::from(capacity));
            }
            for (i, &(code, expanded)) in trees.iter().enumerate() {
                let bucket = budget_bucket(code);
                if expanded > 0 && bucket != cutoff {
                    proptest::prop_assert_eq!(expands[i], bucket < cutoff);
                }
            }
        }
    }

    /// A cascade's trees share one error; ranked by `budget_error` its
    /// budget goes to the trees nearest its camera, in whatever order the
    /// GPU reaches them, and a tree within the wind's reach of the camera
    /// ranks first.
    #[test]
    fn a_cascade_ranks_its_trees_by_distance_to_its_camera() {
        let slope = 2.0 * 22.5f32.to_radians().tan() / 1080.0;
        let code = |distance: f32| shader_threshold_code(budget_error(distance, 1.5, slope, 1.0, 1.0));
        let distances = [400.0f32, 9.0, 120.0, 1.0, 35.0];
        let trees: Vec<(u16, u32)> = distances.iter().map(|&d| (code(d), 1000)).collect();
        // Room for two trees: the ones 1 and 9 m away.
        assert_eq!(budget_expands(&trees, 2000), vec![false, true, false, true, false]);
        assert_eq!(budget_expands(&trees, 3000), vec![false, true, false, true, true]);
        assert_eq!(budget_error(1.0, 1.5, slope, 1.0, 1.0), 0.0);
        // Larger trees (scale 2) are seen at half the error in their metres.
        assert_eq!(
            budget_error(40.0, 0.0, slope, 1.0, 2.0),
            budget_error(20.0, 0.0, slope, 1.0, 1.0)
        );
        assert!(budget_error(40.0, 0.0, slope, 1.0, 0.0).is_finite());
    }

    #[test]
    fn depth_buckets_grow_with_distance_and_clamp() {
        assert_eq!(depth_bucket(0.0), 0);
        assert_eq!(depth_bucket(-3.0), 0);
        assert_eq!(depth_bucket(f32::NAN), 0);
        assert_eq!(depth_bucket(DEPTH_NEAREST), 0);
        assert_eq!(depth_bucket(f32::INFINITY), DEPTH_BUCKETS - 1);
        assert_eq!(depth_bucket(1e9), DEPTH_BUCKETS - 1);
        // An octave is DEPTH_BUCKETS_PER_OCTAVE buckets.
        assert_eq!(
            depth_bucket(80.0) + DEPTH_BUCKETS_PER_OCTAVE as u32,
            depth_bucket(160.0)
        );
        // A mature crown 12 m across at 80 m spans about 40 buckets.
        let span = depth_bucket(86.0) - depth_bucket(74.0);
        assert!((38..=44).contains(&span), "{span}");
        let mut previous = 0;
        for step in 0..20_000 {
            let bucket = depth_bucket(0.01 * 1.001f32.powi(step));
            assert!(bucket >= previous);
            previous = bucket;
        }
    }

    #[test]
    fn back_to_front_draws_the_farthest_bucket_first_and_keeps_ties() {
        let distances = [5.0, 80.0, 80.0001, 0.01, f32::NAN, 300.0, 79.0];
        let order = back_to_front(&distances);
        assert_eq!(order, vec![5, 1, 2, 6, 0, 3, 4]);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..distances.len()).collect::<Vec<_>>());
        assert!(back_to_front(&[]).is_empty());
    }

    #[test]
    fn the_budget_with_room_for_all_and_for_none() {
        let trees = [(100u16, 10u32), (9000, 20), (40_000, 0), (60_000, 5)];
        assert_eq!(budget_expands(&trees, 35), vec![true; 4]);
        assert_eq!(budget_cutoff(&[0; BUDGET_BUCKETS], 0), (BUDGET_BUCKETS, 0));
        // Room for the nearest only, whichever order the GPU reaches them in.
        let reversed: Vec<(u16, u32)> = trees.iter().rev().copied().collect();
        assert_eq!(budget_expands(&reversed, 12), vec![false, true, false, true]);
        // No room: only trees that expand nothing.
        assert_eq!(budget_expands(&trees, 0), vec![false, false, true, false]);
        // One bucket shared: first come, first served.
        assert_eq!(
            budget_expands(&[(10, 6), (11, 6), (12, 6)], 13),
            vec![true, true, false]
        );
        assert_eq!(budget_bucket(u16::MAX), BUDGET_BUCKETS - 1);
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
    fn slot_prisms_collapse_to_the_cpu_prisms() {
        use crate::model::prism::{append_prism, prism_triangle_count};
        // A vertex as (end, cap, ring corner); triangles rotated to start at
        // their smallest vertex, so the winding is kept.
        type Corner = (bool, bool, u32);
        let canonical = |mut tri: [Corner; 3]| {
            let start = (0..3).min_by_key(|&k| tri[k]).unwrap();
            tri.rotate_left(start);
            tri
        };
        for max_sides in [3u8, 4, 7, 8, 12] {
            for sides in 3..=max_sides {
                let m = u32::from(sides);
                // What the shader draws: `prism_corner`, then slot k moves to
                // corner ⌊k·m/Lmax⌋ (collapsed triangles have no area).
                let mut gpu: Vec<[Corner; 3]> = (0..12 * u32::from(max_sides) - 12)
                    .map(|local| {
                        let (slot, at_tip, cap) = prism_corner(local, max_sides);
                        (at_tip, cap, slot * m / u32::from(max_sides))
                    })
                    .collect::<Vec<_>>()
                    .chunks(3)
                    .map(|t| [t[0], t[1], t[2]])
                    .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                    .map(canonical)
                    .collect();
                // What `append_prism` builds: base ring, tip ring, base cap,
                // tip cap, `m` vertices each.
                let needle = crate::model::Needle {
                    base: Vec3::ZERO,
                    tip: Vec3::Y,
                    radius: 0.01,
                    normal: Vec3::X,
                    group: 0,
                };
                let mut cpu_mesh = TriangleMesh::default();
                append_prism(&mut cpu_mesh, &needle, sides);
                let corner = |i: u32| {
                    let ring = i / m;
                    (ring % 2 == 1, ring >= 2, i % m)
                };
                let mut cpu: Vec<[Corner; 3]> = cpu_mesh
                    .indices
                    .chunks(3)
                    .map(|t| canonical([corner(t[0]), corner(t[1]), corner(t[2])]))
                    .collect();
                assert_eq!(cpu.len() as u32, prism_triangle_count(sides));
                gpu.sort();
                cpu.sort();
                assert_eq!(gpu, cpu, "Lmax {max_sides}, {sides} sides");
            }
        }
    }

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
    proptest::proptest! {
        /// A prism's ring faces the view: its silhouette across the view is
        /// centred on the axis and `2r` wide, the cylinder's: an even ring
        /// inscribed, an odd one's corners at `1/cos(π/2m)` radii.
        #[test]
        fn prism_rings_face_the_view(
            ax in (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0),
            to in (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0),
            sides in 3u8..=12,
        ) {
            let axis = Vec3::new(ax.0, ax.1, ax.2);
            let toward = Vec3::new(to.0, to.1, to.2);
            proptest::prop_assume!(axis.length() > 0.1 && toward.length() > 0.1);
            let axis = axis.normalize();
            proptest::prop_assume!(axis.cross(toward.normalize()).length() > 0.05);
            let (u, v, phase, scale) = prism_ring(axis, toward, sides);
            proptest::prop_assert!(u.dot(axis).abs() < 1e-4 && v.dot(axis).abs() < 1e-4 && u.dot(toward) > 0.0);
            // Corners projected on the sideways axis (what the view sees).
            let m = f32::from(sides);
            let across: Vec<f32> = (0..sides)
                .map(|k| {
                    let angle = std::f32::consts::TAU * f32::from(k) / m + phase;
                    scale * (u * angle.cos() + v * angle.sin()).dot(v)
                })
                .collect();
            let (lo, hi) = across.iter().fold((f32::MAX, f32::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)));
            proptest::prop_assert!((hi - lo - 2.0).abs() < 1e-4, "{sides} sides: {} wide", hi - lo);
            proptest::prop_assert!((1.0..1.16).contains(&scale));
            proptest::prop_assert!((hi + lo).abs() < 1e-4, "centred");
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
    fn wood_segments_take_16_bytes_and_decode_near_the_records() {
        let record = record(4000, 5);
        assert!(record.wood.len() > 50, "{} segments", record.wood.len());
        let compact = CompactSpecies::build(&record).unwrap();
        assert_eq!(compact.wood_segments.len(), record.wood.len());
        let bytes = compact.bytes();
        assert_eq!(bytes.wood, 16 * record.wood.len() as u64);
        // Each record segment is decoded once: ends within half a grid step
        // a coordinate, radii rounded up to an even code (at most two codes,
        // 0.098 %) and decoded in `f32` as the shaders do.
        let mut matched = vec![false; record.wood.len()];
        // (and f32 rounding of the sums).
        let half = 0.5 * compact.wood_grid.step + 1e-6;
        for s in 0..compact.wood_segments.len() {
            let ([a, b], [ra, rb]) = compact.wood_segment(s);
            let k = (0..record.wood.len())
                .find(|&k| {
                    let w = &record.wood[k];
                    !matched[k]
                        && (w.start - a).abs().max_element() <= half
                        && (w.end - b).abs().max_element() <= half
                        && (ra / w.start_radius - 1.0).abs() < 1.5e-3
                        && (rb / w.end_radius - 1.0).abs() < 1.5e-3
                })
                .unwrap_or_else(|| panic!("segment {s} ({a} {b} {ra} {rb}) matches no record segment"));
            matched[k] = true;
        }
        // Sorted by the larger radius, so the prism and line prefixes are
        // exactly the segments the record's error rule keeps.
        let larger = |s: usize| {
            let (_, [ra, rb]) = compact.wood_segment(s);
            ra.max(rb)
        };
        assert!((1..compact.wood_segments.len()).all(|s| larger(s - 1) >= larger(s)));
        for e in [0.0005f32, 0.002, 0.01, 0.05, 0.3] {
            let prefixes = compact.prefixes(MAX_THRESHOLD_CODE, e);
            let prisms = (0..compact.wood_segments.len())
                .filter(|&s| e < 2.0 * larger(s))
                .count();
            let lines = (0..compact.wood_segments.len())
                .filter(|&s| e < WOOD_LINE_FADE * 2.0 * larger(s))
                .count();
            assert_eq!(
                (prefixes.wood_prisms as usize, prefixes.wood_lines as usize),
                (prisms, lines)
            );
        }
    }

    /// A branch's segments end to end are joined where they run on: along
    /// the trunk, wherever at least a diameter of trunk lies behind and
    /// ahead of the joint (not between its first short pieces); a branch
    /// leaving the trunk is not; the joint bits never change a radius.
    #[test]
    fn wood_segments_know_which_ends_run_on() {
        let record = record(4000, 5);
        let compact = CompactSpecies::build(&record).unwrap();
        let count = compact.wood_segments.len();
        let joints: Vec<LineJoints> = (0..count).map(|s| compact.wood_joints(s)).collect();
        let (ends, radii): (Vec<[Vec3; 2]>, Vec<[f32; 2]>) = (0..count).map(|s| compact.wood_segment(s)).unzip();
        let along = |k: usize| (ends[k][1] - ends[k][0]).normalize();
        // Every joined end has its partner, within 30°: a segment whose
        // joined start lies at a joined end, or the other way round.
        let has_partner = |s: usize, at_end: bool| {
            (0..count).any(|k| {
                let meets = if at_end {
                    joints[k].start && ends[k][0] == ends[s][1]
                } else {
                    joints[k].end && ends[k][1] == ends[s][0]
                };
                k != s && meets && along(s).dot(along(k)) >= WOOD_JOINT_MIN_COSINE
            })
        };
        for (s, joint) in joints.iter().enumerate() {
            assert!(!joint.end || has_partner(s, true), "segment {s}'s end");
            assert!(!joint.start || has_partner(s, false), "segment {s}'s start");
        }
        // The trunk: the lowest segment, then up through the segments that
        // start where the last ends, rising.
        let mut trunk = vec![
            (0..count)
                .min_by(|&a, &b| ends[a][0].y.total_cmp(&ends[b][0].y))
                .unwrap(),
        ];
        while let Some(next) = (0..count).find(|&k| {
            ends[k][0] == ends[*trunk.last().unwrap()][1]
                && along(k).dot(along(*trunk.last().unwrap())) >= WOOD_JOINT_MIN_COSINE
        }) {
            trunk.push(next);
        }
        let top = trunk.iter().map(|&k| ends[k][1].y).fold(f32::MIN, f32::max);
        let tallest = ends.iter().map(|e| e[1].y).fold(f32::MIN, f32::max);
        assert!(
            trunk.len() > 10 && top > 0.9 * tallest,
            "{} trunk segments to {top} of {tallest} m",
            trunk.len()
        );
        assert!(!joints[trunk[0]].start);
        let lengths: Vec<f32> = trunk.iter().map(|&k| ends[k][0].distance(ends[k][1])).collect();
        let mut joined_inner = 0;
        for i in 0..trunk.len() - 1 {
            let (below, above) = (trunk[i], trunk[i + 1]);
            // Radii decode rounded up by a code or two: a little margin.
            let needed = 2.0
                * radii[below][0]
                    .max(radii[below][1])
                    .max(radii[above][0])
                    .max(radii[above][1]);
            let (behind, ahead) = (lengths[..=i].iter().sum::<f32>(), lengths[i + 1..].iter().sum::<f32>());
            if behind < 0.99 * needed {
                assert!(
                    !joints[below].end && !joints[above].start,
                    "trunk joint {i}: {behind} m behind, {needed} needed"
                );
            } else if behind > 1.01 * needed && ahead > 1.01 * needed {
                assert!(joints[below].end && joints[above].start, "trunk joint {i}");
                joined_inner += 1;
            }
        }
        assert!(
            joined_inner > trunk.len() / 2,
            "{joined_inner} of {} trunk joints",
            trunk.len() - 1
        );
        // Most segments run on from one another, not all: branches' bases
        // leave the trunk at its bark, their tips end.
        let joined = joints.iter().filter(|j| j.start || j.end).count();
        assert!(
            joined > count / 2 && joints.iter().any(|j| !j.start) && joints.iter().any(|j| !j.end),
            "{joined} of {count}"
        );
        // Radius codes stay even under the bits.
        for w in &compact.wood_segments {
            assert_eq!(wood_radius_code(w) & 1, 0);
            assert_eq!(w[3] & !(WOOD_JOINED_START | WOOD_JOINED_END) & 0x0001_0001, 0);
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

    fn placed_record(species: Species, needles: usize) -> (PrototypeRecord, LodRecord) {
        let options = GenerateOptions {
            seed: 4,
            target_needles: Some(needles),
            age: crate::generate::Age::Young,
        };
        let input = crate::generate::generate_prototypes(species, &options);
        let record = crate::model::bake_prototypes(&input, &BakeOptions::default(), &())
            .expect("bake")
            .quantized()
            .expect("quantized");
        let flat = record.flatten().expect("flatten");
        (record, flat)
    }

    /// Nodes in one cut and not the other, each with its error and its
    /// parent's error.
    fn differing_nodes(flat: &LodRecord, a: &Cut, b: &Cut) -> Vec<(u32, f32, f32)> {
        let nodes = |cut: &Cut| -> std::collections::BTreeSet<u32> {
            cut.prisms
                .iter()
                .map(|p| p.0 | 1 << 31)
                .chain(cut.original_lines.iter().copied())
                .chain(cut.merged_lines.iter().copied())
                .collect()
        };
        nodes(a)
            .symmetric_difference(&nodes(b))
            .map(|&node| {
                let node = node & !(1 << 31);
                (node, flat.node_error(node), flat.parent_error(node))
            })
            .collect()
    }

    /// The placed layout is built without flattening the tree: its level-2
    /// lines, their codes and ends, and the placements' parent codes are
    /// those the flattened tree gives; widths agree to a code (the areas
    /// are summed in another order) and alignments to half a step; the prototype record's bounds and
    /// radii are the flattened tree's exactly.
    #[test]
    fn placed_layout_from_the_prototypes_matches_the_flattened_tree() {
        for species in [Species::ScotsPine, Species::NorwaySpruce, Species::LawsonCypress] {
            let (record, flat) = placed_record(species, 30_000);
            let compact = CompactSpecies::build_placed(&record).unwrap();
            let flat_spreads = merged_spreads(&flat);
            let tree_lines = compact.tree_counts[2] as usize;
            let drawable = (flat.node_count() - record.tree_merged.len()..flat.node_count())
                .filter(|&node| {
                    let (own, parent) = merged_line_codes(&flat, node as u32).unwrap();
                    own < parent
                })
                .count();
            assert!(
                tree_lines > 0 && tree_lines == drawable,
                "{species:?}: {tree_lines} of {drawable}"
            );
            for slot in 0..tree_lines {
                let node = compact.merged_source[slot];
                let codes = compact.merged_lines[slot][2];
                let (own, parent) = merged_line_codes(&flat, node).unwrap();
                assert_eq!(
                    codes,
                    u32::from(own) | u32::from(parent) << 16,
                    "{species:?} node {node}"
                );
                // Kept to 12 bits: the flat code rounded alike, or a kept
                // step away where the two sit either side of a rounding edge.
                let width = compact.merged_width_code(slot) as i32;
                let flat_code = i32::from(merged_line_width(&flat, node).unwrap());
                let step = 1 << WIDTH_DROPPED_BITS;
                let flat_width = (flat_code + step / 2) / step * step;
                assert!(
                    (width - flat_width).abs() <= step,
                    "{species:?} node {node}: {width} vs {flat_width}"
                );
                // The alignment from the placed prototypes' moments is the
                // flattened tree's, to half a step (the two are summed in
                // another order, and a value on a step's edge may round
                // either way).
                let flat_alignment = flat_spreads[node as usize - flat.needle_count()]
                    .alignment(flat.node_ends(node)[1].0 - flat.node_ends(node)[0].0);
                assert!(
                    (compact.merged_alignment(slot) - flat_alignment).abs() <= 0.5 / 15.0 + 1e-3,
                    "{species:?} node {node}: {} vs {flat_alignment}",
                    compact.merged_alignment(slot)
                );
                let [w0, w1, w2, _] = compact.needles[slot];
                let stored = [[w0 & 0xffff, w0 >> 16, w1 & 0xffff], [w1 >> 16, w2 & 0xffff, w2 >> 16]]
                    .map(|c| c.map(|v| v as u16));
                let ends = flat.node_ends(node).map(|(p, _)| compact.grid.encode(p));
                assert_eq!(stored, ends, "{species:?} node {node}");
            }
            for placement in &compact.placements {
                let root = record.flat_tree_node(placement.source);
                assert_eq!(placement.parent_code, parent_code(&flat, root).unwrap());
            }
            // Placed through a matrix, not the quaternion: equal to float
            // rounding of the tree's size.
            let (lo, hi) = flat.bounds();
            let tolerance = 1e-6 * (hi - lo).max_element();
            let (record_lo, record_hi) = record.bounds();
            assert!(
                record_lo.abs_diff_eq(lo, tolerance) && record_hi.abs_diff_eq(hi, tolerance),
                "{species:?}"
            );
            assert!(record.crown_center().abs_diff_eq(flat.crown_center(), tolerance));
            let ranges = flat.part_ranges().original_lines;
            let (lo, hi) = record.radius_range();
            assert_eq!((line_error(lo), line_error(hi)), (ranges.min, ranges.max));
            // The flattened tree measures each needle's length between its
            // placed ends, metres from the origin, which loses bits a
            // needle a few millimetres long keeps in its prototype's frame.
            let mut worst = 0.0f32;
            for (node, area) in record.tree_node_areas().iter().enumerate() {
                let flat_area = flat.node_needle_area(record.flat_tree_node(node as u32));
                worst = worst.max((area - flat_area).abs() / flat_area);
            }
            assert!(worst <= 1e-4, "{species:?}: {worst}");
        }
    }

    #[test]
    fn placed_layout_stores_prototypes_once_and_draws_the_prototype_cut() {
        for species in [Species::ScotsPine, Species::NorwaySpruce] {
            let (record, flat) = placed_record(species, 30_000);
            let compact = CompactSpecies::build_placed(&record).unwrap();
            assert_eq!(compact.prototypes.len(), record.prototypes.len(), "{species:?}");
            assert_eq!(compact.placements.len(), record.placements.len());
            let stored = compact.needles.len() - compact.tree_counts[0] as usize;
            assert_eq!(stored as u64, record.prototype_needle_count());
            assert!(
                compact
                    .placements
                    .windows(2)
                    .all(|w| w[0].parent_code >= w[1].parent_code)
            );
            let ranges = flat.part_ranges();
            let top = ranges.merged_lines.map_or(ranges.original_lines.max, |r| r.max);
            let mut e = ranges.cylinders.min * 0.3;
            let mut expanded_at_some = false;
            while e < top * 3.0 {
                for threshold in [threshold_code as fn(f32) -> u16, shader_threshold_code] {
                    let code = threshold(e);
                    let (drawn, processed) = compact.placed_drawn(&record, code, e, threshold, None);
                    let coverage = flat.coverage(&drawn);
                    assert!(
                        coverage.iter().all(|&c| c == 1),
                        "{species:?} e = {e}: a needle not covered once"
                    );
                    // The same cut as the record's, but for nodes whose
                    // interval ends within a code step or two of `e`.
                    let expected = record.cut(e).sorted();
                    let drawn = drawn.sorted();
                    for (node, own, parent) in differing_nodes(&flat, &drawn, &expected) {
                        let near = |x: f32| (x / e - 1.0).abs() < 2e-3;
                        assert!(
                            near(own) || near(parent),
                            "{species:?} e = {e}: node {node} [{own}, {parent})"
                        );
                    }
                    let primitives =
                        (drawn.prisms.len() + drawn.original_lines.len() + drawn.merged_lines.len()) as f64;
                    // A prefix processes the cut and the nodes above it: in a
                    // binary forest fewer than the cut, plus one level-2
                    // ancestor chain per expanded placement.
                    let expanded = compact.expanded_placements(code);
                    assert!(
                        processed as f64 <= 2.0 * primitives + expanded as f64,
                        "{species:?} e = {e}: {processed} processed for {primitives} drawn, {expanded} expanded"
                    );
                    expanded_at_some |= expanded > 0;
                }
                e *= 1.17;
            }
            assert!(expanded_at_some);
        }
    }

    /// The worst band of `edges` over prototype `k`'s codes: the most a
    /// placement of a band processes (in vertices) over its own prefixes.
    fn worst_band(compact: &CompactSpecies, k: usize, edges: &[u16]) -> f64 {
        let vertices = super::super::prism::prism_slot_vertices(compact.max_sides);
        let codes = compact.prototype_codes(k);
        let band = |c: u16| edges.iter().filter(|&&edge| edge <= c).count();
        let mut worst = 1.0f64;
        for b in 0..PLACED_BANDS as usize {
            let members: Vec<SectionPrefixes> = codes
                .iter()
                .filter(|&&c| band(c) == b)
                .map(|&c| compact.prototype_prefixes(k, c))
                .collect();
            let Some(longest) = members.iter().copied().reduce(SectionPrefixes::max) else {
                continue;
            };
            for member in &members {
                worst = worst.max(longest.vertices(vertices) as f64 / member.vertices(vertices).max(1) as f64);
            }
        }
        worst
    }

    #[test]
    fn bands_bound_what_each_placement_processes() {
        let (record, _) = placed_record(Species::EasternWhitePine, 30_000);
        let compact = CompactSpecies::build_placed(&record).unwrap();
        let mut overall = 1.0f64;
        for (k, prototype) in compact.prototypes.iter().enumerate() {
            let codes = compact.prototype_codes(k);
            // Edges: ascending codes of the prototype, then unused.
            let used: Vec<u16> = prototype
                .band_edges
                .iter()
                .copied()
                .filter(|&e| e != u16::MAX)
                .collect();
            assert!(used.windows(2).all(|w| w[0] < w[1]), "prototype {k}");
            assert!(used.iter().all(|e| codes.binary_search(e).is_ok()), "prototype {k}");
            assert!(prototype.band_edges[used.len()..].iter().all(|&e| e == u16::MAX));
            let ours = worst_band(&compact, k, &prototype.band_edges);
            // No worse than edges at quantiles of the codes, or at every
            // code where there are few.
            let quantiles: Vec<u16> = (1..PLACED_BANDS as usize)
                .map(|b| codes[b * codes.len() / PLACED_BANDS as usize])
                .collect();
            assert!(
                ours <= worst_band(&compact, k, &quantiles) * 1.001 + 1e-9,
                "prototype {k}"
            );
            if codes.len() <= PLACED_BANDS as usize {
                assert_eq!(ours, 1.0, "prototype {k}: a band a code");
            }
            overall = overall.max(ours);
        }
        // 16 bands hold every placement of these prototypes within a
        // small multiple of its own prefixes (1.56 when written).
        assert!(overall < 2.0, "worst band {overall}");
    }

    #[test]
    fn merged_lines_by_own_code_are_each_prototype_s_lines_once() {
        let (record, _) = placed_record(Species::NorwaySpruce, 30_000);
        let compact = CompactSpecies::build_placed(&record).unwrap();
        for (k, prototype) in compact.prototypes.iter().enumerate() {
            let [first, count] = prototype.merged_lines;
            let from = prototype.merged_by_own as usize;
            let order = &compact.merged_by_own[from..from + count as usize];
            let mut sorted = order.to_vec();
            sorted.sort_unstable();
            assert_eq!(sorted, (first..first + count).collect::<Vec<_>>(), "prototype {k}");
            assert!(
                order
                    .windows(2)
                    .all(|w| compact.merged_codes(w[0] as usize).0 <= compact.merged_codes(w[1] as usize).0)
            );
            // The two orders' prefixes hold the same drawn lines, and the
            // shorter is taken.
            for &c in &compact.prototype_codes(k) {
                let p = compact.prototype_prefixes(k, c);
                let drawn = |lines: &mut dyn Iterator<Item = u32>| -> Vec<u32> {
                    let mut v: Vec<u32> = lines
                        .filter(|&m| {
                            let (own, parent) = compact.merged_codes(m as usize);
                            own <= c && c < parent
                        })
                        .collect();
                    v.sort_unstable();
                    v
                };
                let by_parent = drawn(&mut (first..first + p.merged_lines));
                let by_own = drawn(&mut order[..p.merged_by_own as usize].iter().copied());
                assert_eq!(by_parent, by_own, "prototype {k}, code {c}");
                assert_eq!(p.merged(), p.merged_lines.min(p.merged_by_own));
            }
        }
    }

    #[test]
    fn unshared_prototypes_get_the_flat_layout() {
        let flat = record(500, 3);
        let prototypes = PrototypeRecord::from_flat(&flat).unwrap();
        let compact = CompactSpecies::build_placed(&prototypes).unwrap();
        assert_eq!(compact, CompactSpecies::build(&flat).unwrap());
        assert!(compact.prototypes.is_empty() && compact.placements.is_empty());
    }
}
