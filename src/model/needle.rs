//! The input of the LOD model: needles (the paper's cylinders) and wood.

use super::prism::TriangleMesh;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// One needle leaf, as the paper takes it in: a cylinder given by its
/// centerline, its radius and the normal of the triangle (or quad) it replaces.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Needle {
    /// Where the needle is attached to its shoot (one end of the centerline), metres.
    pub base: Vec3,
    /// The free end of the centerline, metres.
    pub tip: Vec3,
    /// Radius of the needle's cylinder, metres (half its width).
    pub radius: f32,
    /// Unit normal of the flat needle (the triangle/quad it replaces); the
    /// normal of both ends of its line.
    pub normal: Vec3,
    /// Phyllotaxy group: the shoot, fascicle or spray the needle belongs to.
    /// Needles of one group are merged together first.
    pub group: u32,
}

impl Needle {
    /// Length of the centerline, metres.
    pub fn length(&self) -> f32 {
        self.base.distance(self.tip)
    }

    /// Projected silhouette area of the needle seen side-on (width × length), m².
    pub fn side_area(&self) -> f32 {
        2.0 * self.radius * self.length()
    }

    /// `true` when every number is finite, the radius positive and the
    /// centerline not degenerate: the needle can be modelled.
    pub fn is_valid(&self) -> bool {
        self.base.is_finite()
            && self.tip.is_finite()
            && self.normal.is_finite()
            && self.radius.is_finite()
            && self.radius > 0.0
            && self.length() > 0.0
    }
}

/// A piece of trunk or branch: a truncated cone from `start` to `end`.
/// Wood is not simplified by the foliage LOD; it is kept so a tree renders whole.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WoodSegment {
    /// Centre of the lower (parent-side) cross-section, metres.
    pub start: Vec3,
    /// Centre of the upper cross-section, metres.
    pub end: Vec3,
    /// Radius at `start`, metres.
    pub start_radius: f32,
    /// Radius at `end`, metres.
    pub end_radius: f32,
}

impl WoodSegment {
    /// `true` when every number is finite and the radii are not negative.
    pub fn is_valid(&self) -> bool {
        self.start.is_finite()
            && self.end.is_finite()
            && self.start_radius.is_finite()
            && self.end_radius.is_finite()
            && self.start_radius >= 0.0
            && self.end_radius >= 0.0
    }
}

/// Perceptual roughness of bark (rough and matte beside the needles'
/// waxy [`FoliageMaterial::roughness`]; its reflectance is the
/// material's): the plugin's wood and the reference's.
pub const BARK_ROUGHNESS: f32 = 0.9;

/// Surface appearance of a tree's needles and bark. The paper gives a tree
/// one material; here needles also take their colour from their age (the
/// [`super::Placement::needle_age`] of their shoot) and from the side of
/// the shoot the viewer sees, and bark from its height
/// ([`super::color`]). With the three extra colours equal to the base
/// ones (as [`FoliageMaterial::uniform`] makes them), it is the paper's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FoliageMaterial {
    /// Linear RGBA base (diffuse) colour of the needles, from
    /// [`super::color::NEEDLE_MATURE_YEARS`] of age on.
    pub needle_color: [f32; 4],
    /// Linear RGBA colour of the bark up to `upper_wood_heights[0]`.
    pub wood_color: [f32; 4],
    /// Perceptual roughness in [0, 1] (stands in for the paper's specular exponent).
    pub roughness: f32,
    /// Specular reflectance in [0, 1].
    pub reflectance: f32,
    /// Linear RGBA colour of this year's needles (age 0), blended into
    /// `needle_color` as they age.
    pub young_needle_color: [f32; 4],
    /// Linear RGBA colour of a shoot's lower side, seen from beneath it
    /// (the pale stomatal bands under a fir's needles).
    pub needle_underside_color: [f32; 4],
    /// Linear RGBA colour of the bark from `upper_wood_heights[1]` up (a
    /// Scots pine's orange upper trunk).
    pub upper_wood_color: [f32; 4],
    /// Heights (tree metres) where the bark starts turning from
    /// `wood_color` to `upper_wood_color`, and where it has.
    pub upper_wood_heights: [f32; 2],
}

impl FoliageMaterial {
    /// One needle colour and one bark colour for the whole tree (the
    /// paper's material): the extra colours equal the base ones.
    pub fn uniform(needle_color: [f32; 4], wood_color: [f32; 4], roughness: f32, reflectance: f32) -> Self {
        Self {
            needle_color,
            wood_color,
            roughness,
            reflectance,
            young_needle_color: needle_color,
            needle_underside_color: needle_color,
            upper_wood_color: wood_color,
            upper_wood_heights: [0.0, 0.0],
        }
    }

    /// Every colour channel, roughness and reflectance, for finiteness checks.
    pub fn numbers(&self) -> impl Iterator<Item = f32> + '_ {
        [
            &self.needle_color,
            &self.wood_color,
            &self.young_needle_color,
            &self.needle_underside_color,
            &self.upper_wood_color,
        ]
        .into_iter()
        .flatten()
        .copied()
        .chain([self.roughness, self.reflectance])
        .chain(self.upper_wood_heights)
    }
}

impl Default for FoliageMaterial {
    fn default() -> Self {
        Self::uniform([0.10, 0.24, 0.08, 1.0], [0.23, 0.16, 0.11, 1.0], 0.6, 0.3)
    }
}

/// A whole tree as it enters the bake: needles, wood and material.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TreeInput {
    /// Human-readable name (species preset, or the source file).
    pub name: String,
    /// The needles. Group ids need not be contiguous or sorted.
    pub needles: Vec<Needle>,
    /// Trunk and branches as cylinders (procedural trees).
    pub wood: Vec<WoodSegment>,
    /// Trunk and branches as a triangle mesh (imported trees), drawn as is.
    #[serde(default)]
    pub wood_mesh: TriangleMesh,
    /// Appearance.
    pub material: FoliageMaterial,
}

impl TreeInput {
    /// Axis-aligned bounds `(min, max)` of the needles' centerlines, or `None`
    /// when there are no needles.
    pub fn needle_bounds(&self) -> Option<(Vec3, Vec3)> {
        bounds(self.needles.iter().flat_map(|n| [n.base, n.tip]))
    }

    /// Number of distinct phyllotaxy groups.
    pub fn group_count(&self) -> usize {
        let mut ids: Vec<u32> = self.needles.iter().map(|n| n.group).collect();
        ids.sort_unstable();
        ids.dedup();
        ids.len()
    }
}

/// Axis-aligned bounds of a set of points, `None` when empty.
pub fn bounds(points: impl IntoIterator<Item = Vec3>) -> Option<(Vec3, Vec3)> {
    points.into_iter().fold(None, |acc, p| match acc {
        None => Some((p, p)),
        Some((lo, hi)) => Some((lo.min(p), hi.max(p))),
    })
}
