//! The LOD record (paper, §5.1) and error-controlled selection (§5.2).
//!
//! The record holds the needles' cylinders (prisms are rebuilt from them, not
//! stored), the original lines (one per needle: its centerline), the merged
//! lines, the binary merge forest with every node's error, and the three
//! parts — cylinders, original lines, merged lines — with their error ranges.
//!
//! Node ids: `0..needles` are the original lines (needle `i`'s line is node
//! `i`), `needles..needles + merged` the merged lines in creation order.
//!
//! ## The cut
//!
//! For a spatial error `e`, the cut holds exactly the nodes whose error is
//! `≤ e` and whose parent's error is `> e`; a needle whose line error `2R`
//! is above `e` is drawn as a prism of `⌈π / arccos(1 − e/R)⌉` sides. Every
//! needle is stood for exactly once. Because a parent's error is never below
//! its children's, node `k` is in the cut iff
//! `error(k) ≤ e < parent_error(k)`: a per-node interval test.

use super::merge::{EndpointId, MergeErrorBound, MergeWeights, MergedLine, endpoint_position};
use super::metric::{NeedleForm, line_error, needle_form, prism_error, relative_error};
use super::needle::{FoliageMaterial, Needle, WoodSegment};
use super::prism::{TriangleMesh, prism_triangle_count};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Marks a node without parent (a root of the merge forest).
pub const NO_PARENT: u32 = u32::MAX;

/// The range of node errors of one part of the record, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorRange {
    /// Smallest error of the part.
    pub min: f32,
    /// Largest error of the part.
    pub max: f32,
}

impl ErrorRange {
    fn of(values: impl IntoIterator<Item = f32>) -> Option<Self> {
        values.into_iter().fold(None, |acc, v| match acc {
            None => Some(Self { min: v, max: v }),
            Some(r) => Some(Self {
                min: r.min.min(v),
                max: r.max.max(v),
            }),
        })
    }

    /// `true` when `e` lies in `[min, max]`.
    pub fn contains(&self, e: f32) -> bool {
        self.min <= e && e <= self.max
    }
}

/// The error ranges of the record's three parts (paper, §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartRanges {
    /// Prisms: from the `Lmax`-sided to the 3-sided prism error.
    pub cylinders: ErrorRange,
    /// Original lines: `2R` over all needles.
    pub original_lines: ErrorRange,
    /// Merged lines; `None` when nothing was merged.
    pub merged_lines: Option<ErrorRange>,
}

/// What the bake recorded about itself.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BakeInfo {
    /// Cost weights used for merging.
    pub weights: MergeWeights,
    /// Wall-clock seconds the bake took, if measured.
    pub bake_seconds: Option<f64>,
    /// Free-form description of the source (preset and seed, input file).
    pub source: String,
}

/// The LOD record of one tree.
#[derive(Clone, Debug, PartialEq)]
pub struct LodRecord {
    /// Name of the tree.
    pub name: String,
    /// Needles (cylinders), sorted by group; `group` numbers groups `0..groups`.
    pub needles: Vec<Needle>,
    /// Merged lines in creation order (children before parents).
    pub merged: Vec<MergedLine>,
    /// Trunk and branches as cylinders.
    pub wood: Vec<WoodSegment>,
    /// Trunk and branches as a triangle mesh (imported trees).
    pub wood_mesh: TriangleMesh,
    /// Appearance.
    pub material: FoliageMaterial,
    /// `Lmax`: most prism sides.
    pub max_sides: u8,
    /// How the record was made.
    pub bake: BakeInfo,
    /// The crown impostor baked with the record
    /// ([`super::impostor::CrownImpostor`], the far representation), if
    /// any: the plugin bakes one at load where it is `None`.
    pub impostor: Option<std::sync::Arc<super::impostor::CrownImpostor>>,
    /// The line opacity scales by pixel size the record was calibrated
    /// with ([`super::calibration::LineCalibration`]), if any: without
    /// one every line keeps its opacity (scale 1).
    pub line_calibration: Option<super::calibration::LineCalibration>,
    // Derived from the above by `from_parts`, never stored.
    parent: Vec<u32>,
    merged_needles: Vec<u32>,
    merged_area: Vec<f32>,
    ranges: PartRanges,
}

