//! A tree as shared prototypes placed many times (record format 3).
//!
//! The paper's two merge levels already have this shape: level 1 merges the
//! needles of one phyllotaxy group (shoot, fascicle, spray) down to one
//! line, level 2 merges the group lines across the tree. Here the group is a
//! [`Prototype`]: its needles in its own frame and its level-1 merge forest,
//! stored once and placed any number of times by a [`Placement`] (rotation,
//! translation, uniform scale). Level 2 runs over the placed prototype lines.
//! A procedural tree uses a few dozen prototypes placed thousands of times;
//! an imported or flat tree is the case of every group a prototype placed
//! once ([`PrototypeRecord::from_flat`]).
//!
//! ## Errors of placed prototypes
//!
//! A placement scales every length of its prototype by `scale`, so a placed
//! node's error is its prototype error times `scale` (a needle's radius,
//! hence its line error `2R`, scales the same way). Monotone errors stay
//! monotone, so the cut is still the paper's, node by node:
//! `error ≤ e < parent_error`. [`PrototypeRecord::cut`] walks it without
//! expanding the placements and names its nodes as [`PrototypeRecord::flatten`]
//! numbers them, so the two cuts compare equal.
//!
//! ## Node ids
//!
//! * Inside a prototype (level 1): `0..needles` its needles' own lines, then
//!   its merged lines in creation order; the last is the root (a one-needle
//!   prototype's root is its needle). Endpoint ids are local: `2i` the base
//!   and `2i + 1` the tip of needle `i`.
//! * Level 2 ([`PrototypeRecord::tree_merged`]): ids `0..placements` stand
//!   for placement `p`'s root line, `placements + k` for the `k`-th level-2
//!   merged line. Their ends are tree-wide endpoint ids: needle `i` of
//!   placement `p` is needle `needle_offset(p) + i` of the flattened tree.
//! * Flattened ([`LodRecord`]): the placements' needles in placement order
//!   (placement `p` is group `p`), then every placement's level-1 merged
//!   lines in placement order, then the level-2 merged lines.

use super::merge::{EndpointId, MergedLine};
use super::metric::{NeedleForm, line_error, needle_form, relative_error};
use super::needle::{FoliageMaterial, Needle, TreeInput, WoodSegment};
use super::prism::TriangleMesh;
use super::record::{BakeInfo, Cut, LodRecord, NO_PARENT, RecordInvalid, check_appearance, check_forest};
use super::shading::AxisSpread;
use super::view::{SPHERE_MARGIN, Sphere, ViewPoint};
use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

/// Most needles a record may stand for once placed: the GPU layout packs a
/// needle's index in 24 bits, and the flattened tree must fit in memory
/// whatever a (possibly hostile) file claims.
pub const MAX_PLACED_NEEDLES: u64 = 1 << 24;

/// Where one prototype stands in the tree: `p ↦ rotation · (scale · p) + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Index of the placed prototype.
    pub prototype: u32,
    /// Rotation (a unit quaternion).
    pub rotation: Quat,
    /// Translation, tree metres.
    pub translation: Vec3,
    /// Uniform scale (> 0): lengths, radii and errors of the prototype are
    /// multiplied by it.
    pub scale: f32,
    /// Age of the placed shoot's needles, years (0: grown this year); it
    /// picks their colour ([`super::color`]).
    pub needle_age: u8,
}

impl Placement {
    /// Prototype `prototype` placed as it is (no rotation, no move, scale 1).
    pub fn identity(prototype: u32) -> Self {
        Self {
            prototype,
            rotation: Quat::IDENTITY,
            translation: Vec3::ZERO,
            scale: 1.0,
            needle_age: super::color::MATURE_NEEDLE_AGE,
        }
    }

    /// `true` for the identity transform.
    pub fn is_identity(&self) -> bool {
        self.rotation == Quat::IDENTITY && self.translation == Vec3::ZERO && self.scale == 1.0
    }

    /// `true` when every number is finite, the scale positive and the
    /// rotation a unit quaternion (to 1e-4).
    pub fn is_valid(&self) -> bool {
        self.rotation.is_finite()
            && (self.rotation.length() - 1.0).abs() < 1e-4
            && self.translation.is_finite()
            && self.scale.is_finite()
            && self.scale > 0.0
    }

    /// A prototype-frame point in the tree. The identity is exact.
    pub fn place_point(&self, point: Vec3) -> Vec3 {
        if self.is_identity() {
            point
        } else {
            self.rotation * (point * self.scale) + self.translation
        }
    }

    /// A tree point in the prototype's frame (the inverse of
    /// [`Placement::place_point`]).
    pub fn unplace_point(&self, point: Vec3) -> Vec3 {
        if self.is_identity() {
            point
        } else {
            (self.rotation.inverse() * (point - self.translation)) / self.scale
        }
    }

    /// A prototype needle in the tree, as group `group`.
    pub fn place_needle(&self, needle: &Needle, group: u32) -> Needle {
        Needle {
            base: self.place_point(needle.base),
            tip: self.place_point(needle.tip),
            radius: needle.radius * self.scale,
            normal: if self.is_identity() {
                needle.normal
            } else {
                self.rotation * needle.normal
            },
            group,
        }
    }
}

/// One shared group of needles in its own frame, with its level-1 merge
/// forest down to one line (see the module docs for its node ids).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Prototype {
    /// The needles, prototype metres (as the record stores them: their
    /// `group` is 0).
    pub needles: Vec<Needle>,
    /// Level-1 merged lines in creation order (children before parents);
    /// `needles.len() − 1` of them, the last one the root.
    pub merged: Vec<MergedLine>,
}

impl Prototype {
    /// The root node: the last merged line, or the needle of a one-needle prototype.
    pub fn root(&self) -> u32 {
        (self.needles.len() + self.merged.len()).saturating_sub(1) as u32
    }

    /// Error of local node `node`, prototype metres (`2R` for a needle's line).
    pub fn node_error(&self, node: u32) -> f32 {
        let n = self.needles.len();
        match (node as usize).checked_sub(n) {
            None => line_error(self.needles[node as usize].radius),
            Some(k) => self.merged[k].error,
        }
    }

    /// The two local endpoint ids of node `node`'s line.
    pub fn node_ends(&self, node: u32) -> [EndpointId; 2] {
        match (node as usize).checked_sub(self.needles.len()) {
            None => [2 * node, 2 * node + 1],
            Some(k) => self.merged[k].ends,
        }
    }

    /// Position of local endpoint `end`, prototype metres.
    pub fn endpoint(&self, end: EndpointId) -> Vec3 {
        super::merge::endpoint_position(&self.needles, end)
    }

    /// Checks the needles and the forest: valid needles, children before
    /// parents, one parent each, ends in range, monotone errors, one root.
    fn validate(&self) -> Result<(), RecordInvalid> {
        let n = self.needles.len();
        if n == 0 {
            return Err(RecordInvalid::NoNeedles);
        }
        for (i, needle) in self.needles.iter().enumerate() {
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
        }
        if self.merged.len() != n - 1 {
            return Err(RecordInvalid::NotOneLine {
                needles: n,
                merged: self.merged.len(),
            });
        }
        check_forest(n, &self.merged, 2 * n as u64, |c| line_error(self.needles[c].radius))?;
        Ok(())
    }
}

/// What a prototype bake takes in: shared needle groups and where they go.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PrototypeInput {
    /// Human-readable name (species preset, or the source file).
    pub name: String,
    /// Each prototype's needles in its own frame. Their `group` marks the
    /// phyllotaxy sub-groups (shoots, fascicles) of a prototype larger than
    /// [`crate::model::MergeOptions::exhaustive_group_limit`], merged first
    /// ([`crate::model::merge::merge_nested_group`]); the record does not
    /// keep it.
    pub prototypes: Vec<Vec<Needle>>,
    /// Where the prototypes stand; placement `p` becomes group `p`.
    pub placements: Vec<Placement>,
    /// Trunk and branches as cylinders.
    pub wood: Vec<WoodSegment>,
    /// Trunk and branches as a triangle mesh (imported trees).
    pub wood_mesh: TriangleMesh,
    /// Appearance.
    pub material: FoliageMaterial,
}

impl PrototypeInput {
    /// A flat tree as prototypes: every phyllotaxy group a prototype placed
    /// once as it is, groups in order of first appearance (the order a
    /// flat bake has always used).
    pub fn from_tree(tree: &TreeInput) -> Self {
        let mut index = std::collections::HashMap::new();
        let mut prototypes: Vec<Vec<Needle>> = Vec::new();
        for needle in &tree.needles {
            let k = *index.entry(needle.group).or_insert_with(|| {
                prototypes.push(Vec::new());
                prototypes.len() - 1
            });
            prototypes[k].push(Needle { group: 0, ..*needle });
        }
        Self {
            name: tree.name.clone(),
            placements: (0..prototypes.len() as u32).map(Placement::identity).collect(),
            prototypes,
            wood: tree.wood.clone(),
            wood_mesh: tree.wood_mesh.clone(),
            material: tree.material,
        }
    }

    /// Needles once placed.
    pub fn placed_needle_count(&self) -> u64 {
        self.placements
            .iter()
            .map(|p| self.prototypes.get(p.prototype as usize).map_or(0, |x| x.len() as u64))
            .sum()
    }

    /// The flat tree: every placement's needles in the tree, as group `p`.
    pub fn to_tree(&self) -> TreeInput {
        let needles = self
            .placements
            .iter()
            .enumerate()
            .flat_map(|(p, placement)| {
                self.prototypes[placement.prototype as usize]
                    .iter()
                    .map(move |n| placement.place_needle(n, p as u32))
            })
            .collect();
        TreeInput {
            name: self.name.clone(),
            needles,
            wood: self.wood.clone(),
            wood_mesh: self.wood_mesh.clone(),
            material: self.material,
        }
    }
}

/// What decides, without placing its needles, whether a placement of a
/// prototype keeps every needle valid.
struct PrototypeExtent {
    /// Largest coordinate magnitude of a needle end.
    max_coordinate: f32,
    /// Shortest needle.
    min_length: f32,
    /// Smallest and largest radius.
    radii: (f32, f32),
}

impl PrototypeExtent {
    fn of(prototype: &Prototype) -> Self {
        let mut extent = Self {
            max_coordinate: 0.0,
            min_length: f32::INFINITY,
            radii: (f32::INFINITY, 0.0),
        };
        for n in &prototype.needles {
            extent.max_coordinate = extent
                .max_coordinate
                .max(n.base.abs().max_element())
                .max(n.tip.abs().max_element());
            extent.min_length = extent.min_length.min(n.length());
            extent.radii = (extent.radii.0.min(n.radius), extent.radii.1.max(n.radius));
        }
        extent
    }

    /// `true` when every needle of the prototype stays valid under
    /// `placement` (a valid placement of a valid prototype) for sure:
    /// radii scaled stay positive and finite, and the shortest needle
    /// scaled is far longer than the rounding of a placed end. A placed
    /// end `q·(s·p) + t` has coordinates at most `m = √3·s·max|p| + |t|`
    /// (a unit rotation keeps the length; to 1e-4) and is rounded by a
    /// few ulps of `m` — 32 of them here, far more than glam's rotation
    /// and sum take; two ends that far apart in every coordinate cannot
    /// round to the same point, and a needle of length `L` has one
    /// coordinate at least `L/√3` long; and lengths and reach between
    /// 1e-18 and 1e18 m keep the squares a length is measured from clear
    /// of underflow and overflow. `false` says nothing: the needles are
    /// then placed and checked one by one.
    fn places_validly(&self, placement: &Placement) -> bool {
        const SQUARES_SAFE: f32 = 1e18;
        let s = placement.scale;
        let (lo, hi) = (self.radii.0 * s, self.radii.1 * s);
        let reach = 3f32.sqrt() * 1.0001 * s * self.max_coordinate + placement.translation.abs().max_element();
        let rounding = 32.0 * f32::EPSILON * reach;
        let shortest = s * 0.9998 * self.min_length / 3f32.sqrt();
        lo > 0.0 && hi.is_finite() && reach < SQUARES_SAFE && shortest > 1.0 / SQUARES_SAFE && shortest > 2.0 * rounding
    }
}