/// Why parts do not make a consistent record.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RecordInvalid {
    /// The record has no needles.
    #[error("the record has no needles")]
    NoNeedles,
    /// A number is NaN or infinite.
    #[error("non-finite number in {0}")]
    NonFinite(&'static str),
    /// A needle has a radius ≤ 0 or a zero-length centerline.
    #[error("needle {0} is degenerate (radius ≤ 0 or zero length)")]
    DegenerateNeedle(usize),
    /// Groups are not numbered `0..groups` in needle order.
    #[error("needle {0} breaks the group order")]
    GroupOrder(usize),
    /// `max_sides` outside `[3, 64]`.
    #[error("max_sides {0} outside [3, 64]")]
    MaxSides(u8),
    /// A merged line refers to an end or child that does not exist, or to a
    /// child that comes after it or already has a parent.
    #[error("merged line {0} has a bad child or end reference")]
    BadReference(usize),
    /// A merged line's error is below one of its children's.
    #[error("merged line {0} has an error below a child's")]
    ErrorNotMonotone(usize),
    /// The wood mesh has an index out of range, a partial triangle, a
    /// normal count unlike its position count, or a non-finite number.
    #[error("the wood mesh is inconsistent (index out of range, partial triangle or non-finite number)")]
    BadWoodMesh,
    /// A prototype breaks one of the checks above (its needle and merged
    /// line indices are the prototype's own).
    #[error("prototype {prototype}: {problem}")]
    Prototype {
        /// Index of the prototype.
        prototype: usize,
        /// What is wrong with it.
        problem: Box<RecordInvalid>,
    },
    /// A prototype's level-1 forest does not end in exactly one line.
    #[error("{merged} merged lines for {needles} needles: a prototype merges down to exactly one line")]
    NotOneLine {
        /// Needles of the prototype.
        needles: usize,
        /// Its merged lines.
        merged: usize,
    },
    /// A placement names a prototype that does not exist, or has a
    /// non-finite number, a scale ≤ 0 or a rotation that is not a unit
    /// quaternion, or makes its prototype degenerate (a needle without
    /// length or radius, an infinite error).
    #[error(
        "placement {0} is invalid (unknown prototype, non-finite number, scale ≤ 0, rotation not unit, \
         or its prototype degenerate once placed)"
    )]
    BadPlacement(usize),
    /// The placements stand for more needles than a record may hold.
    #[error("the placements stand for {0} needles: a record holds at most 2^24")]
    TooManyNeedles(u64),
    /// A flat record's merged line `k` mixes the two merge levels (a merge
    /// across groups taking part of a group that is not down to one line).
    #[error("merged line {0} mixes the two merge levels; re-bake the tree")]
    NotTwoLevel(usize),
}

/// Checks the merged lines of a merge forest whose ids `0..leaves` are its
/// leaves and `leaves + k` its `k`-th merged line: finite errors, two
/// distinct children made before the line, one parent each, ends below
/// `ends_limit`, and errors never below a child's (`leaf_error(c)` for a
/// leaf). Returns every node's parent ([`NO_PARENT`] for roots).
pub(crate) fn check_forest(
    leaves: usize,
    merged: &[MergedLine],
    ends_limit: u64,
    leaf_error: impl Fn(usize) -> f32,
) -> Result<Vec<u32>, RecordInvalid> {
    let mut parent = vec![NO_PARENT; leaves + merged.len()];
    for (k, line) in merged.iter().enumerate() {
        let id = leaves + k;
        if !line.error.is_finite() {
            return Err(RecordInvalid::NonFinite("merged line errors"));
        }
        let [c0, c1] = line.children.map(|c| c as usize);
        if c0 == c1
            || c0 >= id
            || c1 >= id
            || parent[c0] != NO_PARENT
            || parent[c1] != NO_PARENT
            || line.ends.iter().any(|&e| e as u64 >= ends_limit)
        {
            return Err(RecordInvalid::BadReference(k));
        }
        parent[c0] = id as u32;
        parent[c1] = id as u32;
        for c in [c0, c1] {
            let child_error = if c < leaves {
                leaf_error(c)
            } else {
                merged[c - leaves].error
            };
            if line.error < child_error {
                return Err(RecordInvalid::ErrorNotMonotone(k));
            }
        }
    }
    Ok(parent)
}