/// Bounds of `needles`' ends placed by `placement`, through the placement
/// as a scaled matrix (the flattened tree places them through the
/// quaternion: the two differ by float rounding, a few ulps of the tree's
/// size).
fn placed_point_bounds(needles: &[Needle], placement: &Placement) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
    if placement.is_identity() {
        for n in needles {
            lo = lo.min(n.base).min(n.tip);
            hi = hi.max(n.base).max(n.tip);
        }
        return (lo, hi);
    }
    let matrix = glam::Mat3::from_quat(placement.rotation) * placement.scale;
    for n in needles {
        let (a, b) = (matrix * n.base, matrix * n.tip);
        lo = lo.min(a).min(b);
        hi = hi.max(a).max(b);
    }
    (lo + placement.translation, hi + placement.translation)
}

/// The LOD record of a tree made of prototypes and placements (format 3).
#[derive(Clone, Debug, PartialEq)]
pub struct PrototypeRecord {
    /// Name of the tree.
    pub name: String,
    /// The shared needle groups with their level-1 forests.
    pub prototypes: Vec<Prototype>,
    /// Where the prototypes stand.
    pub placements: Vec<Placement>,
    /// Level-2 merged lines over the placed prototype lines, in creation
    /// order (see the module docs for their ids).
    pub tree_merged: Vec<MergedLine>,
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
    // Derived by `from_parts`, never stored.
    /// Placed needles before placement `p` (`placements + 1` entries).
    needle_offset: Vec<u64>,
    /// Level-1 merged lines of the placements before `p` (`placements + 1` entries).
    merged_offset: Vec<u64>,
    /// `(min, max)` of the placed needles' ends, tree metres.
    needle_bounds: (Vec3, Vec3),
    /// `(min, max)` of the placed needles' radii, tree metres.
    radius_range: (f32, f32),
    /// Parent of each level-2 node (placements, then `tree_merged`).
    tree_parent: Vec<u32>,
    /// Bounding sphere of each prototype, prototype metres.
    prototype_spheres: Vec<Sphere>,
    /// Bounding sphere of each level-2 node, tree metres: a placement's
    /// prototype sphere placed, a merged line's holding its children's.
    node_spheres: Vec<Sphere>,
    /// A sphere holding every node's sphere and the wood.
    tree_sphere: Sphere,
}

impl PrototypeRecord {
    /// Builds a record from its stored parts, checking every invariant the
    /// cut relies on: valid prototypes, placements of existing prototypes
    /// with finite, positive-scale transforms, at most
    /// [`MAX_PLACED_NEEDLES`] placed needles, and a level-2 forest whose
    /// children come first, have one parent each and errors at most the
    /// parent's (placed errors, scaled).
    #[allow(clippy::too_many_arguments)] // One argument per stored part, checked together.
    pub fn from_parts(
        name: String,
        prototypes: Vec<Prototype>,
        placements: Vec<Placement>,
        tree_merged: Vec<MergedLine>,
        wood: Vec<WoodSegment>,
        wood_mesh: TriangleMesh,
        material: FoliageMaterial,
        max_sides: u8,
        bake: BakeInfo,
    ) -> Result<Self, RecordInvalid> {
        if placements.is_empty() {
            return Err(RecordInvalid::NoNeedles);
        }
        if !(super::metric::MIN_PRISM_SIDES..=super::metric::MAX_PRISM_SIDES).contains(&max_sides) {
            return Err(RecordInvalid::MaxSides(max_sides));
        }
        for (k, prototype) in prototypes.iter().enumerate() {
            prototype.validate().map_err(|problem| RecordInvalid::Prototype {
                prototype: k,
                problem: Box::new(problem),
            })?;
        }
        let mut needle_offset = Vec::with_capacity(placements.len() + 1);
        let mut merged_offset = Vec::with_capacity(placements.len() + 1);
        let (mut needles, mut merged) = (0u64, 0u64);
        let extents: Vec<PrototypeExtent> = prototypes.iter().map(PrototypeExtent::of).collect();
        let mut needle_bounds = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let mut radius_range = (f32::INFINITY, 0.0f32);
        for (p, placement) in placements.iter().enumerate() {
            let (Some(prototype), Some(extent)) = (
                prototypes.get(placement.prototype as usize),
                extents.get(placement.prototype as usize),
            ) else {
                return Err(RecordInvalid::BadPlacement(p));
            };
            // A valid prototype can still degenerate once placed (a scale
            // that underflows a radius or overflows an error, a translation
            // that swallows a length): the flattened tree must be valid.
            // Errors are monotone, so the root's is the largest one scaled.
            if !placement.is_valid()
                || !placed_error(prototype, prototype.root(), placement.scale).is_finite()
                || !(extent.places_validly(placement)
                    || prototype
                        .needles
                        .iter()
                        .all(|n| placement.place_needle(n, 0).is_valid()))
            {
                return Err(RecordInvalid::BadPlacement(p));
            }
            let (lo, hi) = placed_point_bounds(&prototype.needles, placement);
            needle_bounds = (needle_bounds.0.min(lo), needle_bounds.1.max(hi));
            // Scaling by a positive factor keeps the order of floats, so the
            // placed extremes are the prototype's scaled.
            let (thinnest, widest) = extent.radii;
            radius_range = (
                radius_range.0.min(thinnest * placement.scale),
                radius_range.1.max(widest * placement.scale),
            );
            needle_offset.push(needles);
            merged_offset.push(merged);
            needles += prototype.needles.len() as u64;
            merged += prototype.merged.len() as u64;
            if needles > MAX_PLACED_NEEDLES {
                return Err(RecordInvalid::TooManyNeedles(needles));
            }
        }
        needle_offset.push(needles);
        merged_offset.push(merged);
        check_appearance(&wood, &wood_mesh, &material, &bake)?;

        let mut record = Self {
            name,
            prototypes,
            placements,
            tree_merged: Vec::new(),
            wood,
            wood_mesh,
            material,
            max_sides,
            bake,
            impostor: None,
            line_calibration: None,
            needle_offset,
            merged_offset,
            needle_bounds,
            radius_range,
            tree_parent: Vec::new(),
            prototype_spheres: Vec::new(),
            node_spheres: Vec::new(),
            tree_sphere: Sphere::default(),
        };
        let tree_parent = check_forest(record.placements.len(), &tree_merged, 2 * needles, |p| {
            record.placed_root_error(p)
        })?;
        record.tree_merged = tree_merged;
        record.tree_parent = tree_parent;
        record.bound_nodes()?;
        Ok(record)
    }

    /// Derives the bounding spheres (see [`super::view`]): each prototype's
    /// around its needles' ends and widest radius, each placement's that
    /// sphere placed, each level-2 merged line's the smallest holding its
    /// two children's grown by [`SPHERE_MARGIN`] of the tree's size, and
    /// the tree's holding the roots' and the wood's, grown the same.
    fn bound_nodes(&mut self) -> Result<(), RecordInvalid> {
        self.prototype_spheres = self
            .prototypes
            .iter()
            .map(|prototype| {
                let widest = prototype.needles.iter().map(|n| n.radius).fold(0.0, f32::max);
                Sphere::around_points(prototype.needles.iter().flat_map(|n| [n.base, n.tip]), widest)
            })
            .collect::<Option<_>>()
            .ok_or(RecordInvalid::NoNeedles)?;
        let mut spheres: Vec<Sphere> = self
            .placements
            .iter()
            .map(|pl| self.prototype_spheres[pl.prototype as usize].placed(pl))
            .collect();
        let wood: Vec<Sphere> = self
            .wood
            .iter()
            .map(Sphere::around_wood)
            .chain(Sphere::around_points(self.wood_mesh.positions.iter().copied(), 0.0))
            .collect();
        let extent = Sphere::around_points(
            spheres
                .iter()
                .chain(&wood)
                .flat_map(|s| [s.center - Vec3::splat(s.radius), s.center + Vec3::splat(s.radius)]),
            0.0,
        )
        .map_or(0.0, |s| s.radius);
        let margin = (extent * SPHERE_MARGIN).max(f32::MIN_POSITIVE);
        for line in &self.tree_merged {
            let [a, b] = line.children.map(|c| spheres[c as usize]);
            spheres.push(a.enclosing(&b).grown(margin));
        }
        let mut roots = (0..spheres.len())
            .filter(|&k| self.tree_parent[k] == NO_PARENT)
            .map(|k| spheres[k])
            .chain(wood);
        let first = roots.next().ok_or(RecordInvalid::NoNeedles)?;
        self.tree_sphere = roots.fold(first, |all, s| all.enclosing(&s)).grown(margin);
        self.node_spheres = spheres;
        Ok(())
    }

    /// Bounding sphere of prototype `k`, prototype metres.
    pub fn prototype_sphere(&self, prototype: usize) -> Sphere {
        self.prototype_spheres[prototype]
    }

    /// Bounding sphere of level-2 node `node` (placements, then merged
    /// lines), tree metres; each holds its children's.
    pub fn node_sphere(&self, node: u32) -> Sphere {
        self.node_spheres[node as usize]
    }

    /// A sphere holding every node's sphere and the wood, tree metres.
    pub fn tree_sphere(&self) -> Sphere {
        self.tree_sphere
    }

    /// Axis-aligned bounds of the placed needles' ends, `(min, max)`:
    /// [`LodRecord::crown_center`]'s box of the flattened tree (to float
    /// rounding), known without flattening it.
    pub fn needle_bounds(&self) -> (Vec3, Vec3) {
        self.needle_bounds
    }

    /// Centre of [`PrototypeRecord::needle_bounds`]: the flattened tree's
    /// [`LodRecord::crown_center`] (to float rounding).
    pub fn crown_center(&self) -> Vec3 {
        (self.needle_bounds.0 + self.needle_bounds.1) * 0.5
    }