/// Checks what every record carries beside its foliage: finite wood
/// segments, a consistent wood mesh, a finite material and bake time.
pub(crate) fn check_appearance(
    wood: &[WoodSegment],
    wood_mesh: &TriangleMesh,
    material: &FoliageMaterial,
    bake: &BakeInfo,
) -> Result<(), RecordInvalid> {
    if !wood.iter().all(WoodSegment::is_valid) {
        return Err(RecordInvalid::NonFinite("wood"));
    }
    if !wood_mesh.is_valid() {
        return Err(RecordInvalid::BadWoodMesh);
    }
    if !material.numbers().all(f32::is_finite) {
        return Err(RecordInvalid::NonFinite("material"));
    }
    if bake.bake_seconds.is_some_and(|s| !s.is_finite()) {
        return Err(RecordInvalid::NonFinite("bake_seconds"));
    }
    Ok(())
}

impl LodRecord {
    /// The record with its merged lines' errors recomputed under `bound`
    /// (every other part kept: forest, ends, needles, impostor,
    /// calibration). `conifer eval` draws its `paper` method with the
    /// paper's [`MergeErrorBound::Nested`] this way, beside ours from the
    /// same record.
    pub fn with_error_bound(&self, bound: MergeErrorBound) -> Result<Self, RecordInvalid> {
        let mut merged = self.merged.clone();
        match bound {
            MergeErrorBound::Needles => super::merge::tighten_group_errors(&self.needles, &mut merged),
            MergeErrorBound::Nested => super::merge::nest_errors(&self.needles, &mut merged),
        }
        let mut record = Self::from_parts(
            self.name.clone(),
            self.needles.clone(),
            merged,
            self.wood.clone(),
            self.wood_mesh.clone(),
            self.material,
            self.max_sides,
            self.bake.clone(),
        )?;
        record.impostor = self.impostor.clone();
        record.line_calibration = self.line_calibration;
        Ok(record)
    }

    /// Builds a record from its stored parts, checking every invariant the
    /// cut relies on (see [`RecordInvalid`]) and deriving parents, needle
    /// counts, areas and the part ranges.
    #[allow(clippy::too_many_arguments)] // One argument per stored part, checked together.
    pub fn from_parts(
        name: String,
        needles: Vec<Needle>,
        merged: Vec<MergedLine>,
        wood: Vec<WoodSegment>,
        wood_mesh: TriangleMesh,
        material: FoliageMaterial,
        max_sides: u8,
        bake: BakeInfo,
    ) -> Result<Self, RecordInvalid> {
        let n = needles.len();
        if n == 0 {
            return Err(RecordInvalid::NoNeedles);
        }
        if !(super::metric::MIN_PRISM_SIDES..=super::metric::MAX_PRISM_SIDES).contains(&max_sides) {
            return Err(RecordInvalid::MaxSides(max_sides));
        }
        let mut expected_group = 0u32;
        for (i, needle) in needles.iter().enumerate() {
            if !(needle.base.is_finite()
                && needle.tip.is_finite()
                && needle.normal.is_finite()
                && needle.radius.is_finite())
            {
                return Err(RecordInvalid::NonFinite("needles"));
            }
            if !needle.is_valid() {
                return Err(RecordInvalid::DegenerateNeedle(i));
            }
            if i == 0 && needle.group != 0 {
                return Err(RecordInvalid::GroupOrder(i));
            }
            if needle.group != expected_group {
                if needle.group != expected_group + 1 {
                    return Err(RecordInvalid::GroupOrder(i));
                }
                expected_group += 1;
            }
        }
        check_appearance(&wood, &wood_mesh, &material, &bake)?;

        let parent = check_forest(n, &merged, 2 * n as u64, |c| line_error(needles[c].radius))?;
        let mut merged_needles = Vec::with_capacity(merged.len());
        let mut merged_area = Vec::with_capacity(merged.len());
        for line in &merged {
            let (mut count, mut area) = (0u32, 0f32);
            for c in line.children.map(|c| c as usize) {
                if c < n {
                    count += 1;
                    area += needles[c].side_area();
                } else {
                    count += merged_needles[c - n];
                    area += merged_area[c - n];
                }
            }
            merged_needles.push(count);
            merged_area.push(area);
        }

        let radii = || needles.iter().map(|x| x.radius);
        let min_radius = radii().fold(f32::INFINITY, f32::min);
        let max_radius = radii().fold(0.0, f32::max);
        let ranges = PartRanges {
            cylinders: ErrorRange {
                min: prism_error(min_radius, max_sides),
                max: prism_error(max_radius, super::metric::MIN_PRISM_SIDES),
            },
            original_lines: ErrorRange {
                min: line_error(min_radius),
                max: line_error(max_radius),
            },
            merged_lines: ErrorRange::of(merged.iter().map(|m| m.error)),
        };
        Ok(Self {
            name,
            needles,
            merged,
            wood,
            wood_mesh,
            material,
            max_sides,
            bake,
            impostor: None,
            line_calibration: None,
            parent,
            merged_needles,
            merged_area,
            ranges,
        })
    }

    /// Number of needles (= original lines).
    pub fn needle_count(&self) -> usize {
        self.needles.len()
    }

    /// Number of phyllotaxy groups.
    pub fn group_count(&self) -> usize {
        self.needles.last().map_or(0, |n| n.group as usize + 1)
    }

    /// Number of nodes of the merge forest (original plus merged lines).
    pub fn node_count(&self) -> usize {
        self.needles.len() + self.merged.len()
    }

    /// Error of node `node`: `2R` for an original line, the merge error for
    /// a merged line.
    pub fn node_error(&self, node: u32) -> f32 {
        let n = self.needles.len();
        let node = node as usize;
        if node < n {
            line_error(self.needles[node].radius)
        } else {
            self.merged[node - n].error
        }
    }

    /// Parent of node `node`, or [`NO_PARENT`] for a root.
    pub fn parent(&self, node: u32) -> u32 {
        self.parent[node as usize]
    }

    /// Error of the parent of `node`; infinite for a root. The node is in the
    /// cut at `e` iff `node_error(node) ≤ e < parent_error(node)`.
    pub fn parent_error(&self, node: u32) -> f32 {
        match self.parent[node as usize] {
            NO_PARENT => f32::INFINITY,
            p => self.node_error(p),
        }
    }

    /// Roots of the merge forest (nodes without parent), ascending.
    pub fn roots(&self) -> Vec<u32> {
        (0..self.node_count() as u32)
            .filter(|&k| self.parent[k as usize] == NO_PARENT)
            .collect()
    }

    /// Needles stood for by node `node` (1 for an original line).
    pub fn node_needle_count(&self, node: u32) -> u32 {
        let n = self.needles.len();
        if (node as usize) < n {
            1
        } else {
            self.merged_needles[node as usize - n]
        }
    }