    /// Axis-aligned bounds of the placed needles and the wood, `(min,
    /// max)`: the flattened tree's [`LodRecord::bounds`] (to float
    /// rounding).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let wood = self.wood.iter().flat_map(|w| [w.start, w.end]);
        let mesh = self.wood_mesh.positions.iter().copied();
        let (lo, hi) = self.needle_bounds;
        super::needle::bounds([lo, hi].into_iter().chain(wood).chain(mesh)).unwrap_or((lo, hi))
    }

    /// Smallest and largest placed needle radius, tree metres (a placement
    /// scales its prototype's radii): the flattened tree's original-line
    /// error range is `2R` of these ([`LodRecord::part_ranges`]).
    pub fn radius_range(&self) -> (f32, f32) {
        self.radius_range
    }

    /// Position of flattened endpoint `end` (`2 · needle + tip`, needles
    /// numbered as [`PrototypeRecord::flatten`] numbers them), tree metres:
    /// the flattened tree's [`crate::model::merge::endpoint_position`].
    /// `None` past the last needle.
    pub fn endpoint_position(&self, end: u32) -> Option<Vec3> {
        let needle = u64::from(end / 2);
        if needle >= self.needle_count() {
            return None;
        }
        let placement = self.needle_offset.partition_point(|&first| first <= needle) - 1;
        let pl = &self.placements[placement];
        let local = &self.prototypes[pl.prototype as usize].needles[(needle - self.needle_offset[placement]) as usize];
        Some(pl.place_point(if end.is_multiple_of(2) { local.base } else { local.tip }))
    }

    /// Summed side area `2rℓ` of the needles under level-2 node `node`
    /// (placements, then merged lines), tree metres²; one entry per node.
    /// A placement's is its prototype's summed in `f64` and scaled by the
    /// square of its scale, so it may differ from the flattened tree's
    /// [`LodRecord::node_needle_area`] in the last bits.
    pub fn tree_node_areas(&self) -> Vec<f32> {
        let prototype_area: Vec<f64> = self
            .prototypes
            .iter()
            .map(|p| p.needles.iter().map(|n| f64::from(n.side_area())).sum())
            .collect();
        let mut areas: Vec<f32> = self
            .placements
            .iter()
            .map(|pl| (prototype_area[pl.prototype as usize] * f64::from(pl.scale) * f64::from(pl.scale)) as f32)
            .collect();
        for line in &self.tree_merged {
            let area = line.children.iter().map(|&c| areas[c as usize]).sum();
            areas.push(area);
        }
        areas
    }

    /// The [`AxisSpread`] of the needles of every level-2 node
    /// (placements, then `tree_merged`), tree metres: each prototype's
    /// needles summed once, turned and scaled by its placements, summed up
    /// the level-2 forest.
    pub fn tree_node_spreads(&self) -> Vec<AxisSpread> {
        let prototype_spread: Vec<AxisSpread> = self
            .prototypes
            .iter()
            .map(|p| {
                p.needles.iter().fold(AxisSpread::default(), |sum, n| {
                    sum + AxisSpread::needle(n.base, n.tip, n.side_area())
                })
            })
            .collect();
        let mut spreads: Vec<AxisSpread> = self
            .placements
            .iter()
            .map(|pl| prototype_spread[pl.prototype as usize].placed(pl.rotation, pl.scale * pl.scale))
            .collect();
        for line in &self.tree_merged {
            let [a, b] = line.children.map(|c| spreads[c as usize]);
            spreads.push(a + b);
        }
        spreads
    }

    /// The spatial error `view` gives level-2 node `node`: its own
    /// sphere's, or the tree sphere's for a camera beyond
    /// [`super::view::VIEW_RANGE`].
    pub fn node_error_seen_from(&self, view: &ViewPoint, node: u32) -> f32 {
        view.node_error(&self.tree_sphere, &self.node_spheres[node as usize])
    }

    /// Needles once placed (the flattened tree's needle count).
    pub fn needle_count(&self) -> u64 {
        *self.needle_offset.last().unwrap_or(&0)
    }

    /// Needles stored in the prototypes.
    pub fn prototype_needle_count(&self) -> u64 {
        self.prototypes.iter().map(|p| p.needles.len() as u64).sum()
    }

    /// Placed needles before placement `p`: needle `i` of placement `p` is
    /// needle `needle_offset(p) + i` of the flattened tree.
    pub fn needle_offset(&self, placement: usize) -> u64 {
        self.needle_offset[placement]
    }

    /// Error of placement `p`'s root line in the tree, metres.
    pub fn placed_root_error(&self, placement: usize) -> f32 {
        let pl = &self.placements[placement];
        let prototype = &self.prototypes[pl.prototype as usize];
        placed_error(prototype, prototype.root(), pl.scale)
    }

    /// Replaces the errors of the level-2 forest by
    /// [`crate::model::merge::MergeErrorBound::Needles`]: each merged line's
    /// error becomes the largest [`crate::model::merge::needle_reach`] of the
    /// placed needles below it, raised to its children's errors (a
    /// placement's: [`PrototypeRecord::placed_root_error`]). The prototypes'
    /// own forests must be final; the forest's shape and ends are kept.
    /// Exact: a placement is searched needle by needle only where its
    /// bounding sphere ([`PrototypeRecord::node_sphere`]) could reach farther
    /// than the needles found so far.
    pub fn tighten_tree_errors(&mut self) {
        use rayon::prelude::*;
        let leaves = self.placements.len();
        let runs = super::merge::LeafRuns::new(leaves, &self.tree_merged);
        let reach: Vec<f32> = self
            .tree_merged
            .par_iter()
            .enumerate()
            .map(|(k, line)| {
                let [a, b] = line.ends.map(|end| {
                    self.endpoint_position(end)
                        .expect("a valid record's lines end at its placed needles' ends")
                });
                // Farthest-reaching spheres first, so that the rest are skipped.
                let mut bounds: Vec<(f32, u32)> = runs
                    .leaves((leaves + k) as u32)
                    .iter()
                    .map(|&p| {
                        let sphere = self.node_sphere(p);
                        let bound = 2.0 * (super::merge::point_segment_distance(sphere.center, a, b) + sphere.radius);
                        (bound, p)
                    })
                    .collect();
                bounds.sort_unstable_by(|x, y| y.0.total_cmp(&x.0));
                let mut farthest = 0.0f32;
                for (bound, p) in bounds {
                    if bound <= farthest {
                        break;
                    }
                    let placement = &self.placements[p as usize];
                    let (la, lb) = (placement.unplace_point(a), placement.unplace_point(b));
                    let local = self.prototypes[placement.prototype as usize]
                        .needles
                        .iter()
                        .map(|n| super::merge::needle_reach(n, la, lb))
                        .fold(0.0f32, f32::max);
                    farthest = farthest.max(local * placement.scale);
                }
                farthest
            })
            .collect();
        for (line, reach) in self.tree_merged.iter_mut().zip(reach) {
            line.error = reach;
        }
        let root_errors: Vec<f32> = (0..leaves).map(|p| self.placed_root_error(p)).collect();
        super::merge::make_errors_monotone(leaves, &mut self.tree_merged, |p| root_errors[p]);
    }

    /// Parent of level-2 node `node` (placements, then merged lines), or [`NO_PARENT`].
    pub fn tree_parent(&self, node: u32) -> u32 {
        self.tree_parent[node as usize]
    }

    /// Flattened node id of local node `node` of placement `p` (see the
    /// module docs for both numberings).
    pub fn flat_local(&self, placement: usize, node: u32) -> u32 {
        let n = self.prototypes[self.placements[placement].prototype as usize]
            .needles
            .len() as u32;
        if node < n {
            (self.needle_offset[placement] + node as u64) as u32
        } else {
            (self.needle_count() + self.merged_offset[placement] + (node - n) as u64) as u32
        }
    }

    /// Flattened node id of level-2 node `node` (a placement's root line
    /// for `node < placements`).
    pub fn flat_tree_node(&self, node: u32) -> u32 {
        let p_count = self.placements.len() as u32;
        if node < p_count {
            let prototype = &self.prototypes[self.placements[node as usize].prototype as usize];
            self.flat_local(node as usize, prototype.root())
        } else {
            let level1 = *self.merged_offset.last().unwrap_or(&0);
            (self.needle_count() + level1 + (node - p_count) as u64) as u32
        }
    }

    /// Every placement's needles placed, in placement order, each in the
    /// group of its placement: the needles of [`PrototypeRecord::flatten`]
    /// without its lines.
    pub fn placed_needles(&self) -> Vec<Needle> {
        let mut needles = Vec::with_capacity(self.needle_count() as usize);
        for (p, placement) in self.placements.iter().enumerate() {
            let prototype = &self.prototypes[placement.prototype as usize];
            needles.extend(prototype.needles.iter().map(|n| placement.place_needle(n, p as u32)));
        }
        needles
    }

    /// The flat record of the same tree: every placement expanded (see the
    /// module docs for its numbering). Its cut at any error equals
    /// [`PrototypeRecord::cut`]'s.
    pub fn flatten(&self) -> Result<LodRecord, RecordInvalid> {
        let needles = self.placed_needles();
        let level1 = *self.merged_offset.last().unwrap_or(&0) as usize;
        let mut merged = Vec::with_capacity(level1 + self.tree_merged.len());
        for (p, placement) in self.placements.iter().enumerate() {
            let prototype = &self.prototypes[placement.prototype as usize];
            let first_end = 2 * self.needle_offset[p] as u32;
            merged.extend(prototype.merged.iter().map(|m| MergedLine {
                ends: m.ends.map(|e| first_end + e),
                children: m.children.map(|c| self.flat_local(p, c)),
                error: m.error * placement.scale,
            }));
        }
        merged.extend(self.tree_merged.iter().map(|m| MergedLine {
            ends: m.ends,
            children: m.children.map(|c| self.flat_tree_node(c)),
            error: m.error,
        }));
        LodRecord::from_parts(
            self.name.clone(),
            needles,
            merged,
            self.wood.clone(),
            self.wood_mesh.clone(),
            self.material,
            self.max_sides,
            self.bake.clone(),
        )
        .map(|mut flat| {
            flat.impostor = self.impostor.clone();
            flat.line_calibration = self.line_calibration;
            flat
        })
    }

    /// The cut at spatial error `e` (tree metres), walked down the level-2
    /// forest and into the placed prototypes without expanding them; nodes
    /// are named as in [`PrototypeRecord::flatten`]. A NaN or negative `e`
    /// counts as 0, an infinite one as the largest finite error.
    pub fn cut(&self, spatial_error: f32) -> Cut {
        let e = if spatial_error > 0.0 {
            spatial_error.min(f32::MAX)
        } else {
            0.0
        };
        self.cut_at(|_| e)
    }

    /// The cut seen from `view` (see [`super::view`]): walked down the
    /// level-2 forest, each merged line and placement at the spatial error
    /// of the nearest point of its own sphere, every node of a placement at
    /// the placement's. A level-2 line whose error equals its parent's is
    /// never in the cut (as at one error, where its interval is empty).
    /// An exact partition of the needles wherever the camera is, inside a
    /// sphere included; named as [`PrototypeRecord::flatten`] numbers its
    /// nodes.
    pub fn cut_seen_from(&self, view: &ViewPoint) -> Cut {
        self.cut_at(|node| self.node_error_seen_from(view, node).min(f32::MAX))
    }

    /// The walk both cuts make: level-2 node `node` (and, for a placement,
    /// every node inside it) at spatial error `error_at(node)`. A line with
    /// its parent's error is walked through: at one error it cannot be in
    /// the cut anyway, and seen from a camera the compact layout leaves it
    /// out.
    fn cut_at(&self, error_at: impl Fn(u32) -> f32) -> Cut {
        let mut cut = Cut::default();
        let p_count = self.placements.len() as u32;
        let mut stack: Vec<u32> = (0..self.tree_parent.len() as u32)
            .filter(|&k| self.tree_parent[k as usize] == NO_PARENT)
            .collect();
        while let Some(node) = stack.pop() {
            let e = error_at(node);
            if node < p_count {
                self.push_placement(&mut cut, node as usize, e);
                continue;
            }
            let line = &self.tree_merged[(node - p_count) as usize];
            let parent = self.tree_parent[node as usize];
            let empty = parent != NO_PARENT && self.tree_merged[(parent - p_count) as usize].error <= line.error;
            if line.error <= e && !empty {
                cut.merged_lines.push(self.flat_tree_node(node));
            } else {
                stack.extend(line.children);
            }
        }
        cut
    }

    /// Adds placement `p`'s part of the cut (its parent is known not to be in it).
    fn push_placement(&self, cut: &mut Cut, placement: usize, e: f32) {
        let pl = &self.placements[placement];
        let prototype = &self.prototypes[pl.prototype as usize];
        let n = prototype.needles.len() as u32;
        let mut stack = vec![prototype.root()];
        while let Some(node) = stack.pop() {
            if node < n {
                let radius = prototype.needles[node as usize].radius * pl.scale;
                let flat = self.flat_local(placement, node);
                match needle_form(relative_error(e, radius), self.max_sides) {
                    NeedleForm::Line => cut.original_lines.push(flat),
                    NeedleForm::Prism { sides } => cut.prisms.push((flat, sides)),
                }
            } else if placed_error(prototype, node, pl.scale) <= e {
                cut.merged_lines.push(self.flat_local(placement, node));
            } else {
                stack.extend(prototype.merged[(node - n) as usize].children);
            }
        }
    }

    /// The same tree as prototypes: every group of a flat record a
    /// prototype placed once as it is. The record's forest must have the
    /// two levels every bake gives it: each group merged down to one line
    /// by merges inside it, then group lines merged across groups
    /// ([`RecordInvalid::NotTwoLevel`] otherwise).
    pub fn from_flat(record: &LodRecord) -> Result<Self, RecordInvalid> {
        const MIXED: u32 = u32::MAX;
        let n = record.needle_count();
        let groups = record.group_count();
        let mut group_start = vec![0u32; groups + 1];
        for needle in &record.needles {
            group_start[needle.group as usize + 1] += 1;
        }
        for g in 0..groups {
            group_start[g + 1] += group_start[g];
        }
        let mut prototypes: Vec<Prototype> = (0..groups)
            .map(|g| Prototype {
                needles: record.needles[group_start[g] as usize..group_start[g + 1] as usize]
                    .iter()
                    .map(|x| Needle { group: 0, ..*x })
                    .collect(),
                merged: Vec::new(),
            })
            .collect();
        // A group's root so far: its first needle, then its latest level-1 line.
        let mut group_root: Vec<u32> = group_start[..groups].to_vec();
        // Per merged line: its group (`MIXED` across groups) and its index
        // in its group's level-1 list or in level 2's.
        let mut merged_group: Vec<u32> = Vec::with_capacity(record.merged.len());
        let mut local_index: Vec<u32> = Vec::with_capacity(record.merged.len());
        let mut level2: Vec<(usize, MergedLine)> = Vec::new();
        let group_of = |node: u32, merged_group: &[u32]| {
            if (node as usize) < n {
                record.needles[node as usize].group
            } else {
                merged_group[node as usize - n]
            }
        };
        for (k, line) in record.merged.iter().enumerate() {
            let [g0, g1] = line.children.map(|c| group_of(c, &merged_group));
            if g0 != g1 || g0 == MIXED {
                merged_group.push(MIXED);
                local_index.push(level2.len() as u32);
                level2.push((k, *line));
                continue;
            }
            let first = group_start[g0 as usize];
            let prototype = &mut prototypes[g0 as usize];
            let needles = prototype.needles.len() as u32;
            let local = |c: u32| {
                if (c as usize) < n {
                    c - first
                } else {
                    needles + local_index[c as usize - n]
                }
            };
            let ends = line.ends.map(|e| e.wrapping_sub(2 * first));
            if ends.iter().any(|&e| e >= 2 * needles) {
                return Err(RecordInvalid::NotTwoLevel(k));
            }
            let children = line.children.map(local);
            merged_group.push(g0);
            local_index.push(prototype.merged.len() as u32);
            prototype.merged.push(MergedLine {
                ends,
                children,
                error: line.error,
            });
            group_root[g0 as usize] = (n + k) as u32;
        }
        let tree_merged = level2
            .iter()
            .map(|&(k, line)| {
                let child = |c: u32| match group_of(c, &merged_group) {
                    MIXED => Some(groups as u32 + local_index[c as usize - n]),
                    g if group_root[g as usize] == c => Some(g),
                    _ => None,
                };
                match line.children.map(child) {
                    [Some(a), Some(b)] => Ok(MergedLine {
                        ends: line.ends,
                        children: [a, b],
                        error: line.error,
                    }),
                    _ => Err(RecordInvalid::NotTwoLevel(k)),
                }
            })
            .collect::<Result<Vec<_>, _>>()?;
        Self::from_parts(
            record.name.clone(),
            prototypes,
            (0..groups as u32).map(Placement::identity).collect(),
            tree_merged,
            record.wood.clone(),
            record.wood_mesh.clone(),
            record.material,
            record.max_sides,
            record.bake.clone(),
        )
        .map(|mut prototypes| {
            prototypes.impostor = record.impostor.clone();
            prototypes.line_calibration = record.line_calibration;
            prototypes
        })
    }
}