    /// Summed side-on silhouette area (`2R · length`) of the needles stood
    /// for by node `node`, m²: what an area-preserving opacity needs.
    pub fn node_needle_area(&self, node: u32) -> f32 {
        let n = self.needles.len();
        if (node as usize) < n {
            self.needles[node as usize].side_area()
        } else {
            self.merged_area[node as usize - n]
        }
    }

    /// The two ends of node `node`'s line: positions and (the needles') normals.
    pub fn node_ends(&self, node: u32) -> [(Vec3, Vec3); 2] {
        let n = self.needles.len();
        let ends: [EndpointId; 2] = if (node as usize) < n {
            [2 * node, 2 * node + 1]
        } else {
            self.merged[node as usize - n].ends
        };
        ends.map(|e| {
            (
                endpoint_position(&self.needles, e),
                self.needles[(e / 2) as usize].normal,
            )
        })
    }

    /// Error ranges of the three parts.
    pub fn part_ranges(&self) -> PartRanges {
        self.ranges
    }

    /// Centre of the needles' bounding box: where a viewer's distance to the
    /// tree is measured.
    pub fn crown_center(&self) -> Vec3 {
        super::needle::bounds(self.needles.iter().flat_map(|x| [x.base, x.tip]))
            .map_or(Vec3::ZERO, |(lo, hi)| (lo + hi) * 0.5)
    }

    /// Axis-aligned bounds of the foliage and wood, `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let points = self.needles.iter().flat_map(|x| [x.base, x.tip]);
        let wood = self.wood.iter().flat_map(|w| [w.start, w.end]);
        let mesh = self.wood_mesh.positions.iter().copied();
        super::needle::bounds(points.chain(wood).chain(mesh)).unwrap_or((Vec3::ZERO, Vec3::ZERO))
    }

    /// The cut at spatial error `e` by the paper's traversal, starting in the
    /// part whose error range holds `e` (see [`CutStrategy::Traversal`]).
    pub fn cut(&self, spatial_error: f32) -> Cut {
        self.cut_with(spatial_error, CutStrategy::Traversal { three_part_start: true })
    }

    /// The cut at spatial error `e` with a chosen strategy; all strategies
    /// give the same cut (in different orders). A NaN or negative `e` counts
    /// as 0 (finest detail), an infinite one as the largest finite error
    /// (the roots).
    pub fn cut_with(&self, spatial_error: f32, strategy: CutStrategy) -> Cut {
        let e = if spatial_error > 0.0 {
            spatial_error.min(f32::MAX)
        } else {
            0.0
        };
        let mut cut = Cut::default();
        match strategy {
            CutStrategy::Traversal { three_part_start } => {
                let merged_min = self.ranges.merged_lines.map_or(f32::INFINITY, |r| r.min);
                if three_part_start && e < merged_min {
                    // `e` lies in the cylinder or original-line part: no
                    // merged line can be in the cut, so walk the needles.
                    for i in 0..self.needles.len() as u32 {
                        self.push_needle(&mut cut, i, e);
                    }
                } else {
                    let mut stack = self.roots();
                    while let Some(node) = stack.pop() {
                        let k = node as usize;
                        if k < self.needles.len() {
                            self.push_needle(&mut cut, node, e);
                        } else if self.merged[k - self.needles.len()].error <= e {
                            cut.merged_lines.push(node);
                        } else {
                            stack.extend(self.merged[k - self.needles.len()].children);
                        }
                    }
                }
            }
            CutStrategy::Intervals => {
                for node in 0..self.node_count() as u32 {
                    if self.parent_error(node) <= e {
                        continue;
                    }
                    if (node as usize) < self.needles.len() {
                        self.push_needle(&mut cut, node, e);
                    } else if self.node_error(node) <= e {
                        cut.merged_lines.push(node);
                    }
                }
            }
        }
        cut
    }

    /// Adds needle `i` to the cut as its line or its prism (its parent is
    /// known not to be in the cut).
    fn push_needle(&self, cut: &mut Cut, i: u32, e: f32) {
        let radius = self.needles[i as usize].radius;
        match needle_form(relative_error(e, radius), self.max_sides) {
            NeedleForm::Line => cut.original_lines.push(i),
            NeedleForm::Prism { sides } => cut.prisms.push((i, sides)),
        }
    }

    /// Counts of a cut.
    pub fn cut_stats(&self, cut: &Cut) -> CutStats {
        let mut prism_sides = BTreeMap::new();
        let mut triangles = 0u64;
        for &(_, sides) in &cut.prisms {
            *prism_sides.entry(sides).or_insert(0u64) += 1;
            triangles += prism_triangle_count(sides) as u64;
        }
        let merged_needles: u64 = cut.merged_lines.iter().map(|&k| self.node_needle_count(k) as u64).sum();
        CutStats {
            prisms: cut.prisms.len() as u64,
            prism_sides,
            lines_original: cut.original_lines.len() as u64,
            lines_merged: cut.merged_lines.len() as u64,
            needles_covered: cut.prisms.len() as u64 + cut.original_lines.len() as u64 + merged_needles,
            triangles,
            line_segments: (cut.original_lines.len() + cut.merged_lines.len()) as u64,
        }
    }

    /// How many times each needle is stood for by the cut (all ones for a
    /// correct cut). Walks down from every merged line: for tests and tools.
    pub fn coverage(&self, cut: &Cut) -> Vec<u32> {
        let n = self.needles.len();
        let mut count = vec![0u32; n];
        for &(i, _) in &cut.prisms {
            count[i as usize] += 1;
        }
        for &i in &cut.original_lines {
            count[i as usize] += 1;
        }
        let mut stack: Vec<u32> = cut.merged_lines.clone();
        while let Some(node) = stack.pop() {
            if (node as usize) < n {
                count[node as usize] += 1;
            } else {
                stack.extend(self.merged[node as usize - n].children);
            }
        }
        count
    }
}