/// Error of local node `node` of `prototype` placed at `scale`, tree metres.
/// The one product every placed error goes through, so the flattened record
/// and the prototype cut compare the very same numbers.
fn placed_error(prototype: &Prototype, node: u32, scale: f32) -> f32 {
    prototype.node_error(node) * scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The tree's needles' bound is exact (the pruned search finds the
        /// brute-force reach over every placed needle), monotone, and never
        /// above the paper's nested bound on the same forest.
        #[test]
        fn tree_errors_hold_every_placed_needle(seed in 0u64..1_000, placements in 2usize..40) {
            use crate::model::merge::{
                CostContext, GroupLine, MergeOptions, MergeWeights, PartnerSearch, merge_group, merge_group_lines, needle_reach,
                tighten_group_errors,
            };
            let mut rng = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let mut next = move || {
                rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (rng >> 40) as f32 / (1u64 << 24) as f32
            };
            // Two prototypes: a fan of needles and a straight shoot.
            let prototypes: Vec<Prototype> = (0..2)
                .map(|kind| {
                    let needles: Vec<Needle> = (0..6 + 3 * kind)
                        .map(|i| {
                            let base = Vec3::new(0.0, i as f32 * 0.01, 0.0);
                            let direction = Vec3::new(next() - 0.5, 1.0 - kind as f32 * 0.8, next() - 0.5).normalize();
                            Needle { base, tip: base + direction * 0.03, radius: 5e-4, normal: direction.any_orthonormal_vector(), group: 0 }
                        })
                        .collect();
                    let context = CostContext::new(MergeWeights::default(), 1.0, needles.len());
                    let mut merged = merge_group(&needles, &context, &MergeOptions::default());
                    tighten_group_errors(&needles, &mut merged);
                    Prototype { needles, merged }
                })
                .collect();
            let placements: Vec<Placement> = (0..placements)
                .map(|k| Placement {
                    prototype: (k % 2) as u32,
                    rotation: Quat::from_euler(glam::EulerRot::YXZ, next() * 6.3, next() - 0.5, next() - 0.5),
                    translation: Vec3::new(next(), next() * 2.0, next()),
                    scale: 0.5 + next(),
                    ..Placement::identity(0)
                })
                .collect();
            let mut first = 0u32;
            let lines: Vec<GroupLine> = placements
                .iter()
                .map(|p| {
                    let prototype = &prototypes[p.prototype as usize];
                    let ends = prototype.node_ends(prototype.root());
                    let line = GroupLine {
                        a: p.place_point(prototype.endpoint(ends[0])),
                        b: p.place_point(prototype.endpoint(ends[1])),
                        ends: ends.map(|e| 2 * first + e),
                        error: prototype.node_error(prototype.root()) * p.scale,
                        needles: prototype.needles.len() as u32,
                    };
                    first += prototype.needles.len() as u32;
                    line
                })
                .collect();
            let context = CostContext::new(MergeWeights::default(), 3.0, first as usize);
            let nested = merge_group_lines(&lines, &context, PartnerSearch::Exhaustive, |_| {});
            let mut record = PrototypeRecord::from_parts(
                String::new(),
                prototypes.clone(),
                placements.clone(),
                nested.clone(),
                Vec::new(),
                TriangleMesh::default(),
                FoliageMaterial::default(),
                8,
                BakeInfo::default(),
            )
            .unwrap();
            record.tighten_tree_errors();
            let tight = &record.tree_merged;
            // Brute force: the placed needles below each node.
            let placed: Vec<Vec<Needle>> = placements
                .iter()
                .map(|p| prototypes[p.prototype as usize].needles.iter().map(|n| p.place_needle(n, 0)).collect())
                .collect();
            let all: Vec<Needle> = placed.iter().flatten().copied().collect();
            let count = placements.len();
            let mut below: Vec<Vec<usize>> = (0..count).map(|p| vec![p]).collect();
            let mut errors: Vec<f32> = lines.iter().map(|l| l.error).collect();
            for (k, (ours, paper)) in tight.iter().zip(&nested).enumerate() {
                prop_assert_eq!(ours.children, paper.children);
                let union: Vec<usize> = ours.children.iter().flat_map(|&c| below[c as usize].clone()).collect();
                let (a, b) = (
                    crate::model::merge::endpoint_position(&all, ours.ends[0]),
                    crate::model::merge::endpoint_position(&all, ours.ends[1]),
                );
                let reach = union
                    .iter()
                    .flat_map(|&p| placed[p].iter())
                    .map(|n| needle_reach(n, a, b))
                    .fold(0.0f32, f32::max);
                let expected = ours.children.map(|c| errors[c as usize]).into_iter().fold(reach, f32::max);
                prop_assert!((ours.error - expected).abs() <= 1e-5 * expected.max(1e-3), "node {}: {} vs {}", k, ours.error, expected);
                prop_assert!(ours.error <= paper.error * (1.0 + 1e-4), "node {}: {} > {}", k, ours.error, paper.error);
                below.push(union);
                errors.push(ours.error);
            }
        }
    }

    proptest! {
        /// The quick check never passes a placement under which a needle
        /// degenerates: short needles far from the origin, scales from
        /// underflow to overflow, any rotation.
        #[test]
        fn quick_placement_check_implies_every_needle_placed_is_valid(
            q in prop::array::uniform4(-1.0f32..1.0),
            log_scale in -45.0f32..40.0,
            log_translation in -3.0f32..9.0,
            direction in prop::array::uniform3(-1.0f32..1.0),
            log_length in -7.0f32..0.0,
            offset in prop::array::uniform3(-30.0f32..30.0),
        ) {
            let q = Quat::from_array(q);
            prop_assume!(q.length() > 0.1);
            let placement = Placement {
                rotation: q.normalize(),
                translation: Vec3::from_array(direction) * 10f32.powf(log_translation),
                scale: 10f32.powf(log_scale),
                ..Placement::identity(0)
            };
            prop_assume!(placement.is_valid());
            let base = Vec3::from_array(offset);
            let length = 10f32.powf(log_length);
            let needles: Vec<Needle> = [Vec3::X, Vec3::new(0.3, 0.9, 0.1).normalize(), Vec3::Z]
                .iter()
                .map(|&axis| Needle { base, tip: base + axis * length, radius: 1e-4, normal: Vec3::Y, group: 0 })
                .filter(Needle::is_valid)
                .collect();
            prop_assume!(!needles.is_empty());
            let prototype = Prototype { needles: needles.clone(), merged: Vec::new() };
            if PrototypeExtent::of(&prototype).places_validly(&placement) {
                for needle in &needles {
                    prop_assert!(placement.place_needle(needle, 0).is_valid(), "{needle:?} under {placement:?}");
                }
            }
        }
    }

    /// Bounds through the matrix are the quaternion's to rounding; the
    /// quick check passes an ordinary placement and leaves underflowing and
    /// far-away ones to the needle-by-needle check.
    #[test]
    fn matrix_bounds_are_the_placed_needles_bounds() {
        let needles: Vec<Needle> = (0..50)
            .map(|i| {
                let base = Vec3::new(i as f32 * 0.013, (i % 7) as f32 * 0.05, -(i as f32) * 0.021);
                Needle {
                    base,
                    tip: base + Vec3::new(0.01, 0.02, -0.005),
                    radius: 5e-4,
                    normal: Vec3::Y,
                    group: 0,
                }
            })
            .collect();
        let placement = Placement {
            rotation: Quat::from_euler(glam::EulerRot::YXZ, 0.7, -0.4, 1.9),
            translation: Vec3::new(3.0, 17.0, -2.0),
            scale: 1.3,
            ..Placement::identity(0)
        };
        let (lo, hi) = placed_point_bounds(&needles, &placement);
        let (exact_lo, exact_hi) = super::super::needle::bounds(
            needles
                .iter()
                .map(|n| placement.place_needle(n, 0))
                .flat_map(|n| [n.base, n.tip]),
        )
        .unwrap();
        assert!(
            lo.abs_diff_eq(exact_lo, 1e-5) && hi.abs_diff_eq(exact_hi, 1e-5),
            "{lo} {hi} vs {exact_lo} {exact_hi}"
        );
        assert_eq!(
            placed_point_bounds(&needles, &Placement::identity(0)).0,
            super::super::needle::bounds(needles.iter().flat_map(|n| [n.base, n.tip]))
                .unwrap()
                .0
        );
        let extent = PrototypeExtent::of(&Prototype {
            needles: needles.clone(),
            merged: Vec::new(),
        });
        assert!(extent.places_validly(&placement));
        for scale in [1e-40, 1e-20] {
            assert!(!extent.places_validly(&Placement { scale, ..placement }));
        }
        let far = Placement {
            translation: Vec3::X * 1e6,
            ..placement
        };
        assert!(
            !extent.places_validly(&far),
            "0.5 mm ulps swallow 2 cm needles' coordinates"
        );
    }
}