/// How [`LodRecord::cut_with`] finds the cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CutStrategy {
    /// The paper's top-down traversal of the merge forest. With
    /// `three_part_start`, an `e` below every merged error skips the merged
    /// part (and walks the needles directly).
    Traversal {
        /// Start in the part whose error range holds `e`.
        three_part_start: bool,
    },
    /// One pass over all nodes testing `error ≤ e < parent_error`: what a
    /// GPU does per primitive.
    Intervals,
}

/// How one needle or group of needles is drawn in a cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Representation {
    /// A prism of this many sides.
    Prism(u8),
    /// The needle's own (original) line.
    OriginalLine,
    /// A merged line standing for several needles.
    MergedLine,
}

/// The nodes of a cut.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cut {
    /// Needles drawn as prisms, with their side count.
    pub prisms: Vec<(u32, u8)>,
    /// Needles drawn as their original line (node id = needle id).
    pub original_lines: Vec<u32>,
    /// Merged lines drawn (node ids).
    pub merged_lines: Vec<u32>,
}

impl Cut {
    /// Sorts every list, so cuts found by different strategies compare equal.
    pub fn sorted(mut self) -> Self {
        self.prisms.sort_unstable();
        self.original_lines.sort_unstable();
        self.merged_lines.sort_unstable();
        self
    }
}

/// Counts of a cut.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CutStats {
    /// Needles drawn as prisms.
    pub prisms: u64,
    /// Prisms by side count.
    pub prism_sides: BTreeMap<u8, u64>,
    /// Original lines drawn.
    pub lines_original: u64,
    /// Merged lines drawn.
    pub lines_merged: u64,
    /// Needles stood for (equals the needle count for a correct cut).
    pub needles_covered: u64,
    /// Triangles of the prisms.
    pub triangles: u64,
    /// Line segments (original and merged).
    pub line_segments: u64,
}

impl CutStats {
    /// Primitives drawn, counting a line like a triangle as the paper does.
    pub fn primitives(&self) -> u64 {
        self.triangles + self.line_segments
    }
}
