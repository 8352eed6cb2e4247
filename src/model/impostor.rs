//! The far representation, free of Bevy: a crown impostor, the tree seen
//! from a ring of directions around its vertical axis and stored as small
//! coverage pictures.
//!
//! Merged lines hold their error bound at any distance, but a dense crown
//! stacks them in depth: a 30 m spruce still needs ~380,000 lines at 1 km
//! (`conifer cut --distance 1000`), where it is ~40 pixels tall. Past the
//! distance where its texel is a fraction of the pixel error, the plugin
//! draws the tree as one camera-facing quad textured with the two views
//! nearest the camera's azimuth instead, cross-faded with the lines over
//! a band of distances ([`FADE_START`], [`FADE_END`]): each sample of the
//! tree's pixels goes to one or the other by an ordered dither
//! ([`impostor_samples`]), so the crown keeps its coverage as it fades.
//!
//! The texel has one size for every tree ([`ImpostorOptions::texel`],
//! 10 cm), so every tree turns into its impostor at the same pixel error
//! whatever its height: with the default options, the fade runs while the
//! pixel error grows from 8 to 16 cm, which at ε = 1 in a 1080-pixel-tall
//! 45° view is from ~104 m to ~208 m. (Texels of a fixed share of the
//! height made a 50 m fir an impostor only past 250 m and a 3 m sapling
//! one from ~20 m.)
//!
//! ## What a texel holds
//!
//! Each view `k` looks at the tree horizontally from the azimuth
//! `φ_k = 2πk / views` (the camera on `+z` for `k = 0`, its right `+x`),
//! orthographic, over the tree's box: `columns × rows` texels of side
//! [`CrownImpostor::texel`] metres. A texel stores four bytes:
//!
//! * **coverage**: the fraction of the texel the needles and wood hide;
//! * **wood**: the fraction where wood is what the camera sees (no needle
//!   lies in front of the wood's near side there), drawn with the wood's
//!   colour;
//! * **vertical, across**: how its needles are lit, as shares of a
//!   vertical cylinder and of a horizontal one across the view (the rest
//!   lit as a sphere: [`super::shading::texel_shares`]), each times the
//!   coverage, so that filtering the texels averages them by what they
//!   cover. Lighting one mean needle axis per texel, as the first
//!   impostors did, lit a crown's spread shoots as whatever direction
//!   their mean happened to take: measured against each texel's needles
//!   (Lambert, the sun high in front, low from the side, low behind: the
//!   `conifer eval` suns), the mean-absolute error over the mature silver
//!   fir's texels was 0.080 / 0.056 / 0.002 with the mean axis and
//!   0.021 / 0.019 / 0.001 with the shares.
//!
//! ## Coverage-true baking
//!
//! Each view is rasterized exactly, as the reference draws the tree:
//! [`SAMPLES_PER_TEXEL`]² binary samples a texel, a sample covered when
//! its centre lies in a needle's silhouette (its strip, `2r` wide between
//! its ends, and its prism's end caps seen at its slant:
//! [`super::look::PieceEnds::Capped`]) or a wood segment's trapezoid
//! ([`super::look::SampleBits`], as `look::side_coverage` measures crowns).
//! Needles in depth overlap exactly where they overlap in the picture, so
//! a texel never covers more than itself and a clumped crown keeps the gaps
//! between its shoots. (An earlier bake spread each needle's area as an
//! optical depth and took `1 − exp(−τ)` per cell, as if needles lay at
//! random: on the mature spruce, whose widened needles lie side by side on
//! their shoots, that under-covered a texel by 0.018 on average and by
//! 0.04–0.05 in texels 40–90 % covered.) A texel's coverage is its samples' mean,
//! and the mip levels the plugin samples at a distance are means of
//! texels, so the impostor's coverage at any size is the samples' mean.

use super::look::{PieceEnds, SampleBits};
use super::needle::{Needle, WoodSegment};
use super::prism::TriangleMesh;
use super::shading::{TexelShares, cylinder_lambert, texel_shares, visible_frame};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Binary samples per texel along each axis when baking (256 a texel).
pub const SAMPLES_PER_TEXEL: u32 = 16;

/// Spatial error, in texels, from which the plugin starts fading the
/// lines into the impostor (a texel projects to `1 / FADE_START` of the
/// pixel error: the impostor starts magnified 1.25 times).
pub const FADE_START: f32 = 0.8;

/// Spatial error, in texels, from which the plugin draws only the impostor
/// (a pixel error spans 1.6 texels, so each pixel is the mean of a few
/// texels: at the default texel, the mean of 16 × 16 binary samples over
/// 16 cm).
pub const FADE_END: f32 = 1.6;

/// The band of camera elevations over the crown centre across which the
/// impostor gives way to the tree's lines: its pictures are side views, so
/// a camera looking down on a tree sees its lines. Stored as tangents, as
/// the plugin's cull pass compares them; build one from degrees with
/// [`SteepFade::from_degrees`].
///
/// Seen from 27° above, the mature Norway spruce and Scots pine as their
/// impostors have crown colour errors of 12.92 and 18.00 (of 255) where
/// their lines have 4.49 and 6.67, and 6.10 and 5.12 level
/// (`docs/eval/from-above`): lowering the band trades that error for the
/// lines' cost of the trees it turns back into lines.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SteepFade {
    /// Tangent of the elevation up to which the impostor is drawn in full.
    pub start: f32,
    /// Tangent of the elevation from which it is not drawn at all; above
    /// `start`.
    pub end: f32,
}

impl SteepFade {
    /// The default band in degrees, `[start, end]`: 30° to 45°.
    pub const DEFAULT_DEGREES: [f32; 2] = [30.0, 45.0];

    /// The default band, [`SteepFade::DEFAULT_DEGREES`] as tangents.
    pub const DEFAULT: Self = Self {
        start: 0.577_350_26,
        end: 1.0,
    };

    /// The band from `start_deg` to `end_deg` degrees above the crown
    /// centre. Each is clamped to `[0, 89.9]`; `end_deg` to at least
    /// `start_deg` plus 0.1° (a start of 89.9° or more keeps the impostor
    /// at every elevation). A value that is not a number takes the
    /// default's (30° or 45°).
    pub fn from_degrees(start_deg: f32, end_deg: f32) -> Self {
        const MAX_DEG: f32 = 89.9;
        let [default_start, default_end] = Self::DEFAULT_DEGREES;
        let start_deg = if start_deg.is_nan() {
            default_start
        } else {
            start_deg.clamp(0.0, MAX_DEG)
        };
        if start_deg >= MAX_DEG {
            return Self::NEVER;
        }
        let end_deg = if end_deg.is_nan() { default_end } else { end_deg };
        let end_deg = end_deg.max(start_deg + 0.1).min(MAX_DEG + 0.09);
        Self {
            start: start_deg.to_radians().tan(),
            end: end_deg.to_radians().tan(),
        }
    }

    /// A band no elevation reaches: the impostor is drawn whatever the
    /// camera's elevation (finite, so that the cull pass's division by
    /// `end − start` stays finite).
    pub const NEVER: Self = Self { start: 1e30, end: 2e30 };

    /// How much of the impostor the elevation of tangent `elevation` (its
    /// absolute value) leaves, in `[0, 1]`: 1 up to `start`, falling
    /// linearly to 0 at `end`; 0 for NaN.
    pub fn keep(self, elevation: f32) -> f32 {
        if elevation.is_nan() {
            return 0.0;
        }
        1.0 - ((elevation.abs() - self.start) / (self.end - self.start)).clamp(0.0, 1.0)
    }
}

impl Default for SteepFade {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The tangent of the elevation over a crown centre of a viewer at
/// `offset` from it: its height over its distance across the ground (at
/// least 1e-9), as the cull pass computes it; what [`SteepFade::keep`] and
/// [`impostor_fade`] take. Straight above or below, a very large number.
pub fn elevation_tangent(offset: Vec3) -> f32 {
    offset.y.abs() / Vec2::new(offset.x, offset.z).length().max(1e-9)
}

/// Reads a band of elevations as command lines give it, `START,END` in
/// degrees (`--impostor-steep 15,30`): both from 0 to 90, `START` below
/// `END`. The message names what was expected otherwise.
pub fn parse_degree_band(text: &str) -> Result<[f32; 2], String> {
    let expected = || format!("`{text}`: expected START,END in degrees, 0 ≤ START < END ≤ 90");
    let values: Vec<f32> = text
        .split(',')
        .map(|x| x.trim().parse().ok())
        .collect::<Option<_>>()
        .ok_or_else(expected)?;
    match values[..] {
        [start, end] if (0.0..=90.0).contains(&start) && (0.0..=90.0).contains(&end) && start < end => Ok([start, end]),
        _ => Err(expected()),
    }
}

/// How far a tree at spatial error `spatial_error` (tree metres) has
/// faded into an impostor of texel side `texel`, seen at an elevation of
/// tangent `elevation` over its crown centre, in `[0, 1]`: 0 up to
/// [`FADE_START`] texels, 1 from [`FADE_END`], linear between, times what
/// the band `steep` keeps of it ([`SteepFade::keep`]), in steps
/// of 1/255 (the CPU reference of the plugin's cull pass, which stores it
/// in 8 bits). 0 for a texel or error that is not positive and finite.
pub fn impostor_fade(spatial_error: f32, texel: f32, elevation: f32, steep: SteepFade) -> f32 {
    if !(texel > 0.0 && texel.is_finite() && spatial_error.is_finite()) {
        return 0.0;
    }
    let t = ((spatial_error / texel - FADE_START) / (FADE_END - FADE_START)).clamp(0.0, 1.0);
    (t * steep.keep(elevation) * 255.0).round() / 255.0
}

/// Ordered dithering's 4 × 4 threshold map (Bayer's; Bevy's
/// `visibility_range_dither` uses the same), `[row][column]`: each of
/// 0–15 once, neighbours far apart, so any share of a block's pixels is
/// spread evenly over it.
pub const CROSSFADE_THRESHOLDS: [[u32; 4]; 4] = [[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]];

/// The 2 × 2 threshold map `[row][column]` under 4× MSAA: sample `s` of a
/// pixel has threshold `4·s +` its pixel's entry, so the 16 thresholds
/// span a 2 × 2 block's 16 samples and every pixel gets a quarter of each
/// four.
pub const CROSSFADE_SAMPLE_THRESHOLDS: [[u32; 2]; 2] = [[0, 2], [3, 1]];

/// The samples (a mask, bit `s` for sample `s`) of framebuffer pixel
/// `pixel` that the impostor, rather than the tree's cut (prisms, lines,
/// wood), draws for instance `tree` faded by `fade_code` (0–255,
/// [`impostor_fade`] × 255 as the cull pass stores it), in a view of
/// `msaa_samples` samples a pixel. The two take complementary samples:
/// the impostor those whose threshold `t` has `(t + ½)/16 < fade`, so
/// `round(16·fade)` of every 16 thresholds. Under 4× MSAA (Bevy's default)
/// the thresholds are a 2 × 2 block's samples
/// ([`CROSSFADE_SAMPLE_THRESHOLDS`]) and each pixel blends both
/// representations in quarters; otherwise they are a 4 × 4 block's pixels
/// ([`CROSSFADE_THRESHOLDS`]) and a pixel is one or the other whole (its
/// mask all ones or zero). Either way the crown keeps its coverage through
/// the fade; blending the two instead, the cut's opacity times `1 − fade`
/// over the impostor's times `fade`, left a crown of coverage `a` at
/// `1 − (1 − a/2)²` halfway (a dense crown 30 % see-through where it is
/// 10 %). A sample the impostor takes at one fade it takes at every larger
/// one, so a tree moving away hands samples over one way. The blocks are
/// shifted by a hash of `tree` so that neighbours do not dither alike.
/// CPU reference of the camera passes' fragment test in
/// `conifer_compact.wgsl`.
pub fn impostor_samples(pixel: [u32; 2], tree: u32, fade_code: u8, msaa_samples: u32) -> u32 {
    let offset = super::compact::pcg_hash(tree);
    let takes = |threshold: u32| 255 * (2 * threshold + 1) < 32 * u32::from(fade_code);
    if msaa_samples == 4 {
        let x = (pixel[0].wrapping_add(offset & 1) % 2) as usize;
        let y = (pixel[1].wrapping_add((offset >> 1) & 1) % 2) as usize;
        (0..4)
            .filter(|&s| takes(4 * s + CROSSFADE_SAMPLE_THRESHOLDS[y][x]))
            .map(|s| 1 << s)
            .sum()
    } else {
        let x = (pixel[0].wrapping_add(offset & 3) % 4) as usize;
        let y = (pixel[1].wrapping_add((offset >> 2) & 3) % 4) as usize;
        if takes(CROSSFADE_THRESHOLDS[y][x]) { u32::MAX } else { 0 }
    }
}

/// How far, in radians, the impostor's card leans away from a light at
/// `elevation` radians above the horizon (negative below) when a tree past
/// a shadow view's budget casts it, for a crown `width` wide and `height`
/// tall. Seen from the light, the crown spans `height·cos(el) +
/// width·sin(|el|)` across it and an upright card only `height·cos(el)`:
/// leaning by `t` about the crown's middle, the card spans `height·cos(|el|
/// − |t|)`, as much (at most `height`, the card facing the light), so its
/// shadow is as long as the crown's. The sign follows the elevation's; 0
/// for a light on the horizon and for sizes or elevations that are not
/// finite or not positive. CPU reference of the shadow pass's
/// `CONIFER_IMPOSTOR` vertex.
pub fn shadow_card_lean(elevation: f32, width: f32, height: f32) -> f32 {
    if !(elevation.is_finite() && width > 0.0 && height > 0.0 && width.is_finite() && height.is_finite()) {
        return 0.0;
    }
    let elevation = elevation.clamp(-std::f32::consts::FRAC_PI_2, std::f32::consts::FRAC_PI_2);
    let across = (elevation.cos() + width / height * elevation.abs().sin()).min(1.0);
    elevation.signum() * (elevation.abs() - across.acos()).max(0.0)
}

/// Shadow samples an impostor texel takes through the crown
/// ([`shadow_sample_depths`]).
pub const SHADOW_SAMPLES: usize = 3;

/// Heights a [`CrownImpostor::crown_radii`] profile holds, bottom to top.
pub const CROWN_PROFILE_STEPS: usize = 32;

/// The trunk where an impostor's pictures show it: its centre (tree-local
/// `x`, `z`) and radius at [`CROWN_PROFILE_STEPS`] heights, the middles of
/// even steps from the pictures' bottom to their top (as
/// [`CrownImpostor::crown_radii`]), radius 0 where no trunk stands.
///
/// A texel keeps how its needles and wood are lit as shares of two
/// cylinders and a sphere, each averaged over its whole width: right for
/// pieces far thinner than a texel, but a trunk several texels wide came
/// out one flat shade across, where the tree's own trunk is lit on one
/// side and dark on the other. With the profile the fragment lights the
/// wood it sees over the trunk as the band of the trunk's round surface
/// its pixel covers ([`crate::model::shading::band_average`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrunkProfile {
    /// The trunk's centre at each height (tree-local `x`, `z`).
    pub centres: [Vec2; CROWN_PROFILE_STEPS],
    /// Its radius at each height, metres; 0 where no trunk stands.
    pub radii: [f32; CROWN_PROFILE_STEPS],
}

impl Default for TrunkProfile {
    /// No trunk anywhere.
    fn default() -> Self {
        Self {
            centres: [Vec2::ZERO; CROWN_PROFILE_STEPS],
            radii: [0.0; CROWN_PROFILE_STEPS],
        }
    }
}

impl TrunkProfile {
    /// Segments steeper than this (the sine of their angle above the
    /// horizontal) can be the trunk: a stem leans, a branch does not stand
    /// that upright where it is the widest wood at its height.
    pub const UPRIGHT: f32 = 0.7;

    /// The trunk of `wood` over heights `bottom` to `top`: at each step's
    /// middle height, the widest upright segment ([`Self::UPRIGHT`]) that
    /// spans it, its centre and radius taken where it crosses that height.
    /// Invalid segments are skipped; no trunk (all radii 0) for an empty
    /// or non-finite span, and for wood given only as a triangle mesh.
    pub fn of(wood: &[WoodSegment], bottom: f32, top: f32) -> Self {
        let mut profile = Self::default();
        if !(bottom.is_finite() && top.is_finite() && top > bottom) {
            return profile;
        }
        let upright: Vec<&WoodSegment> = wood
            .iter()
            .filter(|w| {
                let d = w.end - w.start;
                let length = d.length();
                w.is_valid() && length > 0.0 && d.y.abs() >= Self::UPRIGHT * length
            })
            .collect();
        for step in 0..CROWN_PROFILE_STEPS {
            let height = bottom + (step as f32 + 0.5) / CROWN_PROFILE_STEPS as f32 * (top - bottom);
            let widest = upright
                .iter()
                .filter_map(|w| {
                    let d = w.end - w.start;
                    let t = (height - w.start.y) / d.y;
                    (0.0..=1.0).contains(&t).then(|| {
                        let at = w.start + d * t;
                        (
                            Vec2::new(at.x, at.z),
                            w.start_radius + (w.end_radius - w.start_radius) * t,
                        )
                    })
                })
                .max_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((centre, radius)) = widest {
                profile.centres[step] = centre;
                profile.radii[step] = radius;
            }
        }
        profile
    }

    /// The trunk's centre and radius at tree-local `height` in a profile
    /// from `bottom` to `top`: linear between the steps' middles, the end
    /// steps' outside them ([`CrownImpostor::profile_step`]). CPU reference
    /// of the impostor fragment's `trunk_at`.
    pub fn at(&self, bottom: f32, top: f32, height: f32) -> (Vec2, f32) {
        let (k, t) = CrownImpostor::profile_step(bottom, top, height);
        (
            self.centres[k].lerp(self.centres[k + 1], t),
            self.radii[k] + (self.radii[k + 1] - self.radii[k]) * t,
        )
    }

    /// The band `[s0, s1]` of the trunk's projected width (offsets across
    /// it over its radius, `−1` at its left edge as the camera sees it)
    /// that a pixel covers: the pixel's centre `offset` metres right of the
    /// trunk's axis, its footprint `footprint` metres wide across it. `None`
    /// where the band misses the trunk (or there is none: `radius` 0). CPU
    /// reference of the impostor fragment's `trunk_band`.
    pub fn band(offset: f32, footprint: f32, radius: f32) -> Option<(f32, f32)> {
        if !(radius > 0.0 && offset.is_finite() && footprint.is_finite()) {
            return None;
        }
        let half = 0.5 * footprint.abs();
        let (s0, s1) = (
            ((offset - half) / radius).max(-1.0),
            ((offset + half) / radius).min(1.0),
        );
        (s1 > s0).then_some((s0, s1))
    }
}

/// Bins of a [`WoodVisibility`] across the crown, from its far side to its
/// near side at each height.
pub const WOOD_NEARNESS_BINS: usize = 8;

/// Finer bins the bake counts wood samples in across the pictures' width,
/// before the crown's radius at each height is known.
const WOOD_COUNT_BINS: usize = 64;

/// How many fully covered wood samples' worth a [`WoodVisibility`] bin's
/// fit is drawn toward its height's by (a texel's samples).
const WOOD_FIT_PRIOR: f64 = (SAMPLES_PER_TEXEL * SAMPLES_PER_TEXEL) as f64;

/// Per height and [`WOOD_COUNT_BINS`] nearness, the sums of the wood
/// samples' least-squares fit ([`WoodVisibility`]): `Σ (seen − t)(1 − t)`
/// and `Σ (1 − t)²`.
type WoodCounts = [[[f64; 2]; WOOD_COUNT_BINS]; CROWN_PROFILE_STEPS];

/// How much of the wood its needles leave in sight where they cover the
/// picture, by where the wood lies in the crown: at each of
/// [`CROWN_PROFILE_STEPS`] heights (bottom to top, as
/// [`CrownImpostor::crown_radii`]) and [`WOOD_NEARNESS_BINS`] nearnesses
/// toward the camera (from one crown radius behind the axis to one in
/// front), a share `g`.
///
/// Blended lines are not sorted one by one, so the order of a species'
/// draws decides what lies on top in a pixel. The plugin draws a tree's
/// wood lines twice, before its foliage lines and after them, their
/// opacity `a` split by `g`, this table's at the line's midpoint
/// ([`WoodVisibility::at`], [`wood_layer_opacities`]). In a pixel whose
/// needle lines let `t` through, the wood then takes `a·(g + (1 − g)·t)`
/// of it: all of its opacity where no needle covers the pixel, `g` of it
/// where they cover it all. The bake fits `g` on the impostor's binary
/// samples: per height and nearness, the least-squares fit of `seen ≈ g +
/// (1 − g)·t` over the wood's samples in every view, `seen` 1 where no
/// needle lies in front of the wood (the texels' `wood`) and `t` the
/// share of the sample's texel no needle covers. Drawn only before the
/// needles, the young Scots pine's branches took `a·t` (its densest crown
/// pixels 7.7 of 255 short in red), drawn only after them `a` (11.0
/// over), and drawn after at the mean share of the wood in sight, 8.5
/// over: the wood is hidden most where the needles are densest.
#[derive(Clone, Debug, PartialEq)]
pub struct WoodVisibility {
    /// The shares `g`, `[height][nearness]`, each in `[0, 1]` in steps of
    /// 1/255.
    pub shares: [[f32; WOOD_NEARNESS_BINS]; CROWN_PROFILE_STEPS],
}

impl Default for WoodVisibility {
    /// The wood in sight wherever it is (a tree without needles).
    fn default() -> Self {
        Self {
            shares: [[1.0; WOOD_NEARNESS_BINS]; CROWN_PROFILE_STEPS],
        }
    }
}

/// The opacities of a camera's two draws of a wood line of opacity
/// `opacity` whose share in sight where the needles cover the pixel is
/// `in_sight` ([`WoodVisibility`]): `(under, over)`, drawn before the
/// foliage lines and after them, `a·(1 − g)/(1 − a·g)` and `a·g`. Blended
/// over a pixel that lets `b` through, needle lines that let `t` through
/// between them, the wood takes `a·(g + (1 − g)·t)` of the pixel and `b`
/// keeps `t·(1 − a)`, as with the wood among the needles. Exact when `a`
/// is what the line covers of the pixel: the shaders split a wide area
/// line's coverage of each pixel in the fragment stage (split by its
/// opacity of 1, a pixel it half covers would take `½ + ½·g·½` with
/// nothing between the layers), a thinner line's opacity in the vertex
/// stage (its strip is as wide as its opacity; a hardware line covers its
/// pixels whole). Inputs are clamped to `[0, 1]`. CPU reference of the
/// wood lines' shaders (`CONIFER_WOOD_LAYERS`).
pub fn wood_layer_opacities(opacity: f32, in_sight: f32) -> (f32, f32) {
    let (a, g) = (clamp_share(opacity), clamp_share(in_sight));
    (a * (1.0 - g) / (1.0 - a * g).max(1e-6), a * g)
}

/// `value` in `[0, 1]`, 0 for NaN.
fn clamp_share(value: f32) -> f32 {
    if value.is_nan() { 0.0 } else { value.clamp(0.0, 1.0) }
}

impl WoodVisibility {
    /// The shares as bytes (`share · 255`), heights major.
    pub fn to_bytes(&self) -> Vec<u8> {
        unit_table_bytes(&self.shares)
    }

    /// The table [`WoodVisibility::to_bytes`] gave; `None` for another
    /// length.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        unit_table_from_bytes(bytes).map(|shares| Self { shares })
    }

    /// The share `g` at tree-local `height` and `nearness`
    /// (metres toward the camera from the axis, horizontally), for a crown
    /// of profile `radii` between `bottom` and `top`
    /// ([`CrownImpostor::crown_radius_at`]): bilinear between the bins'
    /// middles, the end bins' outside them. 1 for inputs that are not
    /// finite. CPU reference of the wood lines' `wood_visibility_at` in
    /// the plugin's vertex shader.
    pub fn at(&self, radii: &[f32; CROWN_PROFILE_STEPS], bottom: f32, top: f32, height: f32, nearness: f32) -> f32 {
        if !(height.is_finite() && nearness.is_finite() && bottom.is_finite() && top > bottom && top.is_finite()) {
            return 1.0;
        }
        let radius = CrownImpostor::crown_radius_at(radii, bottom, top, height).max(1e-6);
        let steps = CROWN_PROFILE_STEPS as f32;
        let bins = WOOD_NEARNESS_BINS as f32;
        let fh = ((height - bottom) / (top - bottom) * steps - 0.5).clamp(0.0, steps - 1.0);
        let fn_ = ((nearness / radius + 1.0) * 0.5 * bins - 0.5).clamp(0.0, bins - 1.0);
        let (k, b) = (
            (fh as usize).min(CROWN_PROFILE_STEPS - 2),
            (fn_ as usize).min(WOOD_NEARNESS_BINS - 2),
        );
        let (th, tn) = (fh - k as f32, fn_ - b as f32);
        let row = |k: usize| self.shares[k][b] * (1.0 - tn) + self.shares[k][b + 1] * tn;
        (row(k) * (1.0 - th) + row(k + 1) * th).clamp(0.0, 1.0)
    }

    /// The shares from per-height fit sums ([`WoodCounts`]) in
    /// [`WOOD_COUNT_BINS`] nearness bins across `[-half_width,
    /// half_width]`, regrouped by each height's crown radius. A bin's fit
    /// is drawn toward its height's by [`WOOD_FIT_PRIOR`] samples' worth,
    /// and a height's toward the whole tree's, so that a bin of a few
    /// samples does not swing from 0 to 1 beside its neighbours; a tree
    /// whose needles cover none of its wood is in sight wherever it is.
    fn from_counts(counts: &WoodCounts, radii: &[f32; CROWN_PROFILE_STEPS], half_width: f32) -> Self {
        let mut visibility = Self::default();
        let mut by_height = [[[0.0f64; 2]; WOOD_NEARNESS_BINS]; CROWN_PROFILE_STEPS];
        for (step, by_nearness) in counts.iter().enumerate() {
            let radius = radii[step].max(1e-6);
            for (bin, fit) in by_nearness.iter().enumerate() {
                let nearness = ((bin as f32 + 0.5) / WOOD_COUNT_BINS as f32 * 2.0 - 1.0) * half_width;
                let u = ((nearness / radius + 1.0) * 0.5 * WOOD_NEARNESS_BINS as f32).floor();
                let target = u.clamp(0.0, (WOOD_NEARNESS_BINS - 1) as f32) as usize;
                by_height[step][target][0] += fit[0];
                by_height[step][target][1] += fit[1];
            }
        }
        let sum = |fits: &mut dyn Iterator<Item = &[f64; 2]>| fits.fold([0.0, 0.0], |s, f| [s[0] + f[0], s[1] + f[1]]);
        let tree = sum(&mut by_height.iter().flatten());
        if tree[1] <= 0.0 {
            return visibility;
        }
        let fit = |s: [f64; 2], prior: f64| (s[0] + WOOD_FIT_PRIOR * prior) / (s[1] + WOOD_FIT_PRIOR);
        let tree_share = (tree[0] / tree[1]).clamp(0.0, 1.0);
        for (step, bins) in by_height.iter().enumerate() {
            let height_share = fit(sum(&mut bins.iter()), tree_share).clamp(0.0, 1.0);
            for (bin, s) in bins.iter().enumerate() {
                let share = fit(*s, height_share).clamp(0.0, 1.0) as f32;
                // In steps of 1/255, as record files store it.
                visibility.shares[step][bin] = (share * 255.0).round() / 255.0;
            }
        }
        visibility
    }
}

/// Where an impostor texel takes the shadows it receives: depths (tree
/// metres, toward the camera from the card) of [`SHADOW_SAMPLES`] points
/// on the view ray through the crown, which the shader averages. The ray
/// enters a crown of `radius` (at the texel's height,
/// [`CrownImpostor::crown_radius_at`]) at `√(radius² − offset²)` for a
/// texel `offset` from the axis across the card, and crosses a chord
/// twice that long. Along it the needles are as dense as the crown's
/// rings say (`density`, its [`CrownDensity::row_at`] at the texel's
/// height, read at each point's distance from the axis,
/// [`density_across`]), taken in [`SHADOW_DEPTH_STEPS`] even steps; lying
/// at random within that, with the texel's `coverage` (1 − what the chord
/// lets through), the share `F(s)` of the chord's needles in front of
/// depth `s` holds the seen ones in front of it with probability
/// `(1 − (1 − coverage)^F(s)) / coverage`, and the points sit at the 1/6,
/// 1/2 and 5/6 quantiles of that, linear within a step: toward the near
/// side in a dense crown, along the chord in a sparse one, and deeper
/// where the needles crowd toward the axis (branches spread from the
/// trunk). With the needles even along the chord (the density 1 every
/// ring, as a record before format 13 reads) the quantiles are `½ chord −
/// chord · ln(1 − q · coverage) / ln(1 − coverage)`; on the mature
/// Norway spruce that put the middle sample 0.88 m in front of the
/// texel's median seen needle on average (a depth buffer of its needles,
/// `tests/record_file.rs`), the crown's rings 0.40 m, and in the shadow
/// maps the impostor's sunlit side took 1.41 times the light its lines do
/// (1.24 with the rings). One plane (the card, or the crown's near side)
/// takes a neighbour's shadow with a hard edge and none of the crown's
/// own: its sunlit impostors read flat and pale. Texels outside the
/// crown's circle, and inputs that are not finite, take the three at the
/// card's plane offset by nothing; a chord whose rings hold no needles is
/// taken as even. CPU reference of the impostor fragment's
/// `impostor_shadow_depths`.
pub fn shadow_sample_depths(
    coverage: f32,
    offset: f32,
    radius: f32,
    density: &[f32; CROWN_DENSITY_RINGS],
) -> [f32; SHADOW_SAMPLES] {
    let half_chord = (radius * radius - offset * offset).max(0.0).sqrt();
    if !(half_chord > 0.0 && half_chord.is_finite() && coverage.is_finite()) {
        return [0.0; SHADOW_SAMPLES];
    }
    let coverage = coverage.clamp(1e-4, 0.999);
    let step = 2.0 * half_chord / SHADOW_DEPTH_STEPS as f32;
    // The chord's needles in front of each step's far end, in steps' worth
    // of density, from the near side.
    let mut in_front = [0.0f32; SHADOW_DEPTH_STEPS + 1];
    for k in 0..SHADOW_DEPTH_STEPS {
        let depth = half_chord - (k as f32 + 0.5) * step;
        let share = (offset * offset + depth * depth).sqrt() / radius;
        in_front[k + 1] = in_front[k] + density_across(density, share);
    }
    if !(in_front[SHADOW_DEPTH_STEPS] > 0.0 && in_front[SHADOW_DEPTH_STEPS].is_finite()) {
        for (k, sum) in in_front.iter_mut().enumerate() {
            *sum = k as f32;
        }
    }
    let through = (1.0 - coverage).ln();
    [1.0f32 / 6.0, 0.5, 5.0 / 6.0].map(|q| {
        let wanted = in_front[SHADOW_DEPTH_STEPS] * (1.0 - q * coverage).ln() / through;
        let k = (0..SHADOW_DEPTH_STEPS - 1)
            .find(|&k| in_front[k + 1] >= wanted)
            .unwrap_or(SHADOW_DEPTH_STEPS - 1);
        let within = ((wanted - in_front[k]) / (in_front[k + 1] - in_front[k]).max(1e-12)).clamp(0.0, 1.0);
        half_chord - (k as f32 + within) * step
    })
}

/// Steps a texel's ray through the crown is taken in by
/// [`shadow_sample_depths`].
pub const SHADOW_DEPTH_STEPS: usize = 16;

/// Rings a [`CrownDensity`] holds at each height: even shares of the
/// crown's radius there, from the axis out.
pub const CROWN_DENSITY_RINGS: usize = 8;

/// How densely the crown's needles fill it, by height and distance from
/// the axis: at each of [`CROWN_PROFILE_STEPS`] heights (bottom to top, as
/// [`CrownImpostor::crown_radii`]) and [`CROWN_DENSITY_RINGS`] rings (ring
/// `k` from `k/8` to `(k + 1)/8` of the crown's radius at the needle's
/// height; needles past it count in the last), the needles' area
/// (`2·radius·length`, by their middles) over the ring's volume, each
/// height's densest ring 1. Branches spread from the trunk, so a crown's
/// needles crowd toward its axis (a whorl's density falls as one over the
/// distance), and the impostor's shadow samples go where a texel's needles
/// are seen ([`shadow_sample_depths`]). A height without needles is even.
#[derive(Clone, Debug, PartialEq)]
pub struct CrownDensity {
    /// Relative densities, `[height][ring]`, each in `[0, 1]` in steps of
    /// 1/255.
    pub rings: [[f32; CROWN_DENSITY_RINGS]; CROWN_PROFILE_STEPS],
}

impl Default for CrownDensity {
    /// Needles even through the crown (what the shadow samples took before
    /// record format 13).
    fn default() -> Self {
        Self {
            rings: [[1.0; CROWN_DENSITY_RINGS]; CROWN_PROFILE_STEPS],
        }
    }
}

impl CrownDensity {
    /// Measures the density of `needles` (tree-local; invalid ones
    /// skipped) in the crown `impostor` pictures (its axis, height span
    /// and [`CrownImpostor::crown_radii`]).
    pub fn measure<'a>(needles: impl IntoIterator<Item = &'a Needle>, impostor: &CrownImpostor) -> Self {
        let radii = impostor.crown_radii();
        let (bottom, top) = (impostor.bottom, impostor.top());
        let mut area = [[0.0f64; CROWN_DENSITY_RINGS]; CROWN_PROFILE_STEPS];
        for needle in needles.into_iter().filter(|n| n.is_valid()) {
            let middle = needle.base.lerp(needle.tip, 0.5);
            let step = ((middle.y - bottom) / (top - bottom) * CROWN_PROFILE_STEPS as f32).floor();
            if !(step >= 0.0 && step < CROWN_PROFILE_STEPS as f32) {
                continue;
            }
            let radius = CrownImpostor::crown_radius_at(&radii, bottom, top, middle.y).max(1e-6);
            let distance = Vec2::new(middle.x, middle.z).distance(impostor.axis);
            let ring = ((distance / radius * CROWN_DENSITY_RINGS as f32) as usize).min(CROWN_DENSITY_RINGS - 1);
            area[step as usize][ring] += f64::from(2.0 * needle.radius * needle.length());
        }
        let mut density = Self::default();
        for (row, sums) in density.rings.iter_mut().zip(&area) {
            // A ring's volume in a height's slice goes as (k + 1)² − k².
            let per_volume: [f64; CROWN_DENSITY_RINGS] = std::array::from_fn(|k| sums[k] / (2 * k + 1) as f64);
            let densest = per_volume.iter().fold(0.0f64, |a, &b| a.max(b));
            if densest > 0.0 && densest.is_finite() {
                // In steps of 1/255, as record files store it.
                *row = per_volume.map(|d| ((d / densest * 255.0).round() / 255.0) as f32);
            }
        }
        density
    }

    /// The rings' densities at tree-local `height` of a crown from
    /// `bottom` to `top`: linear between the heights' middles, the end
    /// heights' outside them ([`CrownImpostor::profile_step`]). CPU
    /// reference of the impostor fragment's `crown_density_row`.
    pub fn row_at(&self, bottom: f32, top: f32, height: f32) -> [f32; CROWN_DENSITY_RINGS] {
        let (k, t) = CrownImpostor::profile_step(bottom, top, height);
        std::array::from_fn(|ring| self.rings[k][ring] * (1.0 - t) + self.rings[k + 1][ring] * t)
    }

    /// The densities as bytes (`density · 255`), heights major.
    pub fn to_bytes(&self) -> Vec<u8> {
        unit_table_bytes(&self.rings)
    }

    /// The table [`CrownDensity::to_bytes`] gave; `None` for another
    /// length.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        unit_table_from_bytes(bytes).map(|rings| Self { rings })
    }
}

/// A table of values in `[0, 1]` as bytes (`value · 255`, rounded), rows
/// major.
fn unit_table_bytes<const COLUMNS: usize>(rows: &[[f32; COLUMNS]]) -> Vec<u8> {
    rows.iter()
        .flatten()
        .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
}

/// The table [`unit_table_bytes`] gave; `None` for another length.
fn unit_table_from_bytes<const COLUMNS: usize, const ROWS: usize>(bytes: &[u8]) -> Option<[[f32; COLUMNS]; ROWS]> {
    if bytes.len() != COLUMNS * ROWS {
        return None;
    }
    let mut table = [[0.0; COLUMNS]; ROWS];
    for (k, &byte) in bytes.iter().enumerate() {
        table[k / COLUMNS][k % COLUMNS] = f32::from(byte) / 255.0;
    }
    Some(table)
}

/// The density of a [`CrownDensity::row_at`] row `density` at `share` of
/// the crown's radius from the axis: linear between the rings' middles,
/// the end rings' outside them (the first ring's for NaN). CPU reference
/// of the impostor fragment's `density_across`.
pub fn density_across(density: &[f32; CROWN_DENSITY_RINGS], share: f32) -> f32 {
    let rings = CROWN_DENSITY_RINGS as f32;
    let f = (share * rings - 0.5).clamp(0.0, rings - 1.0);
    let f = if f.is_nan() { 0.0 } else { f };
    let k = (f as usize).min(CROWN_DENSITY_RINGS - 2);
    let t = f - k as f32;
    density[k] * (1.0 - t) + density[k + 1] * t
}

/// Where on its calm card an impostor fragment reads the crown's picture
/// when the wind moves it: the fragment's calm card point `at`
/// (tree-local) moved back by `moved` (tree metres) across the card
/// (`right`, unit) and up it (`up`, unit); a move along the view moves no
/// picture. The quad's corners lean with the trunk
/// ([`crate::model::wind::trunk_offset`] there), straight between them,
/// so `moved` is what the field ([`crate::model::wind::wind_offset`])
/// moves `at` by less what that lean moved the fragment by: the
/// branches' sway, the shoots' flutter, and where the trunk's bend strays
/// from the straight lean. The quad is wider and taller by
/// [`crate::model::wind::impostor_margin`] on every side, so the picture
/// can move past the calm crown's edge. The field is taken at the card's
/// plane, which stands on the trunk's axis turned to the camera: the
/// middle of the chord a texel's ray crosses the crown on, and at the
/// crown's edge, where a move shows most, where its needles are. Moving
/// back by the field at `at` rather than at the moved point is the first
/// step of the inverse: off by the field's slope times the move. CPU
/// reference of the impostor fragment's `impostor_swayed_uv`.
pub fn swayed_card_point(at: Vec3, right: Vec3, up: Vec3, moved: Vec3) -> Vec3 {
    if !moved.is_finite() {
        return at;
    }
    at - right * moved.dot(right) - up * moved.dot(up)
}

/// Fewest texels over a tree's height: a smaller tree gets texels smaller
/// than [`ImpostorOptions::texel`].
pub const MIN_ROWS: u32 = 8;

/// Most texels over a tree's height: a taller tree gets texels larger than
/// [`ImpostorOptions::texel`] (at the default 10 cm, trees over 51 m), which
/// bounds the bake's memory (16² samples a texel, two views at a time on
/// two threads).
pub const MAX_ROWS: u32 = 512;

/// Texels both sides of an impostor are whole multiples of: its first
/// four mip levels halve exactly.
pub const MIP_ALIGN: u32 = 16;

/// How a [`CrownImpostor`] is baked.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImpostorOptions {
    /// Views around the vertical axis (at least 1).
    pub views: u32,
    /// Side of a texel, tree-local metres (positive): the tree's height is
    /// cut into `ceil(height / texel)` rows, clamped to [`MIN_ROWS`] ..=
    /// [`MAX_ROWS`], and the texel is then the height over the rows (the
    /// picture then grows to whole multiples of [`MIP_ALIGN`] texels).
    pub texel: f32,
}

impl Default for ImpostorOptions {
    /// Eight views, texels of 10 cm. Measured on the six mature records
    /// (one view, footprint-filtered to 19 cm pixels, the pixel at 250 m
    /// in a 1080-pixel 45° view, against a bake at a fifth of the pixel):
    /// the coverage error over the crown's box is 0.0043–0.0068 at 10 cm
    /// and 0.0104–0.0161 at 16 cm (the texel 192 rows gave a 30 m tree).
    /// With 8 views the bake takes 1.5–3.9 s on two threads and the mip
    /// chain is 0.73–2.24 MB.
    fn default() -> Self {
        Self { views: 8, texel: 0.10 }
    }
}

/// A crown impostor (module docs): `views` pictures of `columns × rows`
/// texels, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct CrownImpostor {
    /// Views around the vertical axis.
    pub views: u32,
    /// Texels across.
    pub columns: u32,
    /// Texels up.
    pub rows: u32,
    /// The vertical axis the views turn around (tree-local `x`, `z`).
    pub axis: Vec2,
    /// Half the pictures' width, metres: the farthest any needle or wood
    /// reaches from the axis.
    pub half_width: f32,
    /// Tree-local height of the pictures' bottom edge.
    pub bottom: f32,
    /// Side of a texel, metres.
    pub texel: f32,
    /// `views × rows × columns` texels: coverage, wood, vertical share ×
    /// coverage, across share × coverage (module docs).
    pub texels: Vec<[u8; 4]>,
    /// How much of the wood the needles leave in sight, by height and
    /// depth in the crown.
    pub wood_visibility: WoodVisibility,
    /// How densely the needles fill the crown, by height and distance
    /// from the axis: where a texel's shadow samples go.
    pub crown_density: CrownDensity,
    /// The ages and sides of the needles the views see first
    /// ([`super::color::NeedleMix::seen`]), which colour the far crown;
    /// `None` for a tree without ages (a flat record) or an older record.
    pub seen_needles: Option<super::color::NeedleMix>,
    /// How its direct light is scaled so that its texels are lit as the
    /// needles its views show ([`CrownImpostor::view_light_scale`]);
    /// `None` (every scale 1) for an older record.
    pub view_light_scale: Option<ViewLightScale>,
}

/// One texel decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImpostorTexel {
    /// Fraction of the texel hidden, in `[0, 1]`.
    pub coverage: f32,
    /// Fraction hidden by wood, in `[0, coverage]`.
    pub wood: f32,
    /// How what hides it is lit (module docs).
    pub shares: TexelShares,
}

/// Most taps along each side the plugin's fragment shader takes of a
/// pixel's footprint on the impostor (16 in all).
pub const MAX_FOOTPRINT_TAPS: u32 = 4;

/// Taps along each side for a pixel whose footprint is `texels` level-0
/// texels across: one per texel, at least 1, at most
/// [`MAX_FOOTPRINT_TAPS`] (a tap then reads the level whose texel is its
/// share of the footprint). 1 for a footprint that is not finite.
pub fn footprint_taps(texels: f32) -> u32 {
    if !texels.is_finite() {
        return 1;
    }
    texels.ceil().clamp(1.0, MAX_FOOTPRINT_TAPS as f32) as u32
}

/// An impostor's mip chain decoded for sampling as the GPU samples it:
/// normalized coordinates, clamped to the edge, bilinear within a level
/// and linear between levels. The CPU reference of the plugin's fragment
/// shader (`impostor_footprint` in `conifer_compact.wgsl`).
#[derive(Clone, Debug)]
pub struct ImpostorMips {
    views: u32,
    /// Each level's `(columns, rows, texels)`, view-major.
    levels: Vec<(u32, u32, Vec<[u8; 4]>)>,
}

impl ImpostorMips {
    /// The mip chain of `impostor` ([`CrownImpostor::mip_chain`]).
    pub fn new(impostor: &CrownImpostor) -> Self {
        Self {
            views: impostor.views,
            levels: impostor.mip_chain(),
        }
    }

    /// Mip levels (level 0 is the impostor's own texels).
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Level 0's `(columns, rows)`.
    pub fn size(&self) -> (u32, u32) {
        let (w, h, _) = &self.levels[0];
        (*w, *h)
    }

    /// Texel `(x, y)` of `level` in `view`, clamped to the edge, as four
    /// values in `[0, 1]` (coverage, wood, the two shares times coverage).
    fn texel(&self, view: u32, level: usize, x: i64, y: i64) -> [f32; 4] {
        let (w, h, texels) = &self.levels[level];
        let x = x.clamp(0, i64::from(*w) - 1) as u32;
        let y = y.clamp(0, i64::from(*h) - 1) as u32;
        let view = view.min(self.views.saturating_sub(1));
        texels[((view * h + y) * w + x) as usize].map(|b| f32::from(b) / 255.0)
    }

    /// Bilinear sample of `level` at normalized `uv` (`u` right, `v` down).
    fn bilinear(&self, view: u32, level: usize, uv: Vec2) -> [f32; 4] {
        let (w, h, _) = &self.levels[level];
        let p = uv * Vec2::new(*w as f32, *h as f32) - 0.5;
        let (x0, y0) = (p.x.floor(), p.y.floor());
        let (fx, fy) = (p.x - x0, p.y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let corners = [
            (self.texel(view, level, x0, y0), (1.0 - fx) * (1.0 - fy)),
            (self.texel(view, level, x0 + 1, y0), fx * (1.0 - fy)),
            (self.texel(view, level, x0, y0 + 1), (1.0 - fx) * fy),
            (self.texel(view, level, x0 + 1, y0 + 1), fx * fy),
        ];
        let mut out = [0.0; 4];
        for (texel, weight) in corners {
            for (o, t) in out.iter_mut().zip(texel) {
                *o += t * weight;
            }
        }
        out
    }

    /// Trilinear sample at normalized `uv` with the screen derivatives
    /// `du`, `dv` of `uv` (what WGSL's `textureSampleGrad` takes): the
    /// level of detail is `log2` of the longer derivative in level-0
    /// texels, clamped to the chain.
    pub fn sample_grad(&self, view: u32, uv: Vec2, du: Vec2, dv: Vec2) -> [f32; 4] {
        let (w, h) = self.size();
        let texels = Vec2::new(w as f32, h as f32);
        let rho = (du * texels).length().max((dv * texels).length());
        let lod = if rho > 0.0 { rho.log2() } else { 0.0 };
        let lod = lod.clamp(0.0, (self.levels.len() - 1) as f32);
        let below = lod.floor() as usize;
        let above = (below + 1).min(self.levels.len() - 1);
        let t = lod - below as f32;
        let (a, b) = (self.bilinear(view, below, uv), self.bilinear(view, above, uv));
        std::array::from_fn(|c| a[c] * (1.0 - t) + b[c] * t)
    }

    /// The impostor over a pixel's footprint: the parallelogram `uv ±
    /// du/2 ± dv/2` cut into `taps × taps` cells
    /// ([`footprint_taps`] of its longer side in level-0 texels), each
    /// sampled at its centre from the level of its own size, averaged. A
    /// box filter of the pixel where one trilinear sample is a box
    /// convolved with two tents (its error at 30 pixels a tree is a fifth
    /// of trilinear's). A cell whose centre is off the pictures (outside
    /// `[0, 1]²`) sees nothing: the card is wider than the pictures in
    /// wind ([`swayed_card_point`]).
    pub fn footprint(&self, view: u32, uv: Vec2, du: Vec2, dv: Vec2) -> [f32; 4] {
        let (w, h) = self.size();
        let texels = Vec2::new(w as f32, h as f32);
        let taps = footprint_taps((du * texels).length().max((dv * texels).length()));
        let n = taps as f32;
        let (du_tap, dv_tap) = (du / n, dv / n);
        let mut sum = [0.0; 4];
        for a in 0..taps {
            for b in 0..taps {
                let at = uv + du * ((a as f32 + 0.5) / n - 0.5) + dv * ((b as f32 + 0.5) / n - 0.5);
                if !(at.cmpge(Vec2::ZERO).all() && at.cmple(Vec2::ONE).all()) {
                    continue;
                }
                let sample = self.sample_grad(view, at, du_tap, dv_tap);
                for (s, v) in sum.iter_mut().zip(sample) {
                    *s += v;
                }
            }
        }
        sum.map(|s| s / (n * n))
    }
}

/// Accumulates one view at the fine resolution.
struct ViewCanvas {
    right: Vec3,
    /// Horizontal, toward the view's camera.
    toward: Vec3,
    /// Samples the needles cover.
    needles: SampleBits,
    /// Samples the wood covers.
    wood: SampleBits,
    /// Samples where a needle lies in front of the wood.
    wood_hidden: SampleBits,
    /// How near the camera the wood's front is at each sample (metres
    /// along `toward`; only meaningful where `wood` is set).
    wood_front: Vec<f32>,
    /// Per texel, the projected-area-weighted sums of its pieces' vertical
    /// and across shares, and of their weights.
    shares: Vec<[f32; 3]>,
}

impl ViewCanvas {
    /// View `k` of `impostor`, nothing drawn yet.
    fn new(impostor: &CrownImpostor, k: u32) -> Self {
        let (width, height) = (impostor.columns * SAMPLES_PER_TEXEL, impostor.rows * SAMPLES_PER_TEXEL);
        Self {
            right: impostor.view_right(k),
            toward: impostor.view_toward(k),
            needles: SampleBits::new(width, height),
            wood: SampleBits::new(width, height),
            wood_hidden: SampleBits::new(width, height),
            wood_front: vec![f32::NEG_INFINITY; width as usize * height as usize],
            shares: vec![[0.0; 3]; (impostor.columns * impostor.rows) as usize],
        }
    }
}

impl CrownImpostor {
    /// Bakes the impostor of `needles` and `wood` (tree-local metres; the
    /// tree stands along `+y`). `None` when nothing is valid or the
    /// options are out of range.
    pub fn bake(
        needles: &[Needle],
        wood: &[WoodSegment],
        wood_mesh: &TriangleMesh,
        options: ImpostorOptions,
    ) -> Option<Self> {
        if options.views == 0 || !(options.texel > 0.0 && options.texel.is_finite()) {
            return None;
        }
        let needles: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
        let wood: Vec<&WoodSegment> = wood.iter().filter(|w| w.is_valid()).collect();
        // An imported tree's bark comes as triangles.
        let triangles: Vec<[Vec3; 3]> = wood_mesh
            .indices
            .chunks_exact(3)
            .filter_map(|t| {
                let corner = |k: u32| wood_mesh.positions.get(k as usize).copied().filter(|p| p.is_finite());
                Some([corner(t[0])?, corner(t[1])?, corner(t[2])?])
            })
            .collect();
        if needles.is_empty() {
            return None;
        }
        // The box: the vertical axis through the middle of the horizontal
        // extent, wide enough for every view.
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let pieces = needles
            .iter()
            .flat_map(|n| [(n.base, n.radius), (n.tip, n.radius)])
            .chain(
                wood.iter()
                    .flat_map(|w| [(w.start, w.start_radius), (w.end, w.end_radius)]),
            )
            .chain(triangles.iter().flatten().map(|&p| (p, 0.0)));
        for (p, r) in pieces.clone() {
            lo = lo.min(p - r);
            hi = hi.max(p + r);
        }
        let axis = Vec2::new(0.5 * (lo.x + hi.x), 0.5 * (lo.z + hi.z));
        let half_width = pieces
            .map(|(p, r)| Vec2::new(p.x, p.z).distance(axis) + r)
            .fold(0.0f32, f32::max);
        let height = hi.y - lo.y;
        if !(height > 0.0 && height.is_finite() && half_width > 0.0 && half_width.is_finite()) {
            return None;
        }
        let tree_rows = (height / options.texel).ceil().clamp(MIN_ROWS as f32, MAX_ROWS as f32) as u32;
        let texel = height / tree_rows as f32;
        // Both sides are whole multiples of MIP_ALIGN texels (the box grows
        // up and sideways with empty texels), so the first mip levels
        // halve exactly: a level of odd size drops its last row or column
        // and its texels no longer sit where the level below has them.
        let rows = tree_rows.next_multiple_of(MIP_ALIGN);
        let columns = ((2.0 * half_width / texel).ceil() as u32)
            .clamp(1, 4 * tree_rows)
            .next_multiple_of(MIP_ALIGN);
        let mut impostor = Self {
            views: options.views,
            columns,
            rows,
            axis,
            half_width: 0.5 * columns as f32 * texel,
            bottom: lo.y,
            texel,
            texels: Vec::new(),
            wood_visibility: WoodVisibility::default(),
            crown_density: CrownDensity::default(),
            seen_needles: None,
            view_light_scale: None,
        };
        // Views are independent: each rasterizes every piece (in parallel,
        // on the caller's rayon pool), wood first, so that each needle
        // sample can tell whether it lies in front of the wood there.
        let views: Vec<(Vec<[u8; 4]>, Box<WoodCounts>)> = (0..options.views)
            .into_par_iter()
            .map(|k| {
                let mut canvas = ViewCanvas::new(&impostor, k);
                for segment in &wood {
                    impostor.stamp_wood(&mut canvas, segment);
                }
                for triangle in &triangles {
                    impostor.stamp_wood_triangle(&mut canvas, triangle);
                }
                for needle in &needles {
                    impostor.splat_needle(&mut canvas, needle);
                }
                (impostor.resolve(&canvas), impostor.count_wood(&canvas))
            })
            .collect();
        let mut counts: Box<WoodCounts> = Box::new([[[0.0; 2]; WOOD_COUNT_BINS]; CROWN_PROFILE_STEPS]);
        for (_, view) in &views {
            for (sum, add) in counts.iter_mut().flatten().zip(view.iter().flatten()) {
                sum[0] += add[0];
                sum[1] += add[1];
            }
        }
        impostor.texels = views.into_iter().flat_map(|(texels, _)| texels).collect();
        impostor.wood_visibility = WoodVisibility::from_counts(&counts, &impostor.crown_radii(), impostor.half_width);
        impostor.crown_density = CrownDensity::measure(needles.iter().copied(), &impostor);
        Some(impostor)
    }

    /// The crown's radius about the axis at [`CROWN_PROFILE_STEPS`]
    /// heights, bottom to top, each over an even share of the rows: per
    /// view, the distance from the axis within which 95 % of the share's
    /// coverage lies (a stray branch tip does not widen it), averaged over
    /// the views; at least half a texel. A conical crown's radius shrinks
    /// to its tip where the pictures' half width is its widest.
    pub fn crown_radii(&self) -> [f32; CROWN_PROFILE_STEPS] {
        let mut radii = [0.5 * self.texel; CROWN_PROFILE_STEPS];
        if self.rows == 0 || self.columns == 0 || self.views == 0 {
            return radii;
        }
        for (step, radius) in radii.iter_mut().enumerate() {
            // Rows run from the top: step 0 is the bottom share; every
            // share holds at least one row (`rows` ≥ 1).
            let first = self.rows - ((step as u32 + 1) * self.rows).div_ceil(CROWN_PROFILE_STEPS as u32);
            let last = self.rows - (step as u32 * self.rows) / CROWN_PROFILE_STEPS as u32;
            let mut sum = 0.0;
            for view in 0..self.views {
                // Coverage by distance from the axis, one bin a column.
                let mut by_distance: Vec<(f32, f32)> = Vec::new();
                for row in first..last {
                    for column in 0..self.columns {
                        let c = self.texel_at(view, column, row).map_or(0.0, |t| t.coverage);
                        if c > 0.0 {
                            let along = (column as f32 + 0.5) * self.texel - self.half_width;
                            by_distance.push((along.abs() + 0.5 * self.texel, c));
                        }
                    }
                }
                by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
                let total: f32 = by_distance.iter().map(|d| d.1).sum();
                let mut seen = 0.0;
                let mut reach = 0.0;
                for (distance, c) in by_distance {
                    reach = distance;
                    seen += c;
                    if seen >= 0.95 * total {
                        break;
                    }
                }
                sum += reach;
            }
            *radius = (sum / self.views as f32).max(0.5 * self.texel);
        }
        radii
    }

    /// The crown's radius at tree-local `height`, from a
    /// [`CrownImpostor::crown_radii`] profile `radii` of the pictures from
    /// `bottom` to `top`: linear between the steps' middles, the end
    /// steps' outside them. CPU reference of the impostor fragment's
    /// `crown_radius_at`.
    pub fn crown_radius_at(radii: &[f32; CROWN_PROFILE_STEPS], bottom: f32, top: f32, height: f32) -> f32 {
        let (k, t) = Self::profile_step(bottom, top, height);
        radii[k] * (1.0 - t) + radii[k + 1] * t
    }

    /// Where `height` falls in a crown profile of [`CROWN_PROFILE_STEPS`]
    /// steps from `bottom` to `top`: the step below it and how far toward
    /// the next (in `[0, 1]`), linear between the steps' middles, the end
    /// steps' outside them (step 0 for a NaN height). CPU reference of
    /// the fragment's `crown_profile_step`.
    pub fn profile_step(bottom: f32, top: f32, height: f32) -> (usize, f32) {
        let steps = CROWN_PROFILE_STEPS as f32;
        let f = ((height - bottom) / (top - bottom) * steps - 0.5).clamp(0.0, steps - 1.0);
        let f = if f.is_nan() { 0.0 } else { f };
        let k = (f as usize).min(CROWN_PROFILE_STEPS - 2);
        (k, f - k as f32)
    }

    /// Tree-local height of the pictures' top edge.
    pub fn top(&self) -> f32 {
        self.bottom + self.rows as f32 * self.texel
    }

    /// Azimuth of view `k`, radians: the camera stands on
    /// `(sin φ, 0, cos φ)` from the axis.
    pub fn view_azimuth(&self, view: u32) -> f32 {
        std::f32::consts::TAU * view as f32 / self.views.max(1) as f32
    }

    /// Toward view `k`'s camera from the axis (tree-local, horizontal,
    /// unit): `(sin φ, 0, cos φ)`.
    pub fn view_toward(&self, view: u32) -> Vec3 {
        let phi = self.view_azimuth(view);
        Vec3::new(phi.sin(), 0.0, phi.cos())
    }

    /// The picture's right of view `k` (tree-local, horizontal, unit).
    pub fn view_right(&self, view: u32) -> Vec3 {
        let phi = self.view_azimuth(view);
        Vec3::new(phi.cos(), 0.0, -phi.sin())
    }

    /// Texel `(column, row)` of view `k`, decoded (`None` outside).
    pub fn texel_at(&self, view: u32, column: u32, row: u32) -> Option<ImpostorTexel> {
        if view >= self.views || column >= self.columns || row >= self.rows {
            return None;
        }
        let [c, w, v, a] = self.texels[((view * self.rows + row) * self.columns + column) as usize];
        let share = |s: u8| if c > 0 { f32::from(s) / f32::from(c) } else { 0.0 };
        Some(ImpostorTexel {
            coverage: f32::from(c) / 255.0,
            wood: f32::from(w) / 255.0,
            shares: TexelShares {
                vertical: share(v),
                across: share(a),
            }
            .clamped(),
        })
    }

    /// The texel of view `k` a tree-local point projects to.
    pub fn project(&self, view: u32, point: Vec3) -> (f32, f32) {
        let along = (point - self.axis_point()).dot(self.view_right(view));
        let column = (along + self.half_width) / self.texel;
        let row = (self.top() - point.y) / self.texel;
        (column, row)
    }

    /// The piece nearest the camera at each sample of view `k`'s picture,
    /// orthographic, on a grid of `per_texel = [columns, rows]` samples a
    /// texel, each at its cell's centre: a sample takes the nearest needle
    /// of `needles` whose projected capsule (radius `r` about its axis)
    /// holds it, unless a segment of `wood` (a tapered capsule whose front
    /// is its axis' nearness plus its radius) lies nearer there. What the
    /// view shows, needle by needle: [`super::color::NeedleMix::seen`]
    /// counts their ages, [`CrownImpostor::view_lambert`] their light.
    pub fn nearest_pieces(
        &self,
        view: u32,
        wood: &[WoodSegment],
        needles: &[&Needle],
        per_texel: [u32; 2],
    ) -> NearestPieces {
        let (right, toward, centre) = (self.view_right(view), self.view_toward(view), self.axis_point());
        let per_texel = per_texel.map(|n| n.max(1));
        let (step_x, step_y) = (self.texel / per_texel[0] as f32, self.texel / per_texel[1] as f32);
        let (width, height) = (
            (self.columns * per_texel[0]) as usize,
            (self.rows * per_texel[1]) as usize,
        );
        let top = self.top();
        let mut nearest = vec![f32::NEG_INFINITY; width * height];
        let mut owner = vec![NearestPieces::NONE; width * height];
        // A point in the picture (sample units, rows down from the top) and
        // its nearness to the camera.
        let project = |p: Vec3| {
            let q = p - centre;
            (
                Vec2::new((q.dot(right) + self.half_width) / step_x, (top - p.y) / step_y),
                q.dot(toward),
            )
        };
        // Stamps a tapered capsule: a sample within `radius` (metres, linear
        // along it) of the projected axis takes `piece` where it lies nearer
        // than what it holds.
        let mut stamp = |a: Vec3, b: Vec3, radii: [f32; 2], front: [f32; 2], piece: u32| {
            let ((pa, near_a), (pb, near_b)) = (project(a), project(b));
            let reach = radii[0].max(radii[1]);
            let (lo, hi) = (
                pa.min(pb) - Vec2::new(reach / step_x, reach / step_y),
                pa.max(pb) + Vec2::new(reach / step_x, reach / step_y),
            );
            if !(lo.is_finite() && hi.is_finite()) {
                return;
            }
            // Samples whose centres (`k + 0.5`) lie in the box.
            let first = |v: f32| (v - 0.5).ceil().max(0.0) as usize;
            let last = |v: f32, count: usize| ((v - 0.5).floor().max(-1.0) as isize + 1).min(count as isize) as usize;
            // In metres, so that the capsule stays round with unequal steps.
            let (ma, mb) = (pa * Vec2::new(step_x, step_y), pb * Vec2::new(step_x, step_y));
            let axis = mb - ma;
            let inverse_length2 = if axis.length_squared() > 0.0 {
                axis.length_squared().recip()
            } else {
                0.0
            };
            for y in first(lo.y)..last(hi.y, height) {
                // The part of the axis within `reach` of the row, and the
                // columns within `reach` of that part: a long slanted
                // branch tests a strip, not its whole box.
                let row = (y as f32 + 0.5) * step_y;
                let (t0, t1) = if axis.y.abs() > 1e-9 {
                    let (u, v) = ((row - reach - ma.y) / axis.y, (row + reach - ma.y) / axis.y);
                    (u.min(v).max(0.0), u.max(v).min(1.0))
                } else {
                    (0.0, 1.0)
                };
                if t0 > t1 {
                    continue;
                }
                let (xa, xb) = (ma.x + axis.x * t0, ma.x + axis.x * t1);
                let columns = first((xa.min(xb) - reach) / step_x)..last((xa.max(xb) + reach) / step_x, width);
                for x in columns {
                    let point = Vec2::new((x as f32 + 0.5) * step_x, row);
                    let t = ((point - ma).dot(axis) * inverse_length2).clamp(0.0, 1.0);
                    let radius = radii[0] + (radii[1] - radii[0]) * t;
                    if point.distance_squared(ma + axis * t) > radius * radius {
                        continue;
                    }
                    let near = near_a + (near_b - near_a) * t + front[0] + (front[1] - front[0]) * t;
                    let index = y * width + x;
                    if near > nearest[index] {
                        nearest[index] = near;
                        owner[index] = piece;
                    }
                }
            }
        };
        for segment in wood.iter().filter(|w| w.is_valid()) {
            let WoodSegment {
                start,
                end,
                start_radius,
                end_radius,
            } = *segment;
            // Its front: the axis' nearness plus its radius.
            stamp(
                start,
                end,
                [start_radius, end_radius],
                [start_radius, end_radius],
                NearestPieces::WOOD,
            );
        }
        for (k, needle) in needles.iter().enumerate() {
            stamp(needle.base, needle.tip, [needle.radius; 2], [0.0; 2], k as u32);
        }
        NearestPieces {
            width: width as u32,
            step: Vec2::new(step_x, step_y),
            owner,
        }
    }

    /// What view `k` shows of `needles`, sample by sample, on a grid of
    /// [`VIEW_LAMBERT_SAMPLES`]² a texel ([`CrownImpostor::nearest_pieces`]):
    /// each sample's normal (world frame) on the round needle nearest it,
    /// `√(1 − s²)·t + s·b` with `s` its offset across the needle's
    /// projected width ([`super::shading::visible_frame`]), or past its end
    /// its flat cap's, a disk across its axis seen at its slant, turned
    /// toward the camera (a sample the raster's round end reaches and the
    /// cap does not is left out); and per texel the shares of the needles
    /// its samples show, summed, with their count.
    pub fn seen_samples(&self, view: u32, wood: &[WoodSegment], needles: &[&Needle]) -> SeenSamples {
        let (right, toward) = (self.view_right(view), self.view_toward(view));
        let per_texel = VIEW_LAMBERT_SAMPLES as usize;
        let nearest = self.nearest_pieces(view, wood, needles, [VIEW_LAMBERT_SAMPLES; 2]);
        let top = self.top();
        let mut normals = Vec::new();
        let mut sample_texels = Vec::new();
        let mut shown = vec![([0.0f64; 2], 0u32); (self.columns * self.rows) as usize];
        for (index, piece) in nearest.needle_samples_at() {
            let needle = needles[piece];
            let (column, row) = (index % nearest.width as usize, index / nearest.width as usize);
            let point = Vec2::new(
                (column as f32 + 0.5) * nearest.step.x - self.half_width,
                top - (row as f32 + 0.5) * nearest.step.y,
            );
            let Some(normal) = self.seen_normal(view, needle, point) else {
                continue;
            };
            let axis = needle.tip - needle.base;
            normals.push(normal);
            sample_texels.push(((row / per_texel) * self.columns as usize + column / per_texel) as u32);
            let shares = texel_shares(Vec3::new(axis.dot(right), axis.y, axis.dot(toward)));
            let texel = &mut shown[(row / per_texel) * self.columns as usize + column / per_texel];
            texel.0[0] += f64::from(shares.vertical);
            texel.0[1] += f64::from(shares.across);
            texel.1 += 1;
        }
        SeenSamples {
            normals,
            texels: sample_texels,
            shown,
        }
    }

    /// The normal (world frame) view `k` sees on round `needle` at
    /// `point` of its picture (metres right of the axis, height):
    /// `√(1 − s²)·t + s·b` with `s` the point's offset across the needle's
    /// projected width ([`super::shading::visible_frame`]), or past its end
    /// its flat cap's, a disk across its axis seen at its slant, turned
    /// toward the camera. `None` past an end where the raster's round end
    /// reaches and the cap does not. What [`CrownImpostor::seen_samples`]
    /// lights each sample at.
    pub fn seen_normal(&self, view: u32, needle: &Needle, point: Vec2) -> Option<Vec3> {
        let (right, toward, centre) = (self.view_right(view), self.view_toward(view), self.axis_point());
        let in_picture = |p: Vec3| Vec2::new((p - centre).dot(right), p.y);
        let (a, b) = (in_picture(needle.base), in_picture(needle.tip));
        let along = b - a;
        let t = if along.length_squared() > 0.0 {
            (point - a).dot(along) / along.length_squared()
        } else {
            0.5
        };
        let axis = needle.tip - needle.base;
        let (facing, side) = visible_frame(axis, toward);
        let side_in_picture = Vec2::new(side.dot(right), side.y);
        if (0.0..=1.0).contains(&t) {
            let across = ((point - (a + along * t)).dot(side_in_picture) / needle.radius).clamp(-1.0, 1.0);
            return Some((1.0 - across * across).max(0.0).sqrt() * facing + across * side);
        }
        // Past an end: the flat cap, an ellipse `r · slant` long along the
        // axis (the round end the raster stamped reaches `r`), lit along
        // the axis, toward the camera.
        let unit = axis.normalize_or_zero();
        let slant = unit.dot(toward).abs();
        let end = if t < 0.0 { a } else { b };
        let offset = point - end;
        let past = offset.dot(along.normalize_or_zero()) / (needle.radius * slant).max(1e-9);
        let beside = offset.dot(side_in_picture) / needle.radius;
        if past * past + beside * beside > 1.0 {
            return None;
        }
        Some(if unit.dot(toward) < 0.0 { -unit } else { unit })
    }

    /// How the needles of view `k` are lit by a light from `to_light`,
    /// given in the view's frame (`x` its right, `y` up, `z` toward the
    /// camera), as the Lambert factor `max(n·L, 0)` averaged four ways
    /// ([`ViewLambert`]): over every needle by its projected area; over
    /// what the view shows (each sample of a grid of
    /// [`VIEW_LAMBERT_SAMPLES`]² a texel lit at the normal of the round
    /// needle nearest it there, [`CrownImpostor::nearest_pieces`], or past
    /// its end at its flat cap's, as the reference's capped prisms; a
    /// sample the round end reaches and the cap seen at its slant does not
    /// is left out); as the impostor's texels light it (their shares,
    /// [`TexelShares::lambert`], weighted by the coverage the needles give
    /// them); and as texels would whose shares were fitted to the needles
    /// their samples show. `None` where the view shows no needle.
    pub fn view_lambert(
        &self,
        view: u32,
        wood: &[WoodSegment],
        needles: &[Needle],
        to_light: Vec3,
    ) -> Option<ViewLambert> {
        let (right, toward) = (self.view_right(view), self.view_toward(view));
        let to_light = (to_light.x * right + to_light.y * Vec3::Y + to_light.z * toward).try_normalize()?;
        let needles: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
        // Every needle by its projected area.
        let (mut all, mut area) = (0.0f64, 0.0f64);
        for needle in &needles {
            let axis = needle.tip - needle.base;
            let projected = 2.0 * needle.radius * Vec2::new(axis.dot(right), axis.y).length();
            all += f64::from(projected * cylinder_lambert(axis, toward, to_light));
            area += f64::from(projected);
        }
        let SeenSamples { normals, shown, .. } = self.seen_samples(view, wood, &needles);
        let seen: f64 = normals.iter().map(|n| f64::from(n.dot(to_light).max(0.0))).sum();
        let samples = normals.len() as u64;
        // The impostor's texels, by the coverage their needles give them.
        let (mut texels, mut covered) = (0.0f64, 0.0f64);
        for row in 0..self.rows {
            for column in 0..self.columns {
                let Some(texel) = self.texel_at(view, column, row) else {
                    continue;
                };
                let weight = f64::from((texel.coverage - texel.wood).max(0.0));
                texels += weight * f64::from(texel.shares.lambert(Vec3::Y, right, toward, to_light));
                covered += weight;
            }
        }
        let shown_shares: f64 = shown
            .iter()
            .filter(|(_, count)| *count > 0)
            .map(|&([vertical, across], count)| {
                let shares = TexelShares {
                    vertical: (vertical / f64::from(count)) as f32,
                    across: (across / f64::from(count)) as f32,
                }
                .clamped();
                f64::from(count) * f64::from(shares.lambert(Vec3::Y, right, toward, to_light))
            })
            .sum();
        (samples > 0 && area > 0.0 && covered > 0.0).then(|| ViewLambert {
            all_needles: (all / area) as f32,
            seen_needles: (seen / samples as f64) as f32,
            impostor: (texels / covered) as f32,
            shares_of_seen: (shown_shares / samples as f64) as f32,
        })
    }

    /// How much darker or brighter the needles this impostor's views show
    /// are lit than its texels light them, by the light's direction in the
    /// view's frame: at each of [`ViewLightScale`]'s directions, the
    /// Lambert factor over what the views show (each sample lit at the
    /// normal of the needle nearest the camera there, as
    /// [`CrownImpostor::view_lambert`] lights it) over the texels' (their
    /// shares weighted by the coverage their needles give them), each the
    /// mean of the views that show a needle, the two mirror directions
    /// (light from the view's left and right) together. The quotient is
    /// taken as `(seen + DIM) / (impostor + DIM)` with `DIM =`
    /// [`VIEW_LIGHT_DIM_LAMBERT`], so that a light neither lights much
    /// (from behind) scales by about 1, and clamped to
    /// [`VIEW_LIGHT_SCALE_RANGE`]. All 1 where no view shows a needle.
    pub fn view_light_scale(&self, wood: &[WoodSegment], needles: &[Needle]) -> ViewLightScale {
        let needles: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
        let directions = ViewLightScale::directions();
        // Per view: the mean Lambert of what it shows and of its texels at
        // each direction, or `None` where it shows no needle.
        let per_view: Vec<Option<Vec<[f64; 2]>>> = (0..self.views)
            .into_par_iter()
            .map(|view| {
                let (right, toward) = (self.view_right(view), self.view_toward(view));
                // The texels' shares summed by weight: a texel's Lambert is
                // linear in them, so three sums light every texel at once.
                let (mut vertical, mut across, mut sphere, mut covered) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                for row in 0..self.rows {
                    for column in 0..self.columns {
                        let Some(texel) = self.texel_at(view, column, row) else {
                            continue;
                        };
                        let weight = f64::from((texel.coverage - texel.wood).max(0.0));
                        vertical += weight * f64::from(texel.shares.vertical);
                        across += weight * f64::from(texel.shares.across);
                        sphere += weight * f64::from(texel.shares.sphere());
                        covered += weight;
                    }
                }
                let normals = self.seen_samples(view, wood, &needles).normals;
                if normals.is_empty() || covered <= 0.0 {
                    return None;
                }
                // The normals in the view's frame, as the directions are.
                let normals: Vec<Vec3> = normals
                    .iter()
                    .map(|n| Vec3::new(n.dot(right), n.y, n.dot(toward)))
                    .collect();
                let lambert = |to_light: Vec3| -> [f64; 2] {
                    let seen: f64 = normals.iter().map(|n| f64::from(n.dot(to_light).max(0.0))).sum();
                    let (up, across_view, to_viewer) = (Vec3::Y, Vec3::X, Vec3::Z);
                    let texels = vertical * f64::from(cylinder_lambert(up, to_viewer, to_light))
                        + across * f64::from(cylinder_lambert(across_view, to_viewer, to_light))
                        + sphere * f64::from(super::shading::sphere_lambert(to_viewer, to_light));
                    [seen / normals.len() as f64, texels / covered]
                };
                Some(
                    directions
                        .iter()
                        .map(|&d| {
                            let ([s0, t0], [s1, t1]) = (lambert(d), lambert(d * Vec3::new(-1.0, 1.0, 1.0)));
                            [0.5 * (s0 + s1), 0.5 * (t0 + t1)]
                        })
                        .collect(),
                )
            })
            .collect();
        let shown: Vec<&Vec<[f64; 2]>> = per_view.iter().flatten().collect();
        let mut scale = ViewLightScale::default();
        if shown.is_empty() {
            return scale;
        }
        let dim = f64::from(VIEW_LIGHT_DIM_LAMBERT);
        for (k, value) in scale.scales.as_flattened_mut().iter_mut().enumerate() {
            let [seen, texels] = shown
                .iter()
                .fold([0.0f64; 2], |[s, t], view| [s + view[k][0], t + view[k][1]])
                .map(|sum| sum / shown.len() as f64);
            let [lo, hi] = VIEW_LIGHT_SCALE_RANGE;
            *value = (((seen + dim) / (texels + dim)) as f32).clamp(lo, hi);
        }
        scale
    }

    /// Coverage of view `k` as a picture (for measures and tests).
    pub fn coverage_grid(&self, view: u32) -> super::look::CoverageGrid {
        let mut grid = super::look::CoverageGrid::new(self.columns, self.rows);
        for row in 0..self.rows {
            for column in 0..self.columns {
                grid.coverage[(row * self.columns + column) as usize] =
                    self.texel_at(view, column, row).map_or(0.0, |t| t.coverage);
            }
        }
        grid
    }

    /// The mip chain of view-major texels the plugin uploads: level 0 is
    /// [`CrownImpostor::texels`], each next level halves both sides
    /// (rounding down, at least 1), and each of its texels is the mean of
    /// level 0 over the texel's footprint (the part of the picture its
    /// normalized coordinates span, as the GPU samples it; level-0 texels
    /// it covers in part weighed by the part), rounded once. So every
    /// level keeps level 0's mean to within half a step, however many
    /// levels lie between (rounding each level from the one below let a
    /// sparse crown's faint texels drift by up to 5 % at the fourth
    /// level), and a level of odd size below it drops no row or column.
    /// Returns each level's `(columns, rows, texels)`.
    pub fn mip_chain(&self) -> Vec<(u32, u32, Vec<[u8; 4]>)> {
        let (w0, h0) = (self.columns, self.rows);
        let mut levels = vec![(w0, h0, self.texels.clone())];
        let (mut w, mut h) = (w0, h0);
        while w > 1 || h > 1 {
            (w, h) = ((w / 2).max(1), (h / 2).max(1));
            // Each texel's footprint along one axis: the level-0 texels
            // it overlaps and by how much (in level-0 texels).
            let footprints = |size: u32, size0: u32| -> Vec<Vec<(u32, f64)>> {
                (0..size)
                    .map(|k| {
                        let (lo, hi) = (
                            f64::from(k) * f64::from(size0) / f64::from(size),
                            f64::from(k + 1) * f64::from(size0) / f64::from(size),
                        );
                        (lo.floor() as u32..(hi.ceil() as u32).min(size0))
                            .map(|t| (t, hi.min(f64::from(t + 1)) - lo.max(f64::from(t))))
                            .filter(|&(_, weight)| weight > 0.0)
                            .collect()
                    })
                    .collect()
            };
            let (across, down) = (footprints(w, w0), footprints(h, h0));
            let mut next = Vec::with_capacity((self.views * w * h) as usize);
            for view in 0..self.views {
                for rows in &down {
                    for columns in &across {
                        let (mut sum, mut area) = ([0.0f64; 4], 0.0f64);
                        for &(y, wy) in rows {
                            for &(x, wx) in columns {
                                let t = self.texels[((view * h0 + y) * w0 + x) as usize];
                                for (s, v) in sum.iter_mut().zip(t) {
                                    *s += wx * wy * f64::from(v);
                                }
                                area += wx * wy;
                            }
                        }
                        next.push(sum.map(|s| (s / area.max(f64::MIN_POSITIVE)).round().clamp(0.0, 255.0) as u8));
                    }
                }
            }
            levels.push((w, h, next));
        }
        levels
    }

    /// Bytes of the mip chain.
    pub fn byte_size(&self) -> u64 {
        self.mip_chain().iter().map(|(_, _, t)| 4 * t.len() as u64).sum()
    }

    /// The tree-local point at the foot of the vertical axis the views
    /// turn around.
    pub fn axis_point(&self) -> Vec3 {
        Vec3::new(self.axis.x, 0.0, self.axis.y)
    }

    /// Sample coordinates of a tree-local point in a view.
    fn sample_point(&self, canvas: &ViewCanvas, p: Vec3) -> Vec2 {
        let along = (p - self.axis_point()).dot(canvas.right);
        let sample = self.texel / SAMPLES_PER_TEXEL as f32;
        Vec2::new((along + self.half_width) / sample, (self.top() - p.y) / sample)
    }

    /// Adds the shares of a piece along tree-local `along`, times `weight`,
    /// to the texels along its projected axis from `a` to `b` (sample
    /// units), in steps of at most half a texel.
    fn add_shares(&self, canvas: &mut ViewCanvas, a: Vec2, b: Vec2, along: Vec3, weight: f32) {
        let in_view = Vec3::new(along.dot(canvas.right), along.y, along.dot(canvas.toward));
        let shares = texel_shares(in_view);
        let steps = (2.0 * a.distance(b) / SAMPLES_PER_TEXEL as f32).ceil().max(1.0) as u32;
        let w = weight / steps as f32;
        for s in 0..steps {
            let p = a.lerp(b, (s as f32 + 0.5) / steps as f32) / SAMPLES_PER_TEXEL as f32;
            if p.x >= 0.0 && p.y >= 0.0 && p.x < self.columns as f32 && p.y < self.rows as f32 {
                let sums = &mut canvas.shares[(p.y as u32 * self.columns + p.x as u32) as usize];
                sums[0] += shares.vertical * w;
                sums[1] += shares.across * w;
                sums[2] += w;
            }
        }
    }

    fn splat_needle(&self, canvas: &mut ViewCanvas, needle: &Needle) {
        let (a, b) = (
            self.sample_point(canvas, needle.base),
            self.sample_point(canvas, needle.tip),
        );
        let half_width = needle.radius * SAMPLES_PER_TEXEL as f32 / self.texel;
        // Deep in a dense crown most needles fall where needles already
        // cover every sample and no wood is left unhidden: stamping them
        // would change nothing.
        let settled = canvas
            .needles
            .box_is_full_and_inside(&canvas.wood, &canvas.wood_hidden, a, b, half_width);
        if !settled {
            let centre = self.axis_point();
            let (near_a, near_b) = (
                (needle.base - centre).dot(canvas.toward),
                (needle.tip - centre).dot(canvas.toward),
            );
            let ends = PieceEnds::of_cylinder(needle.tip - needle.base, canvas.toward);
            let (wood, wood_front, wood_hidden) = (&canvas.wood, &canvas.wood_front, &mut canvas.wood_hidden);
            // The callback sees only the samples over wood (a word of
            // samples at a time): most of a crown's needles lie over none.
            canvas
                .needles
                .stamp_each_over(a, b, half_width, ends, wood, |index, t| {
                    if near_a + (near_b - near_a) * t > wood_front[index] {
                        wood_hidden.set(index);
                    }
                });
        }
        // Weighted by the projected area.
        self.add_shares(
            canvas,
            a,
            b,
            needle.tip - needle.base,
            (2.0 * half_width * a.distance(b)).max(1e-6),
        );
    }

    fn stamp_wood(&self, canvas: &mut ViewCanvas, segment: &WoodSegment) {
        let (a, b) = (
            self.sample_point(canvas, segment.start),
            self.sample_point(canvas, segment.end),
        );
        let scale = SAMPLES_PER_TEXEL as f32 / self.texel;
        let (ra, rb) = (segment.start_radius * scale, segment.end_radius * scale);
        let centre = self.axis_point();
        // The front of the segment: its axis' nearness plus its radius.
        let (near_a, near_b) = (
            (segment.start - centre).dot(canvas.toward) + segment.start_radius,
            (segment.end - centre).dot(canvas.toward) + segment.end_radius,
        );
        let front = &mut canvas.wood_front;
        canvas.wood.stamp_each(a, b, ra, rb, PieceEnds::Round, |index, t| {
            let near = near_a + (near_b - near_a) * t;
            front[index] = front[index].max(near);
        });
        self.add_shares(
            canvas,
            a,
            b,
            segment.end - segment.start,
            ((ra + rb) * a.distance(b)).max(1e-6),
        );
    }

    /// Stamps one bark triangle of an imported wood mesh: its samples are
    /// wood, with its front interpolated across it; it is lit as a
    /// cylinder along its longest side, as a branch's faces run along the
    /// branch.
    fn stamp_wood_triangle(&self, canvas: &mut ViewCanvas, corners: &[Vec3; 3]) {
        let projected = corners.map(|p| self.sample_point(canvas, p));
        let centre = self.axis_point();
        let near = corners.map(|p| (p - centre).dot(canvas.toward));
        let front = &mut canvas.wood_front;
        canvas.wood.stamp_triangle_each(projected, |index, w| {
            let nearness = w[0] * near[0] + w[1] * near[1] + w[2] * near[2];
            front[index] = front[index].max(nearness);
        });
        let (i, j) = [(0, 1), (1, 2), (2, 0)]
            .into_iter()
            .max_by(|&(a, b), &(c, d)| {
                corners[a]
                    .distance_squared(corners[b])
                    .total_cmp(&corners[c].distance_squared(corners[d]))
            })
            .unwrap_or((0, 1));
        let [p0, p1, p2] = projected;
        let area = 0.5 * (p1 - p0).perp_dot(p2 - p0).abs();
        self.add_shares(
            canvas,
            projected[i],
            projected[j],
            corners[j] - corners[i],
            area.max(1e-6),
        );
    }

    /// The view's sums of the wood samples' fit ([`WoodVisibility`]) by
    /// height and nearness (the front-most wood's, [`WOOD_COUNT_BINS`]
    /// across the pictures' width).
    fn count_wood(&self, canvas: &ViewCanvas) -> Box<WoodCounts> {
        let mut counts: Box<WoodCounts> = Box::new([[[0.0; 2]; WOOD_COUNT_BINS]; CROWN_PROFILE_STEPS]);
        let n = SAMPLES_PER_TEXEL;
        let (width, height) = (self.columns * n, self.rows * n);
        // What the needles let through, per texel.
        let mut through = vec![0.0f64; (self.columns * self.rows) as usize];
        for row in 0..self.rows {
            for column in 0..self.columns {
                let covered: u32 = (row * n..(row + 1) * n)
                    .map(|j| {
                        let first = j as usize * width as usize + (column * n) as usize;
                        canvas.needles.run_bits(first, n).count_ones()
                    })
                    .sum();
                through[(row * self.columns + column) as usize] = 1.0 - f64::from(covered) / f64::from(n * n);
            }
        }
        let (steps, bins) = (CROWN_PROFILE_STEPS as f32, WOOD_COUNT_BINS as f32);
        // The wood's samples in row-major order, a word at a time.
        canvas.wood.for_each_set(|index| {
            let (i, j) = ((index % width as usize) as u32, (index / width as usize) as u32);
            // Rows run from the top; a sample row's share of the height.
            let up = 1.0 - (j as f32 + 0.5) / height as f32;
            let step = ((up * steps) as usize).min(CROWN_PROFILE_STEPS - 1);
            let nearness = canvas.wood_front[index];
            let bin = ((nearness / self.half_width + 1.0) * 0.5 * bins)
                .floor()
                .clamp(0.0, bins - 1.0) as usize;
            let t = through[((j / n) * self.columns + i / n) as usize];
            let seen = if canvas.wood_hidden.is_set(index) { 0.0 } else { 1.0 };
            let fit = &mut counts[step][bin];
            fit[0] += (seen - t) * (1.0 - t);
            fit[1] += (1.0 - t) * (1.0 - t);
        });
        counts
    }

    /// The view's texels from its samples: coverage is the samples the
    /// needles or the wood cover; wood is seen where no needle lies in
    /// front of it.
    fn resolve(&self, canvas: &ViewCanvas) -> Vec<[u8; 4]> {
        let n = SAMPLES_PER_TEXEL;
        let per_texel = (n * n) as f32;
        let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        let mut texels = Vec::with_capacity((self.columns * self.rows) as usize);
        let width = (self.columns * n) as usize;
        for row in 0..self.rows {
            for column in 0..self.columns {
                let (mut covered, mut wood) = (0u32, 0u32);
                // A texel's row of samples at a time.
                for j in row * n..(row + 1) * n {
                    let first = j as usize * width + (column * n) as usize;
                    let (needles, bark) = (canvas.needles.run_bits(first, n), canvas.wood.run_bits(first, n));
                    covered += (needles | bark).count_ones();
                    wood += (bark & !canvas.wood_hidden.run_bits(first, n)).count_ones();
                }
                // A texel no piece's axis crossed (the edge of a wide
                // trunk) is lit as a vertical cylinder.
                let [vertical, across, weight] = canvas.shares[(row * self.columns + column) as usize];
                let shares = if weight > 0.0 {
                    TexelShares {
                        vertical: vertical / weight,
                        across: across / weight,
                    }
                    .clamped()
                } else {
                    TexelShares {
                        vertical: 1.0,
                        across: 0.0,
                    }
                };
                let coverage = covered as f32 / per_texel;
                texels.push([
                    byte(coverage),
                    byte(wood as f32 / per_texel),
                    byte(shares.vertical * coverage),
                    byte(shares.across * coverage),
                ]);
            }
        }
        texels
    }
}

/// Samples along each side of a texel at which
/// [`CrownImpostor::view_lambert`] takes what a view shows (2.5 cm apart
/// at the default 10 cm texel).
pub const VIEW_LAMBERT_SAMPLES: u32 = 4;

/// What one view of a crown shows at each sample
/// ([`CrownImpostor::nearest_pieces`]): row by row from the top, the index
/// of the nearest needle in the slice it was given, or
/// [`NearestPieces::WOOD`], or [`NearestPieces::NONE`].
#[derive(Clone, Debug, PartialEq)]
pub struct NearestPieces {
    /// Samples across.
    pub width: u32,
    /// A sample's side across and down, metres.
    pub step: Vec2,
    /// The nearest piece at each sample.
    pub owner: Vec<u32>,
}

impl NearestPieces {
    /// Nothing at the sample.
    pub const NONE: u32 = u32::MAX;
    /// Wood in front at the sample.
    pub const WOOD: u32 = u32::MAX - 1;

    /// The needle shown at each sample that shows one (its index).
    pub fn needle_samples(&self) -> impl Iterator<Item = usize> + '_ {
        self.needle_samples_at().map(|(_, piece)| piece)
    }

    /// `(sample index, needle index)` of each sample that shows a needle.
    pub fn needle_samples_at(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.owner
            .iter()
            .enumerate()
            .filter(|&(_, &piece)| piece < Self::WOOD)
            .map(|(index, &piece)| (index, piece as usize))
    }
}

/// The Lambert factor of one view of a crown, averaged three ways
/// ([`CrownImpostor::view_lambert`]). A pixel of the crown shows the
/// needles nearest the camera, not all of them: a crown's shoots point
/// outward, so those in front point toward the camera and show it the
/// grazing side of their surface, away from a light in front.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewLambert {
    /// Over every needle, by its projected area (what the texels' shares
    /// are fitted to).
    pub all_needles: f32,
    /// Over what the view shows: each sample lit at the normal of the
    /// needle nearest it.
    pub seen_needles: f32,
    /// As the impostor's texels light the view.
    pub impostor: f32,
    /// As texels would whose shares were fitted to the needles they show
    /// (each texel's samples' needles, clamped as the bake clamps).
    pub shares_of_seen: f32,
}

/// What a view of the crown shows, sample by sample
/// ([`CrownImpostor::seen_samples`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SeenSamples {
    /// Each sample's normal on the needle it shows (world frame).
    pub normals: Vec<Vec3>,
    /// Each sample's texel in the view (`row × columns + column`).
    pub texels: Vec<u32>,
    /// Per texel: the shares ([`texel_shares`]) of the needles its
    /// samples show, summed (vertical, across), and their count.
    pub shown: Vec<([f64; 2], u32)>,
}

/// Steps of a [`ViewLightScale`] in the angle between the light and the
/// view's direction toward the camera, from 0 (a light behind the camera)
/// to π (a light behind the tree), 15° apart.
pub const VIEW_LIGHT_ANGLES: usize = 13;

/// Steps of a [`ViewLightScale`] in the light's roll about the view's
/// direction, from 0 (above) through π/2 (beside, left or right alike) to
/// π (below), 30° apart.
pub const VIEW_LIGHT_ROLLS: usize = 7;

/// The Lambert factor added to both what the views show and the texels
/// before a [`ViewLightScale`] divides them: a light that lights neither
/// (from behind the tree, where both are ~0.001) scales by about 1.
pub const VIEW_LIGHT_DIM_LAMBERT: f32 = 0.02;

/// The least and the most a [`ViewLightScale`] scales a light by.
pub const VIEW_LIGHT_SCALE_RANGE: [f32; 2] = [0.5, 2.0];

/// How the crown impostor's direct light is scaled so that it lights its
/// texels as brightly as the needles its views show are lit
/// ([`CrownImpostor::view_light_scale`]), by the light's direction in the
/// view's frame (`x` right, `y` up, `z` toward the camera).
///
/// A texel's shares are fitted to every needle in it by projected area,
/// and light those needles within ~2 %; but a pixel of the crown shows the
/// needles nearest the camera, and a needle pointing at the camera shows
/// it its cap and a grazing slice of its side. Under the `conifer eval`
/// front sun the mature silver fir's texels light what its views show
/// 1.104 times too bright, the Scots pine's 1.074 times, the eastern white
/// pine's 0.907 times (`examples/visible_light.rs`); the three shares
/// cannot express it texel by texel (fitted to the needles each texel
/// shows, 1.098), so the bake measures it for the whole crown by direction
/// and the shader scales each light's direct term by it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewLightScale {
    /// `scales[angle][roll]`: the scale at
    /// [`ViewLightScale::direction`]`(angle, roll)`. At the first and the
    /// last angle every roll is one direction (toward the camera, away
    /// from it), and the measure gives each the same scale.
    pub scales: [[f32; VIEW_LIGHT_ROLLS]; VIEW_LIGHT_ANGLES],
}

impl Default for ViewLightScale {
    /// Every scale 1: the texels lit as their shares say (an impostor
    /// baked before the scale was measured).
    fn default() -> Self {
        Self {
            scales: [[1.0; VIEW_LIGHT_ROLLS]; VIEW_LIGHT_ANGLES],
        }
    }
}

impl ViewLightScale {
    /// Scales stored: [`VIEW_LIGHT_ANGLES`] × [`VIEW_LIGHT_ROLLS`].
    pub const LEN: usize = VIEW_LIGHT_ANGLES * VIEW_LIGHT_ROLLS;

    /// The unit direction of step `angle` and `roll`, in the view's frame:
    /// `(sin θ sin ψ, sin θ cos ψ, cos θ)`, `θ` the angle from the view's
    /// direction toward the camera and `ψ` the roll from above, toward the
    /// right.
    pub fn direction(angle: usize, roll: usize) -> Vec3 {
        let theta = std::f32::consts::PI * angle as f32 / (VIEW_LIGHT_ANGLES - 1) as f32;
        let psi = std::f32::consts::PI * roll as f32 / (VIEW_LIGHT_ROLLS - 1) as f32;
        Vec3::new(theta.sin() * psi.sin(), theta.sin() * psi.cos(), theta.cos())
    }

    /// Every step's direction, angle major (the order of
    /// [`ViewLightScale::to_vec`]).
    pub fn directions() -> Vec<Vec3> {
        (0..VIEW_LIGHT_ANGLES)
            .flat_map(|angle| (0..VIEW_LIGHT_ROLLS).map(move |roll| Self::direction(angle, roll)))
            .collect()
    }

    /// The scale for a light from `to_light` (the view's frame; any
    /// length): bilinear between the steps around its angle and its roll,
    /// a light from the left taken as its mirror from the right. 1 for a
    /// zero or non-finite direction. CPU reference of the impostor
    /// shader's `view_light_scale`.
    pub fn at(&self, to_light: Vec3) -> f32 {
        let Some(l) = to_light.try_normalize() else {
            return 1.0;
        };
        let angle = l.z.clamp(-1.0, 1.0).acos() * ((VIEW_LIGHT_ANGLES - 1) as f32 / std::f32::consts::PI);
        let roll = l.x.abs().atan2(l.y) * ((VIEW_LIGHT_ROLLS - 1) as f32 / std::f32::consts::PI);
        let (a, r) = (
            (angle as usize).min(VIEW_LIGHT_ANGLES - 2),
            (roll as usize).min(VIEW_LIGHT_ROLLS - 2),
        );
        let (fa, fr) = (angle - a as f32, roll - r as f32);
        let row = |a: usize| self.scales[a][r] + (self.scales[a][r + 1] - self.scales[a][r]) * fr;
        row(a) + (row(a + 1) - row(a)) * fa
    }

    /// The scales angle major, as a record stores them.
    pub fn to_vec(&self) -> Vec<f32> {
        self.scales.as_flattened().to_vec()
    }

    /// The scales from [`ViewLightScale::to_vec`]'s order; `None` for a
    /// wrong length or a scale outside [`VIEW_LIGHT_SCALE_RANGE`] (or not
    /// finite).
    pub fn from_slice(values: &[f32]) -> Option<Self> {
        let [lo, hi] = VIEW_LIGHT_SCALE_RANGE;
        if values.len() != Self::LEN || !values.iter().all(|v| (lo..=hi).contains(v)) {
            return None;
        }
        let mut scale = Self::default();
        for (k, &value) in values.iter().enumerate() {
            scale.scales[k / VIEW_LIGHT_ROLLS][k % VIEW_LIGHT_ROLLS] = value;
        }
        Some(scale)
    }
}

#[cfg(test)]
mod tests {

    /// A cone's pictures give its radius by height: 64 rows of a crown
    /// 3 m wide at the bottom narrowing to nothing at the top, one stray
    /// texel at the picture's edge in every row where the cone is over
    /// half a metre wide (2 % of a row's coverage at most: inside the 5 %
    /// the profile leaves out). Between the
    /// steps the radius is linear; past the ends it is the end steps'.
    #[test]
    fn the_crown_profile_follows_a_cone() {
        let (columns, rows, texel) = (64u32, 64u32, 0.1f32);
        let half_width = columns as f32 * texel / 2.0;
        let mut texels = vec![[0u8; 4]; (2 * rows * columns) as usize];
        for view in 0..2 {
            for row in 0..rows {
                // Height fraction of the row's middle, 0 at the bottom.
                let up = 1.0 - (row as f32 + 0.5) / rows as f32;
                let radius = 1.5 * (1.0 - up);
                for column in 0..columns {
                    let along = (column as f32 + 0.5) * texel - half_width;
                    let i = ((view * rows + row) * columns + column) as usize;
                    if along.abs() < radius {
                        texels[i] = [200, 0, 0, 0];
                    }
                }
                if radius > 0.5 {
                    texels[((view * rows + row) * columns) as usize] = [2, 0, 0, 0];
                }
            }
        }
        let impostor = CrownImpostor {
            views: 2,
            columns,
            rows,
            axis: Vec2::ZERO,
            half_width,
            bottom: 1.0,
            texel,
            texels,
            wood_visibility: WoodVisibility::default(),
            crown_density: CrownDensity::default(),
            seen_needles: None,
            view_light_scale: None,
        };
        let radii = impostor.crown_radii();
        for (step, radius) in radii.iter().enumerate() {
            let up = (step as f32 + 0.5) / CROWN_PROFILE_STEPS as f32;
            let cone = 1.5 * (1.0 - up);
            assert!(
                (radius - cone).abs() <= 1.5 * texel,
                "step {step}: {radius} for a cone's {cone}"
            );
        }
        assert!(radii[0] > 10.0 * radii[CROWN_PROFILE_STEPS - 1]);
        let (bottom, top) = (impostor.bottom, impostor.top());
        let step = (top - bottom) / CROWN_PROFILE_STEPS as f32;
        let at = |h: f32| CrownImpostor::crown_radius_at(&radii, bottom, top, h);
        assert_eq!(at(bottom - 5.0), radii[0]);
        assert_eq!(at(top + 5.0), radii[CROWN_PROFILE_STEPS - 1]);
        assert!((at(bottom + 3.5 * step) - radii[3]).abs() < 1e-5);
        assert!((at(bottom + 4.0 * step) - 0.5 * (radii[3] + radii[4])).abs() < 1e-5);
        assert_eq!(at(f32::NAN), radii[0]);
    }

    /// The shadow samples sit at the quantiles of the visible needles'
    /// depth: in front of each lies 1/6, 1/2, 5/6 of what the texel shows
    /// (integrated with needles even along the chord), inside the crown,
    /// nearer the near side the denser the texel; outside the circle they
    /// are on the card.
    #[test]
    fn shadow_samples_sit_where_the_texel_s_needles_are_seen() {
        let radius = 3.0f32;
        for offset in [0.0f32, 1.0, 2.5] {
            let half = (radius * radius - offset * offset).sqrt();
            let mut previous_deepest = f32::NEG_INFINITY;
            for coverage in [0.05f32, 0.5, 0.9, 0.99] {
                let depths = shadow_sample_depths(coverage, offset, radius, &[1.0; CROWN_DENSITY_RINGS]);
                for (q, depth) in [1.0f32 / 6.0, 0.5, 5.0 / 6.0].into_iter().zip(depths) {
                    assert!(depth <= half && depth >= -half, "{depth} inside ±{half}");
                    // Share of the seen needles in front of `depth`, by a
                    // sum over 10,000 slices of the chord.
                    let slices = 10_000;
                    let step = 2.0 * half / slices as f32;
                    let density = -(1.0 - coverage).ln() / (2.0 * half);
                    let seen = |s: f32| density * (-density * s).exp();
                    let total: f32 = (0..slices).map(|k| seen((k as f32 + 0.5) * step) * step).sum();
                    let front: f32 = (0..slices)
                        .map(|k| (k as f32 + 0.5) * step)
                        .filter(|&s| half - s > depth)
                        .map(|s| seen(s) * step)
                        .sum();
                    assert!(
                        (front / total - q).abs() < 2e-3,
                        "offset {offset}, coverage {coverage}: {} for {q}",
                        front / total
                    );
                }
                assert!(depths[0] > depths[1] && depths[1] > depths[2]);
                assert!(depths[2] > previous_deepest, "a denser texel is seen nearer its front");
                previous_deepest = depths[2];
            }
        }
        let even = [1.0; CROWN_DENSITY_RINGS];
        assert_eq!(shadow_sample_depths(0.5, 4.0, 3.0, &even), [0.0; 3]);
        assert_eq!(shadow_sample_depths(f32::NAN, 0.0, 3.0, &even), [0.0; 3]);
        assert_eq!(shadow_sample_depths(0.5, 0.0, f32::INFINITY, &even), [0.0; 3]);
        // Rings without needles read as even ones.
        assert_eq!(
            shadow_sample_depths(0.5, 1.0, 3.0, &[0.0; CROWN_DENSITY_RINGS]),
            shadow_sample_depths(0.5, 1.0, 3.0, &even)
        );
    }
    use super::*;
    use crate::model::look::tests::needle;

    /// A crown of branches spread from its axis (16 a whorl, a whorl
    /// every 10 cm, needles even along each) holds as much of a branch's
    /// needles in every ring, so its density falls as one over the
    /// distance: measured, each ring's over the second's within 10 % of
    /// `3 / (2k + 1)` (the ring's volume), but the last, which holds the
    /// tips past the radius as well.
    /// The shadow samples on a chord through such a crown sit where a sum
    /// over 10,000 slices of the chord, with the density read at each
    /// slice's distance from the axis, finds the texel's needles seen;
    /// on chords that pass within half the radius of the axis, deeper than
    /// the even crown puts them (the middle one, and the three's mean).
    #[test]
    fn a_crown_of_branches_is_densest_at_its_axis_and_seen_there() {
        let mut needles = Vec::new();
        for whorl in 0..60 {
            let y = 1.0 + 0.1 * whorl as f32;
            for branch in 0..16 {
                let angle = std::f32::consts::TAU * (branch as f32 + 0.37 * whorl as f32) / 16.0;
                let out = Vec3::new(angle.cos(), 0.0, angle.sin());
                for k in 0..200 {
                    let base = Vec3::new(0.0, y, 0.0) + out * (2.0 * (k as f32 + 0.5) / 200.0);
                    needles.push(needle(
                        base,
                        base + Vec3::new(0.0, 0.02, 0.0) + out.cross(Vec3::Y) * 0.01,
                        0.001,
                    ));
                }
            }
        }
        let impostor = CrownImpostor::bake(&needles, &[], &TriangleMesh::default(), ImpostorOptions::default())
            .expect("an impostor");
        let density = &impostor.crown_density;
        let middle_row = density.row_at(impostor.bottom, impostor.top(), 4.0);
        for ring in 1..CROWN_DENSITY_RINGS - 1 {
            let expected = 1.5 / (ring as f32 + 0.5);
            assert!(
                (middle_row[ring] / middle_row[1] - expected).abs() < 0.1 * expected,
                "ring {ring}: {:?}",
                middle_row
            );
        }
        // The last ring also holds the branch tips past the radius, which
        // leaves out the outermost 5 % of the pictures' coverage.
        assert!(middle_row[CROWN_DENSITY_RINGS - 1] / middle_row[1] > 1.5 / 7.5);
        let radius = 2.0f32;
        for offset in [0.0f32, 0.6, 1.4] {
            let half = (radius * radius - offset * offset).sqrt();
            for coverage in [0.3f32, 0.8, 0.99] {
                let depths = shadow_sample_depths(coverage, offset, radius, &middle_row);
                let even = shadow_sample_depths(coverage, offset, radius, &[1.0; CROWN_DENSITY_RINGS]);
                let slices = 10_000;
                let step = 2.0 * half / slices as f32;
                let at = |k: usize| half - (k as f32 + 0.5) * step;
                let dense = |d: f32| density_across(&middle_row, (offset * offset + d * d).sqrt() / radius);
                let total: f32 = (0..slices).map(|k| dense(at(k))).sum();
                let through = -(1.0 - coverage).ln();
                for (q, depth) in [1.0f32 / 6.0, 0.5, 5.0 / 6.0].into_iter().zip(depths) {
                    assert!(depth <= half && depth >= -half, "{depth} inside ±{half}");
                    let in_front: f32 = (0..slices).filter(|&k| at(k) > depth).map(|k| dense(at(k))).sum();
                    let seen = (1.0 - (-through * in_front / total).exp()) / coverage;
                    assert!(
                        (seen - q).abs() < 0.01,
                        "offset {offset}, coverage {coverage}: {seen} for {q}"
                    );
                }
                assert!(depths[0] > depths[1] && depths[1] > depths[2]);
                if offset < 1.0 {
                    assert!(
                        depths[1] < even[1] && depths.iter().sum::<f32>() < even.iter().sum::<f32>(),
                        "deeper: {depths:?} against {even:?}"
                    );
                }
            }
        }
        // The table round-trips through bytes; another length is refused.
        assert_eq!(CrownDensity::from_bytes(&density.to_bytes()).as_ref(), Some(density));
        assert_eq!(CrownDensity::from_bytes(&[0; 3]), None);
    }

    proptest::proptest! {
        /// Any band built from degrees, NaN and infinities included, keeps
        /// the whole impostor up to its start, none of it from its end and
        /// less of it the steeper the camera, with finite tangents and the
        /// end past the start; the default is 30° to 45°.
        #[test]
        fn a_steep_band_from_any_degrees_keeps_less_the_steeper_the_camera(
            start in proptest::prop_oneof![-100.0f32..200.0, proptest::strategy::Just(f32::NAN), proptest::strategy::Just(f32::INFINITY)],
            end in proptest::prop_oneof![-100.0f32..200.0, proptest::strategy::Just(f32::NAN), proptest::strategy::Just(f32::NEG_INFINITY)],
            elevations in proptest::collection::vec(0.0f32..60.0, 2..16),
        ) {
            let band = SteepFade::from_degrees(start, end);
            proptest::prop_assert!(band.start.is_finite() && band.end.is_finite() && band.start >= 0.0);
            proptest::prop_assert!(band.end > band.start, "{band:?}");
            proptest::prop_assert_eq!(band.keep(band.start), 1.0);
            proptest::prop_assert_eq!(band.keep(-0.5 * band.start), 1.0);
            if band != SteepFade::NEVER {
                proptest::prop_assert_eq!(band.keep(band.end), 0.0);
            }
            let mut elevations = elevations;
            elevations.sort_by(f32::total_cmp);
            for pair in elevations.windows(2) {
                proptest::prop_assert!(band.keep(pair[1]) <= band.keep(pair[0]));
            }
        }
    }

    #[test]
    fn the_default_steep_band_runs_from_30_to_45_degrees() {
        let band = SteepFade::from_degrees(30.0, 45.0);
        assert!((band.start - SteepFade::DEFAULT.start).abs() < 1e-6);
        assert!((band.end - SteepFade::DEFAULT.end).abs() < 1e-6);
        assert_eq!(SteepFade::from_degrees(f32::NAN, f32::NAN), band);
        // From 89.9° up the impostor stays at any elevation a camera has.
        assert_eq!(SteepFade::from_degrees(90.0, 95.0), SteepFade::NEVER);
        assert_eq!(SteepFade::NEVER.keep(1e12), 1.0);
        // A band with its end below its start ends 0.1° past the start.
        let sharp = SteepFade::from_degrees(20.0, 10.0);
        assert!((sharp.end.atan().to_degrees() - 20.1).abs() < 1e-3);
        assert_eq!(sharp.keep(20.2f32.to_radians().tan()), 0.0);
    }

    #[test]
    fn the_elevation_tangent_is_height_over_ground_distance() {
        assert_eq!(elevation_tangent(Vec3::new(0.0, 1.0, 1.0)), 1.0);
        assert!((elevation_tangent(Vec3::new(3.0, -2.5, 4.0)) - 0.5).abs() < 1e-6);
        assert_eq!(elevation_tangent(Vec3::new(5.0, 0.0, 0.0)), 0.0);
        let overhead = elevation_tangent(Vec3::Y);
        assert!(overhead.is_finite() && overhead >= 1e9);
        assert_eq!(SteepFade::DEFAULT.keep(overhead), 0.0);
    }

    #[test]
    fn a_degree_band_reads_as_start_comma_end() {
        assert_eq!(parse_degree_band("15,30"), Ok([15.0, 30.0]));
        assert_eq!(parse_degree_band(" 0 , 90 "), Ok([0.0, 90.0]));
        for bad in [
            "", "15", "15,30,45", "30,15", "20,20", "-5,30", "15,91", "NaN,30", "a,b", "15;30",
        ] {
            let error = parse_degree_band(bad).expect_err(bad);
            assert!(error.contains("START,END"), "{bad}: {error}");
        }
    }

    proptest::proptest! {
        /// Leaned by `shadow_card_lean`, the card spans across the light
        /// what the crown spans (at most its height), never leans past
        /// facing the light, and leans away from it.
        #[test]
        fn the_shadow_card_spans_what_the_crown_spans(
            elevation in -1.57f32..1.57,
            width in 0.1f32..30.0,
            height in 0.1f32..60.0,
        ) {
            let lean = shadow_card_lean(elevation, width, height);
            proptest::prop_assert!(lean.abs() <= elevation.abs() + 1e-6);
            proptest::prop_assert!(lean * elevation >= 0.0);
            let spans = height * (elevation.abs() - lean.abs()).cos();
            let crown = (height * elevation.cos() + width * elevation.abs().sin()).min(height);
            proptest::prop_assert!((spans - crown).abs() <= 1e-3 * height, "{} against {}", spans, crown);
        }
    }

    proptest::proptest! {
        /// Every mip level of any picture, its sides odd or even, keeps
        /// each view's mean of every channel to within half a step (each
        /// texel the rounded mean of level 0 over its footprint), however
        /// faint the texels; the last level is the rounded mean.
        #[test]
        fn every_mip_level_keeps_the_pictures_mean(
            columns in 1u32..40, rows in 1u32..40, seed in 0u64..u64::MAX, faint in proptest::bool::ANY,
        ) {
            let views = 2;
            let mut state = seed | 1;
            let texels: Vec<[u8; 4]> = (0..views * columns * rows)
                .map(|_| {
                    std::array::from_fn(|_| {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        // Faint: mostly 0, sometimes 1 or 2 of 255.
                        if faint { [0, 0, 0, 0, 0, 1, 1, 2][(state % 8) as usize] } else { (state % 256) as u8 }
                    })
                })
                .collect();
            let impostor = CrownImpostor {
                views,
                columns,
                rows,
                axis: Vec2::ZERO,
                half_width: 1.0,
                bottom: 0.0,
                texel: 0.1,
                texels,
                wood_visibility: WoodVisibility::default(),
                crown_density: CrownDensity::default(),
                seen_needles: None,
                view_light_scale: None,
            };
            let chain = impostor.mip_chain();
            proptest::prop_assert_eq!((chain[0].0, chain[0].1), (columns, rows));
            proptest::prop_assert_eq!(chain.last().map(|l| (l.0, l.1)), Some((1, 1)));
            let mean = |(w, h, t): &(u32, u32, Vec<[u8; 4]>), view: u32, channel: usize| {
                let n = (w * h) as usize;
                t[view as usize * n..(view as usize + 1) * n].iter().map(|x| f64::from(x[channel])).sum::<f64>() / n as f64
            };
            for view in 0..views {
                for channel in 0..4 {
                    let whole = mean(&chain[0], view, channel);
                    for level in &chain[1..] {
                        proptest::prop_assert!((mean(level, view, channel) - whole).abs() <= 0.5 + 1e-9);
                    }
                    let last = chain.last().map(|l| l.2[view as usize][channel]);
                    proptest::prop_assert_eq!(last, Some(whole.round() as u8));
                }
            }
        }
    }

    proptest::proptest! {
        /// A fragment of the swayed card reads the picture where the field
        /// came from: a crown point `p` on the card moved by its sway
        /// (across the card and up) to `q` is read back at `p` to within
        /// the field's change between `p` and `q`, its slope times the
        /// move: a slope under 0.1 per unit of the strongest gust's force
        /// (under 0.15 in a light breeze). A sway along the view moves
        /// nothing.
        #[test]
        fn a_swayed_card_reads_the_picture_where_its_needles_came_from(
            across in -3.0f32..3.0, height in 2.0f32..20.0, azimuth in 0.0f32..std::f32::consts::TAU,
            seconds in 0.0f64..1e4, strength in 0.1f32..4.0, turbulence in 0.0f32..1.0,
        ) {
            use crate::model::wind::{TreeWindPhase, Wind, WindClock, WindShape, sway_offset};
            let shape = WindShape::from_bounds(Vec3::new(-3.0, 0.0, -3.0), Vec3::new(3.0, 20.0, 3.0), Vec2::ZERO);
            let wind = Wind { direction: Vec2::new(0.6, 0.8), strength, gustiness: 0.5, turbulence };
            let clock = WindClock::at(seconds, &shape);
            let phase = TreeWindPhase::of_root(Vec2::new(3.0, -7.0), &wind);
            let sway = |p: Vec3| sway_offset(&wind, &shape, &clock, &phase, p).world(wind.unit_direction(), 1.0);
            let right = Vec3::new(azimuth.cos(), 0.0, -azimuth.sin());
            let p = right * across + Vec3::Y * height;
            let moved = sway(p) - right.cross(Vec3::Y) * sway(p).dot(right.cross(Vec3::Y));
            let q = p + moved;
            let back = swayed_card_point(q, right, Vec3::Y, sway(q));
            proptest::prop_assert!(
                (back - p).length() <= 0.1 * strength * 1.5 * moved.length() + 1e-5,
                "read back {} m off after a move of {} m", (back - p).length(), moved.length()
            );
            let along_view = right.cross(Vec3::Y) * 0.4;
            proptest::prop_assert!((swayed_card_point(p, right, Vec3::Y, along_view) - p).length() < 1e-6);
        }
    }

    #[test]
    fn a_swayed_card_point_of_known_moves() {
        let (right, up) = (Vec3::X, Vec3::Y);
        let at = Vec3::new(1.0, 5.0, 0.0);
        assert_eq!(
            swayed_card_point(at, right, up, Vec3::new(0.2, -0.1, 0.3)),
            Vec3::new(0.8, 5.1, 0.0)
        );
        assert_eq!(swayed_card_point(at, right, up, Vec3::splat(f32::NAN)), at);
    }

    #[test]
    fn shadow_card_lean_of_known_lights() {
        // On the horizon the card stands upright; overhead it spans the
        // crown's width; a 20 m crown 5 m wide under a sun 60° high leans
        // until cos(60° − t) = 0.5 + 0.25·0.866.
        assert_eq!(shadow_card_lean(0.0, 5.0, 20.0), 0.0);
        let overhead = shadow_card_lean(std::f32::consts::FRAC_PI_2, 5.0, 20.0);
        assert!((20.0 * (std::f32::consts::FRAC_PI_2 - overhead).cos() - 5.0).abs() < 1e-3);
        let sixty = 60f32.to_radians();
        let expected = sixty - (0.5f32 + 0.25 * sixty.sin()).acos();
        assert!((shadow_card_lean(sixty, 5.0, 20.0) - expected).abs() < 1e-6);
        assert!((shadow_card_lean(-sixty, 5.0, 20.0) + expected).abs() < 1e-6);
        // A crown wider than tall faces a high light.
        assert!((shadow_card_lean(sixty, 40.0, 20.0) - sixty).abs() < 1e-6);
        for bad in [f32::NAN, f32::INFINITY] {
            assert_eq!(shadow_card_lean(bad, 5.0, 20.0), 0.0);
            assert_eq!(shadow_card_lean(0.5, bad, 20.0), 0.0);
        }
        assert_eq!(shadow_card_lean(0.5, 5.0, 0.0), 0.0);
    }

    use crate::model::look::{SideView, side_coverage};

    /// A cone of random needles, 10 m tall, 3 m across at the bottom.
    fn cone(count: u32, radius: f32) -> Vec<Needle> {
        let mut state = 0x9e37_79b9u32;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32
        };
        (0..count)
            .map(|_| {
                let y = 10.0 * (1.0 - next().sqrt());
                let reach = 1.5 * (1.0 - y / 10.0) * next().sqrt();
                let phi = std::f32::consts::TAU * next();
                let base = Vec3::new(reach * phi.cos(), y, reach * phi.sin());
                let d = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize_or(Vec3::Y);
                needle(base, base + d * 0.05, radius)
            })
            .collect()
    }

    /// Each texel is lit like its needles, on the shipped mature silver
    /// fir (flat two-rowed shoots): under the three suns of `conifer eval`,
    /// the texel's shares give within 0.025 (Lambert, mean over covered
    /// texels) of its needles' mean cylinder, and at most half the error of
    /// one sign-folded mean needle axis per texel (what the first
    /// impostors stored) where that error is not negligible.
    /// Needles at random (a small LCG, fixed seed): `count` of
    /// `radius` and `length`, each from `place(u)` for three uniforms.
    fn random_needles(count: usize, radius: f32, place: impl Fn([f32; 3], [f32; 3]) -> (Vec3, Vec3)) -> Vec<Needle> {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..count)
            .map(|k| {
                let (base, tip) = place([uniform(), uniform(), uniform()], [uniform(), uniform(), uniform()]);
                Needle {
                    base,
                    tip,
                    radius,
                    normal: Vec3::X,
                    group: k as u32,
                }
            })
            .collect()
    }

    /// A unit direction from two uniforms (even over the sphere).
    fn direction(u: f32, v: f32) -> Vec3 {
        let (y, phi) = (2.0 * u - 1.0, std::f32::consts::TAU * v);
        let r = (1.0 - y * y).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), y, r * phi.sin())
    }

    /// Needles pointing every way, lit from the camera: every needle by
    /// its projected area is lit as a sphere (2/3), and the texels fitted
    /// to them within 8 % (each texel's shares are clamped to a sphere
    /// and two cylinders, which lifts a texel of needles pointing at the
    /// camera to the sphere's light: measured 0.71). A sparse cloud (a
    /// sixth of its picture covered) shows needles of every direction, lit
    /// alike; a dense ball of needles pointing outward (a crown's shoots)
    /// shows those in front, more of them pointing at the camera and
    /// grazing the light: lit 3–10 % less (measured 6 %).
    #[test]
    fn a_view_shows_the_needles_in_front_and_lights_them_as_they_point() {
        let options = ImpostorOptions {
            views: 2,
            ..ImpostorOptions::default()
        };
        let front = Vec3::Z;
        let cloud = random_needles(3000, 0.005, |p, d| {
            let base = (Vec3::from_array(p) - 0.5) * 6.0 + Vec3::Y * 3.0;
            (base, base + 0.2 * direction(d[0], d[1]))
        });
        let ball = random_needles(30_000, 0.002, |p, d| {
            let out = direction(d[0], d[1]);
            let base = Vec3::Y * 1.5 + out * (0.2 + 0.8 * p[0].cbrt());
            (base, base + 0.15 * out)
        });
        for (name, needles, seen_over_all) in [("cloud", &cloud, 0.97..1.03), ("ball", &ball, 0.90..0.97)] {
            let impostor = CrownImpostor::bake(needles, &[], &TriangleMesh::default(), options).unwrap();
            for view in 0..2 {
                let lambert = impostor.view_lambert(view, &[], needles, front).unwrap();
                println!("{name} view {view}: {lambert:?}");
                assert!((lambert.all_needles - 2.0 / 3.0).abs() < 0.02, "{name}: {lambert:?}");
                assert!(
                    (lambert.impostor / lambert.all_needles - 1.0).abs() < 0.08,
                    "{name}: {lambert:?}"
                );
                assert!(
                    seen_over_all.contains(&(lambert.seen_needles / lambert.all_needles)),
                    "{name}: {lambert:?}"
                );
            }
            // Lit from behind, no needle's side the camera sees is lit.
            let behind = impostor.view_lambert(0, &[], needles, -front).unwrap();
            assert!(
                behind.all_needles < 1e-3 && behind.seen_needles < 1e-3,
                "{name}: {behind:?}"
            );
        }
        // Wood in front of every needle leaves none to see.
        let wall = [WoodSegment {
            start: Vec3::new(-6.0, 3.0, 5.0),
            end: Vec3::new(6.0, 3.0, 5.0),
            start_radius: 5.0,
            end_radius: 5.0,
        }];
        let impostor = CrownImpostor::bake(&cloud, &[], &TriangleMesh::default(), options).unwrap();
        assert_eq!(impostor.view_lambert(0, &wall, &cloud, front), None);
    }

    /// The view light scale is what the views show over how the texels
    /// light it, at its own directions and between them: the dense ball
    /// of outward needles (its texels light it too bright from the front)
    /// scales a light behind the camera down by 0.85–0.95 (measured 0.89); a light from
    /// behind scales by ~1; a light from the left as from the right; an
    /// impostor whose needles hide behind wood scales nothing.
    #[test]
    fn the_view_light_scale_lights_the_texels_as_the_views_show() {
        let options = ImpostorOptions {
            views: 2,
            ..ImpostorOptions::default()
        };
        let ball = random_needles(30_000, 0.002, |p, d| {
            let out = direction(d[0], d[1]);
            let base = Vec3::Y * 1.5 + out * (0.2 + 0.8 * p[0].cbrt());
            (base, base + 0.15 * out)
        });
        let impostor = CrownImpostor::bake(&ball, &[], &TriangleMesh::default(), options).unwrap();
        let scale = impostor.view_light_scale(&[], &ball);
        let dim = f64::from(VIEW_LIGHT_DIM_LAMBERT);
        // What `view_lambert` gives, both views and both mirror lights.
        let measured = |to_light: Vec3| {
            let (mut seen, mut texels) = (0.0f64, 0.0f64);
            for view in 0..2 {
                for light in [to_light, to_light * Vec3::new(-1.0, 1.0, 1.0)] {
                    let lambert = impostor.view_lambert(view, &[], &ball, light).unwrap();
                    seen += f64::from(lambert.seen_needles) / 4.0;
                    texels += f64::from(lambert.impostor) / 4.0;
                }
            }
            ((seen + dim) / (texels + dim)) as f32
        };
        for (angle, roll) in [(0, 0), (3, 0), (3, 3), (6, 2), (12, 5)] {
            let direction = ViewLightScale::direction(angle, roll);
            let (stored, expected) = (scale.scales[angle][roll], measured(direction));
            assert!(
                (stored - expected).abs() < 1e-4,
                "{angle}, {roll}: {stored} vs {expected}"
            );
            assert!((scale.at(direction) - stored).abs() < 1e-5, "{angle}, {roll}");
        }
        // From the front the needles in front are lit less than the texels
        // light them (0.89 with the light behind the camera). Between the steps the table holds within
        // 1.5 %: the texels' cylinders are lit by a light along their axes
        // as `sin` of its angle to them, a cusp at the rolls 0, π/2 and π
        // that the steps round off (the low sun from the side, 1.2 %).
        let low = 15f32.to_radians();
        for sun in [Vec3::new(4.0, 8.0, 6.0), Vec3::new(low.cos(), low.sin(), 0.0), Vec3::Z] {
            let (at, expected) = (scale.at(sun), measured(sun.normalize()));
            println!("sun {sun}: table {at:.4}, measured {expected:.4}");
            assert!((at - expected).abs() < 0.015, "{sun}: {at} vs {expected}");
        }
        assert!((0.85..0.95).contains(&scale.at(Vec3::Z)), "{scale:?}");
        assert!((scale.at(-Vec3::Z) - 1.0).abs() < 0.02, "{scale:?}");
        let left = Vec3::new(-0.3, 0.5, 0.4);
        assert_eq!(scale.at(left), scale.at(left * Vec3::new(-1.0, 1.0, 1.0)));
        assert_eq!(scale.at(Vec3::ZERO), 1.0);
        assert_eq!(scale.at(Vec3::NAN), 1.0);
        // A stored table reads back; one out of range does not.
        assert_eq!(ViewLightScale::from_slice(&scale.to_vec()), Some(scale));
        assert_eq!(ViewLightScale::from_slice(&[1.0; 90]), None);
        // Wood in front of every needle in both views: nothing seen, every
        // scale 1.
        let walls = [8.0, -8.0].map(|z| WoodSegment {
            start: Vec3::new(-6.0, 1.5, z),
            end: Vec3::new(6.0, 1.5, z),
            start_radius: 5.0,
            end_radius: 5.0,
        });
        assert_eq!(impostor.view_light_scale(&walls, &ball), ViewLightScale::default());
    }

    #[test]
    fn a_texel_is_lit_like_its_needles() {
        use crate::model::shading::cylinder_lambert;
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/trees/mature/silver-fir.conifer");
        let record = crate::model::file::decode_prototype_record(&std::fs::read(path).unwrap()).unwrap();
        let needles = record.placed_needles();
        let one_view = ImpostorOptions {
            views: 1,
            ..ImpostorOptions::default()
        };
        let impostor = CrownImpostor::bake(&needles, &[], &TriangleMesh::default(), one_view).unwrap();
        // View 0 looks along −z; its right is +x.
        let (columns, rows) = (impostor.columns as usize, impostor.rows as usize);
        let low = 15f32.to_radians();
        let suns = [
            Vec3::new(4.0, 8.0, 6.0).normalize(),
            Vec3::new(low.cos(), low.sin(), 0.0),
            Vec3::new(0.0, low.sin(), -low.cos()),
        ];
        // Per texel: weight, exact sums per sun, the sign-folded axis sum.
        let mut cells = vec![(0.0f64, [0.0f64; 3], Vec3::ZERO); columns * rows];
        for n in &needles {
            let d = n.tip - n.base;
            let w = f64::from(Vec2::new(d.x, d.y).length());
            let (column, row) = impostor.project(0, 0.5 * (n.base + n.tip));
            let cell = &mut cells[row as usize * columns + column as usize];
            cell.0 += w;
            for (sum, sun) in cell.1.iter_mut().zip(suns) {
                *sum += w * f64::from(cylinder_lambert(d.normalize(), Vec3::Z, sun));
            }
            cell.2 += if d.y < 0.0 { -d } else { d }.normalize() * w as f32;
        }
        for (k, sun) in suns.iter().enumerate() {
            let (mut shares_error, mut axis_error, mut weight) = (0.0, 0.0, 0.0);
            for (i, (w, exact, axis)) in cells.iter().enumerate() {
                let texel = impostor
                    .texel_at(0, (i % columns) as u32, (i / columns) as u32)
                    .unwrap();
                if *w <= 0.0 || texel.coverage < 0.25 {
                    continue;
                }
                let exact = exact[k] / w;
                let fitted = texel.shares.lambert(Vec3::Y, Vec3::X, Vec3::Z, *sun);
                let mean_axis = cylinder_lambert(axis.normalize_or(Vec3::Y), Vec3::Z, *sun);
                shares_error += w * (f64::from(fitted) - exact).abs();
                axis_error += w * (f64::from(mean_axis) - exact).abs();
                weight += w;
            }
            let (shares_error, axis_error) = (shares_error / weight, axis_error / weight);
            println!("sun {k}: shares {shares_error:.4}, mean axis {axis_error:.4}");
            assert!(shares_error < 0.025, "sun {k}: {shares_error}");
            assert!(
                shares_error < axis_error / 2.0 || axis_error < 0.003,
                "sun {k}: {shares_error} vs {axis_error}"
            );
        }
    }

    /// The trunk profile finds the stem among the wood: the widest upright
    /// segment at each height, not a wider branch lying flat nor a thin
    /// upright twig; nothing above the stem's top; and the pixel's band
    /// across it.
    #[test]
    fn the_trunk_profile_follows_the_stem() {
        let segment = |start: Vec3, end: Vec3, start_radius: f32, end_radius: f32| WoodSegment {
            start,
            end,
            start_radius,
            end_radius,
        };
        let wood = [
            // A stem leaning toward +x, 0.4 m wide at the foot, to 8 m.
            segment(Vec3::ZERO, Vec3::new(0.2, 4.0, 0.0), 0.2, 0.15),
            segment(Vec3::new(0.2, 4.0, 0.0), Vec3::new(0.4, 8.0, 0.0), 0.15, 0.05),
            // A thick branch lying flat at 3 m, wider than the stem there.
            segment(Vec3::new(0.0, 3.0, 0.0), Vec3::new(3.0, 3.2, 0.0), 0.5, 0.3),
            // A thin upright twig beside the stem.
            segment(Vec3::new(2.0, 2.0, 1.0), Vec3::new(2.0, 6.0, 1.0), 0.02, 0.01),
            // Invalid wood is skipped.
            segment(Vec3::NAN, Vec3::Y, 1.0, 1.0),
        ];
        let profile = TrunkProfile::of(&wood, 0.0, 10.0);
        for step in 0..CROWN_PROFILE_STEPS {
            let height = (step as f32 + 0.5) / CROWN_PROFILE_STEPS as f32 * 10.0;
            let (centre, radius) = (profile.centres[step], profile.radii[step]);
            if height > 8.0 {
                assert_eq!(radius, 0.0, "step {step}");
                continue;
            }
            let (expected_x, expected_radius) = if height <= 4.0 {
                (0.2 * height / 4.0, 0.2 - 0.05 * height / 4.0)
            } else {
                (0.2 + 0.2 * (height - 4.0) / 4.0, 0.15 - 0.1 * (height - 4.0) / 4.0)
            };
            assert!(
                (centre.x - expected_x).abs() < 1e-5 && centre.y.abs() < 1e-6,
                "step {step}: {centre}"
            );
            assert!((radius - expected_radius).abs() < 1e-5, "step {step}: {radius}");
        }
        // Between two steps' middles: linear.
        let (k, t) = CrownImpostor::profile_step(0.0, 10.0, 2.0);
        let (centre, radius) = profile.at(0.0, 10.0, 2.0);
        assert!((radius - (profile.radii[k] * (1.0 - t) + profile.radii[k + 1] * t)).abs() < 1e-6);
        assert!((centre.x - 0.1).abs() < 1e-4, "{centre}");
        // No trunk for an empty span or no wood.
        assert_eq!(TrunkProfile::of(&wood, 5.0, 5.0), TrunkProfile::default());
        assert_eq!(TrunkProfile::of(&[], 0.0, 10.0), TrunkProfile::default());
        assert_eq!(TrunkProfile::of(&wood, f32::NAN, 10.0), TrunkProfile::default());
        // The band a pixel covers: clipped to the trunk, none beside it.
        let close = |band: Option<(f32, f32)>, expected: (f32, f32)| {
            band.is_some_and(|(s0, s1)| (s0 - expected.0).abs() < 1e-6 && (s1 - expected.1).abs() < 1e-6)
        };
        assert!(close(TrunkProfile::band(0.0, 0.1, 0.2), (-0.25, 0.25)));
        assert!(close(TrunkProfile::band(0.15, 0.2, 0.2), (0.25, 1.0)));
        assert_eq!(TrunkProfile::band(0.35, 0.2, 0.2), None);
        assert_eq!(TrunkProfile::band(0.0, 1.0, 0.2), Some((-1.0, 1.0)));
        assert_eq!(TrunkProfile::band(0.0, 0.1, 0.0), None);
        assert_eq!(TrunkProfile::band(f32::NAN, 0.1, 0.2), None);
    }

    #[test]
    fn bad_input_gives_none() {
        let n = needle(Vec3::ZERO, Vec3::Y, 0.01);
        assert!(CrownImpostor::bake(&[], &[], &TriangleMesh::default(), ImpostorOptions::default()).is_none());
        let nan = needle(Vec3::NAN, Vec3::Y, 0.01);
        assert!(CrownImpostor::bake(&[nan], &[], &TriangleMesh::default(), ImpostorOptions::default()).is_none());
        let no_views = ImpostorOptions { views: 0, texel: 0.1 };
        assert!(CrownImpostor::bake(&[n], &[], &TriangleMesh::default(), no_views).is_none());
        for texel in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            let options = ImpostorOptions { views: 8, texel };
            assert!(
                CrownImpostor::bake(&[n], &[], &TriangleMesh::default(), options).is_none(),
                "texel {texel}"
            );
        }
        let flat = needle(Vec3::ZERO, Vec3::X, 0.0);
        assert!(CrownImpostor::bake(&[flat], &[], &TriangleMesh::default(), ImpostorOptions::default()).is_none());
    }

    #[test]
    fn every_tree_gets_the_same_texel_within_the_row_limits() {
        let options = ImpostorOptions::default();
        // Cones 10 m tall and half that: the same texel (the height over
        // whole rows), so both turn into impostors at the same pixel error.
        let tall: Vec<Needle> = cone(2_000, 0.001);
        let short: Vec<Needle> = tall
            .iter()
            .map(|n| needle(n.base * 0.5, n.tip * 0.5, n.radius))
            .collect();
        let mut tree_rows = Vec::new();
        for needles in [&tall, &short] {
            let impostor = CrownImpostor::bake(needles, &[], &TriangleMesh::default(), options).expect("needles");
            assert!(
                impostor.texel <= options.texel && impostor.texel > 0.98 * options.texel,
                "texel {} rows {}",
                impostor.texel,
                impostor.rows
            );
            assert_eq!((impostor.rows % MIP_ALIGN, impostor.columns % MIP_ALIGN), (0, 0));
            assert!((impostor.top() - impostor.bottom - impostor.rows as f32 * impostor.texel).abs() < 1e-4);
            // The tree's height is cut into whole texels, and the picture
            // holds it with at most MIP_ALIGN empty rows above it.
            let tree_top = needles
                .iter()
                .flat_map(|n| [n.base.y + n.radius, n.tip.y + n.radius])
                .fold(f32::NEG_INFINITY, f32::max);
            let rows = (tree_top - impostor.bottom) / impostor.texel;
            assert!((rows - rows.round()).abs() < 1e-2, "{rows} rows over the tree");
            let above = impostor.rows as f32 - rows;
            assert!(
                (-0.5..MIP_ALIGN as f32 + 0.5).contains(&above),
                "{above} rows above the tree"
            );
            tree_rows.push(rows);
        }
        assert!(tree_rows[0] > 1.9 * tree_rows[1], "{tree_rows:?} rows");
        // A 20 cm tree gets MIN_ROWS rows over it, a 100 m one MAX_ROWS.
        let tiny = [needle(Vec3::ZERO, Vec3::Y * 0.2, 0.01)];
        let tiny = CrownImpostor::bake(&tiny, &[], &TriangleMesh::default(), options).expect("needle");
        assert!((tiny.texel - 0.22 / MIN_ROWS as f32).abs() < 1e-5, "{}", tiny.texel);
        let giant = [needle(Vec3::ZERO, Vec3::Y * 100.0, 0.01)];
        let giant = CrownImpostor::bake(&giant, &[], &TriangleMesh::default(), options).expect("needle");
        assert_eq!(giant.rows, MAX_ROWS);
        assert!((giant.texel - 100.02 / MAX_ROWS as f32).abs() < 1e-4, "{}", giant.texel);
    }

    #[test]
    fn a_sparse_crown_keeps_its_needles_area_and_a_dense_one_saturates() {
        // Few thin needles: coverage adds up to their area (no overlap).
        let sparse = cone(2_000, 0.0005);
        let options = ImpostorOptions {
            views: 4,
            texel: 10.0 / 64.0,
        };
        let impostor = CrownImpostor::bake(&sparse, &[], &TriangleMesh::default(), options).expect("needles");
        let area: f32 = sparse.iter().map(|n| 2.0 * n.radius * (n.tip - n.base).length()).sum();
        for view in 0..4 {
            let summed: f32 = impostor.coverage_grid(view).coverage.iter().sum::<f32>() * impostor.texel.powi(2);
            // Projected area: a random direction's length projects to π/4
            // of it on average, and rounding to bytes.
            assert!(
                (summed / (area * std::f32::consts::FRAC_PI_4) - 1.0).abs() < 0.15,
                "view {view}: {summed} vs {area}"
            );
        }
        // Many thick needles: no texel covers more than all of itself.
        let dense = cone(200_000, 0.01);
        let impostor = CrownImpostor::bake(&dense, &[], &TriangleMesh::default(), options).expect("needles");
        let grid = impostor.coverage_grid(0);
        assert!(grid.coverage.iter().all(|&c| (0.0..=1.0).contains(&c)));
        assert!(grid.coverage.iter().any(|&c| c > 0.99));
    }

    #[test]
    fn needles_hidden_behind_needles_add_nothing() {
        // Combs of 50 vertical needles 2 cm wide and 1 m long, 4 cm apart,
        // in planes facing view 0 (its camera on +z): one comb covers
        // 1 m²; a second right behind it adds nothing; one behind it
        // shifted by half a period fills its gaps. (Spreading each needle's
        // area as an optical depth would count the hidden comb as more
        // cover, and the two halves as less than all.)
        let comb = |z: f32, shift: f32| -> Vec<Needle> {
            (0..50)
                .map(|k| {
                    let x = -1.0 + 0.04 * k as f32 + shift;
                    needle(Vec3::new(x, 0.0, z), Vec3::new(x, 1.0, z), 0.01)
                })
                .collect()
        };
        let options = ImpostorOptions {
            views: 4,
            texel: 10.0 / 64.0,
        };
        let covered = |needles: &[Needle]| {
            let impostor = CrownImpostor::bake(needles, &[], &TriangleMesh::default(), options).expect("needles");
            impostor.coverage_grid(0).coverage.iter().sum::<f32>() * impostor.texel.powi(2)
        };
        let one = covered(&comb(0.0, 0.0));
        let hidden = covered(&[comb(0.0, 0.0), comb(-0.5, 0.0)].concat());
        let filled = covered(&[comb(0.0, 0.0), comb(-0.5, 0.02)].concat());
        assert!((one - 1.0).abs() < 0.02, "one comb covers {one} m²");
        assert!((hidden / one - 1.0).abs() < 0.01, "hidden comb: {hidden} against {one}");
        assert!(
            (filled / one - 2.0).abs() < 0.04,
            "shifted comb: {filled} against {one}"
        );
    }

    #[test]
    fn wood_shows_only_where_no_needle_lies_in_front_of_it() {
        // A trunk 2 m tall on the axis; a sheet of horizontal needles in
        // front of its upper half (toward view 0's camera, +z) and one
        // behind its lower half. View 0 sees needles over the upper trunk
        // and the trunk over the lower sheet.
        let sheet = |z: f32, y0: f32| -> Vec<Needle> {
            (0..50)
                .map(|k| {
                    let y = y0 + 0.01 + 0.02 * k as f32;
                    needle(Vec3::new(-0.5, y, z), Vec3::new(0.5, y, z), 0.0105)
                })
                .collect()
        };
        let needles = [sheet(0.5, 1.0), sheet(-0.5, 0.0)].concat();
        let trunk = WoodSegment {
            start: Vec3::ZERO,
            end: Vec3::new(0.0, 2.0, 0.0),
            start_radius: 0.1,
            end_radius: 0.1,
        };
        let options = ImpostorOptions { views: 4, texel: 0.05 };
        let impostor = CrownImpostor::bake(&needles, &[trunk], &TriangleMesh::default(), options).expect("needles");
        let texel = |y: f32| {
            let (column, row) = impostor.project(0, Vec3::new(0.0, y, 0.0));
            impostor.texel_at(0, column as u32, row as u32).expect("inside")
        };
        let (upper, lower) = (texel(1.5), texel(0.5));
        assert!(
            upper.coverage > 0.99 && upper.wood < 0.01,
            "behind the sheet: {upper:?}"
        );
        assert!(
            lower.coverage > 0.99 && lower.wood > 0.99,
            "before the sheet: {lower:?}"
        );
        // From the opposite side (view 2) the roles swap.
        let (column, row) = impostor.project(2, Vec3::new(0.0, 0.5, 0.0));
        let back = impostor.texel_at(2, column as u32, row as u32).expect("inside");
        assert!(back.wood < 0.01, "seen from behind: {back:?}");
    }

    /// An imported tree's bark comes as a triangle mesh: the same trunk as a
    /// mesh covers what it covers as a wood segment (to the polygon's
    /// narrower width), is wood where no needle is in front of it, and
    /// widens the box.
    #[test]
    fn a_wood_mesh_is_baked_like_the_wood_it_stands_for() {
        let needles = cone(5_000, 0.002);
        let trunk = WoodSegment {
            start: Vec3::new(0.0, -3.0, 0.0),
            end: Vec3::new(0.0, 9.0, 0.0),
            start_radius: 0.3,
            end_radius: 0.05,
        };
        let mut mesh = TriangleMesh::default();
        super::super::prism::append_wood_segment(&mut mesh, &trunk, 16);
        let options = ImpostorOptions { views: 4, texel: 0.05 };
        let as_segment = CrownImpostor::bake(&needles, &[trunk], &TriangleMesh::default(), options).expect("needles");
        let as_mesh = CrownImpostor::bake(&needles, &[], &mesh, options).expect("needles");
        let bare = CrownImpostor::bake(&needles, &[], &TriangleMesh::default(), options).expect("needles");
        assert!(
            bare.bottom > -0.1 && (as_mesh.bottom + 3.0).abs() < 0.01,
            "{} {}",
            bare.bottom,
            as_mesh.bottom
        );
        let sums = |impostor: &CrownImpostor, view: u32| {
            let (mut coverage, mut wood) = (0.0f32, 0.0f32);
            for row in 0..impostor.rows {
                for column in 0..impostor.columns {
                    let t = impostor.texel_at(view, column, row).expect("inside");
                    coverage += t.coverage;
                    wood += t.wood;
                }
            }
            (
                coverage * impostor.texel * impostor.texel,
                wood * impostor.texel * impostor.texel,
            )
        };
        for view in 0..4 {
            let (segment_coverage, segment_wood) = sums(&as_segment, view);
            let (mesh_coverage, mesh_wood) = sums(&as_mesh, view);
            // A 16-gon seen across is cos(π/16) to 1 of the circle's width,
            // and the segment has round ends (a half disc of 0.14 m² at the
            // foot) where the open mesh has none.
            assert!(segment_wood > 1.0, "the trunk below the crown shows: {segment_wood} m²");
            assert!(
                mesh_wood >= 0.94 * segment_wood && mesh_wood <= segment_wood,
                "view {view}: wood {mesh_wood} against {segment_wood} m²"
            );
            assert!(
                mesh_coverage <= segment_coverage && mesh_coverage >= segment_coverage - 0.2,
                "view {view}: coverage {mesh_coverage} against {segment_coverage} m²"
            );
        }
    }

    #[test]
    fn coverage_is_near_the_exact_side_view() {
        // The exact binary rasterization (`look::side_coverage`) at the
        // impostor's texel against the impostor's view 0, texel by texel,
        // on a tree of needles scattered at random and with a trunk.
        let needles = cone(60_000, 0.002);
        let trunk = WoodSegment {
            start: Vec3::new(0.0, -2.0, 0.0),
            end: Vec3::new(0.0, 9.0, 0.0),
            start_radius: 0.2,
            end_radius: 0.03,
        };
        let options = ImpostorOptions {
            views: 8,
            texel: 12.1 / 48.0,
        };
        let impostor = CrownImpostor::bake(&needles, &[trunk], &TriangleMesh::default(), options).expect("needles");
        let exact = side_coverage(
            &needles,
            &[trunk],
            SideView {
                azimuth: 0.0,
                pixel: impostor.texel,
                samples: 64,
            },
        )
        .expect("needles");
        let grid = impostor.coverage_grid(0);
        let mean = |values: &[f32]| values.iter().sum::<f32>() / values.len() as f32;
        let ours = mean(&grid.coverage) * (grid.width * grid.height) as f32;
        let reference = mean(&exact.grid.coverage) * (exact.grid.width * exact.grid.height) as f32;
        assert!(
            (ours / reference - 1.0).abs() < 0.05,
            "summed coverage {ours} vs exact {reference}"
        );
        // The trunk below the crown is wood in the impostor: across the row
        // 1 m below the crown, texels cover its width (0.369 m there) and
        // what covers them is upright wood.
        let (_, row) = impostor.project(0, Vec3::new(0.0, -1.0, 0.0));
        let texels: Vec<ImpostorTexel> = (0..impostor.columns)
            .filter_map(|column| impostor.texel_at(0, column, row as u32))
            .filter(|t| t.coverage > 0.0)
            .collect();
        let width: f32 = texels.iter().map(|t| t.coverage).sum::<f32>() * impostor.texel;
        assert!((width / 0.369 - 1.0).abs() < 0.1, "trunk {width} m wide");
        for texel in &texels {
            assert!((texel.wood - texel.coverage).abs() < 0.01, "{texel:?}");
            assert!(texel.shares.vertical > 0.95, "{texel:?}");
        }
    }

    #[test]
    fn the_fade_rises_from_one_texel_to_two_in_8_bit_steps() {
        let texel = 0.25;
        assert_eq!(impostor_fade(0.0, texel, 0.0, SteepFade::DEFAULT), 0.0);
        assert_eq!(impostor_fade(FADE_START * texel, texel, 0.0, SteepFade::DEFAULT), 0.0);
        assert_eq!(impostor_fade(FADE_END * texel, texel, 0.0, SteepFade::DEFAULT), 1.0);
        assert_eq!(impostor_fade(1e9, texel, 0.2, SteepFade::DEFAULT), 1.0);
        assert!(
            (impostor_fade(0.5 * (FADE_START + FADE_END) * texel, texel, -0.3, SteepFade::DEFAULT) - 0.5).abs()
                <= 1.0 / 255.0
        );
        let mut last = 0.0;
        for k in 0..1000 {
            let fade = impostor_fade(k as f32 * 0.001, texel, 0.0, SteepFade::DEFAULT);
            assert!(fade >= last && (fade * 255.0 - (fade * 255.0).round()).abs() < 1e-4);
            last = fade;
        }
        for bad in [f32::NAN, 0.0, -1.0, f32::INFINITY] {
            assert_eq!(impostor_fade(1.0, bad, 0.0, SteepFade::DEFAULT), 0.0);
        }
        assert_eq!(impostor_fade(f32::NAN, texel, 0.0, SteepFade::DEFAULT), 0.0);
        // Looking down on the tree: the impostor gives way to the lines.
        let steep = SteepFade::DEFAULT;
        assert_eq!(impostor_fade(1e9, texel, steep.end, steep), 0.0);
        assert_eq!(impostor_fade(1e9, texel, -2.0, steep), 0.0);
        assert_eq!(impostor_fade(1e9, texel, f32::NAN, steep), 0.0);
        assert!((impostor_fade(1e9, texel, 0.5 * (steep.start + steep.end), steep) - 0.5).abs() <= 1.0 / 255.0);
    }

    /// Every block of any instance hands `round(16·fade)` of its 16
    /// thresholds to the impostor and the rest to the cut, whatever the
    /// fade code: a 4 × 4 block's pixels whole, or under 4× MSAA a 2 × 2
    /// block's samples, a quarter of each four to every pixel; a sample
    /// once the impostor's stays so as the fade grows.
    #[test]
    fn the_crossfade_hands_each_block_over_in_sixteenths() {
        for (samples, side, all) in [(1u32, 4u32, u32::MAX), (4, 2, 0b1111)] {
            for tree in [0u32, 1, 7, 123_456, u32::MAX] {
                let mut last = vec![0u32; (side * side) as usize];
                for code in 0..=255u8 {
                    let expected = (16.0 * f32::from(code) / 255.0).round() as u32;
                    // Blocks anywhere, even across u32 wrapping.
                    for origin in [[0u32, 0], [5, 9], [u32::MAX - 1, 2]] {
                        let mut taken = 0;
                        for y in 0..side {
                            for x in 0..side {
                                let pixel = [origin[0].wrapping_add(x), origin[1].wrapping_add(y)];
                                let mask = impostor_samples(pixel, tree, code, samples);
                                assert!(mask == 0 || mask == all || samples == 4, "{mask:#x}");
                                taken += (mask & all).count_ones();
                                if samples == 4 {
                                    // A pixel's share is within a quarter of the fade.
                                    let share = mask.count_ones() as f32 / 4.0;
                                    assert!((share - f32::from(code) / 255.0).abs() <= 0.25 + 1e-6);
                                }
                            }
                        }
                        let per_pixel = if samples == 4 { 1 } else { 32 };
                        assert_eq!(
                            taken / per_pixel,
                            expected,
                            "{samples} samples, tree {tree}, code {code}"
                        );
                    }
                    for (k, was) in last.iter_mut().enumerate() {
                        let now = impostor_samples([k as u32 % side, k as u32 / side], tree, code, samples);
                        assert_eq!(now & *was, *was, "tree {tree}: pixel {k} handed back at code {code}");
                        *was = now;
                    }
                }
                assert_eq!(impostor_samples([3, 1], tree, 0, samples), 0);
                assert_eq!(impostor_samples([3, 1], tree, 255, samples) & all, all);
            }
        }
        // Trees are dithered apart: the pixels taken at a quarter differ
        // between most neighbours.
        let pattern =
            |tree: u32| -> Vec<u32> { (0..16).map(|k| impostor_samples([k % 4, k / 4], tree, 64, 1)).collect() };
        let differing = (0..32u32).filter(|&t| pattern(t) != pattern(t + 1)).count();
        assert!(differing >= 16, "{differing} of 32 neighbours differ");
    }

    #[test]
    fn mips_keep_the_mean_coverage() {
        let impostor = CrownImpostor::bake(
            &cone(20_000, 0.003),
            &[],
            &TriangleMesh::default(),
            ImpostorOptions { views: 2, texel: 0.25 },
        )
        .expect("needles");
        let chain = impostor.mip_chain();
        assert_eq!(chain.last().map(|l| (l.0, l.1)), Some((1, 1)));
        let mean = |(w, h, t): &(u32, u32, Vec<[u8; 4]>)| {
            t[..(*w * *h) as usize].iter().map(|x| f64::from(x[0])).sum::<f64>() / f64::from(w * h)
        };
        // Every level keeps level 0's mean to within half a step of
        // rounding, the levels of odd size below too.
        for level in &chain[1..] {
            assert!(
                (mean(&chain[0]) - mean(level)).abs() <= 0.5 + 1e-9,
                "{} × {}: {} vs {}",
                level.0,
                level.1,
                mean(level),
                mean(&chain[0])
            );
        }
        let bytes: u64 = chain.iter().map(|l| 4 * l.2.len() as u64).sum();
        assert_eq!(impostor.byte_size(), bytes);
        assert!(bytes < 4 * impostor.texels.len() as u64 * 4 / 3 + 64);
    }

    /// The exact mean of level 0's coverage over the square `[u0, u1) ×
    /// [v0, v1)` (level-0 texel units), zero outside the picture.
    fn box_coverage(impostor: &CrownImpostor, u0: f32, v0: f32, u1: f32, v1: f32) -> f32 {
        let (mut sum, mut area) = (0.0, 0.0);
        let mut y = v0.floor();
        while y < v1 {
            let wy = (v1.min(y + 1.0) - v0.max(y)).max(0.0);
            let mut x = u0.floor();
            while x < u1 {
                let wx = (u1.min(x + 1.0) - u0.max(x)).max(0.0);
                let c = if x >= 0.0 && y >= 0.0 {
                    impostor.texel_at(0, x as u32, y as u32).map_or(0.0, |t| t.coverage)
                } else {
                    0.0
                };
                sum += c * wx * wy;
                area += wx * wy;
                x += 1.0;
            }
            y += 1.0;
        }
        sum / area
    }

    #[test]
    fn the_footprint_filter_is_the_pixels_box_where_one_trilinear_sample_blurs() {
        let impostor = CrownImpostor::bake(
            &cone(40_000, 0.004),
            &[],
            &TriangleMesh::default(),
            ImpostorOptions {
                views: 1,
                texel: 10.0 / 96.0,
            },
        )
        .expect("needles");
        let mips = ImpostorMips::new(&impostor);
        assert_eq!(mips.size(), (impostor.columns, impostor.rows));
        let size = Vec2::new(impostor.columns as f32, impostor.rows as f32);
        // Pixels of 1.5 to 8 texels over the whole picture, the grid
        // shifted off the texels': mean |filtered − exact box| per pixel.
        for texels in [1.5f32, 3.0, 5.0, 8.0] {
            let (mut footprint_error, mut trilinear_error, mut n) = (0.0, 0.0, 0.0);
            let offset = Vec2::new(0.37, 0.61) * texels;
            let columns = (size.x / texels).ceil() as i32;
            let rows = (size.y / texels).ceil() as i32;
            for j in 0..rows {
                for i in 0..columns {
                    let corner = Vec2::new(i as f32, j as f32) * texels - offset;
                    let centre = corner + 0.5 * texels;
                    if centre.x < 0.0 || centre.y < 0.0 || centre.x > size.x || centre.y > size.y {
                        continue;
                    }
                    let exact = box_coverage(&impostor, corner.x, corner.y, corner.x + texels, corner.y + texels);
                    let (du, dv) = (Vec2::new(texels / size.x, 0.0), Vec2::new(0.0, texels / size.y));
                    let uv = centre / size;
                    footprint_error += (mips.footprint(0, uv, du, dv)[0] - exact).abs();
                    trilinear_error += (mips.sample_grad(0, uv, du, dv)[0] - exact).abs();
                    n += 1.0;
                }
            }
            let (footprint_error, trilinear_error) = (footprint_error / n, trilinear_error / n);
            println!("{texels} texels a pixel: footprint {footprint_error:.4}, trilinear {trilinear_error:.4}");
            assert!(
                footprint_error < 0.5 * trilinear_error,
                "{footprint_error} vs {trilinear_error}"
            );
            assert!(footprint_error < 0.03, "{footprint_error}");
        }
        // One texel a pixel or less: one tap, level 0.
        assert_eq!(footprint_taps(0.3), 1);
        assert_eq!(footprint_taps(1.0), 1);
        assert_eq!(footprint_taps(2.5), 3);
        assert_eq!(footprint_taps(40.0), MAX_FOOTPRINT_TAPS);
        assert_eq!(footprint_taps(f32::NAN), 1);
        let uv = Vec2::new(0.5, 0.5);
        let d = Vec2::new(0.5 / size.x, 0.0);
        let e = Vec2::new(0.0, 0.5 / size.y);
        assert_eq!(mips.footprint(0, uv, d, e), mips.sample_grad(0, uv, d, e));
    }

    /// The wood's share in sight where the needles cover the picture, by
    /// height and depth: a trunk inside a dense ring of needles (radius
    /// 0.6 m, its lower half) is hidden from both views; two poles outside
    /// the ring, one on each side, are each in sight from the view it
    /// stands in front of the crown for, and hidden behind the ring from
    /// the other.
    #[test]
    fn wood_visibility_counts_the_needles_in_front() {
        let needles: Vec<Needle> = (0..400)
            .map(|k| {
                let angle = std::f32::consts::TAU * k as f32 / 400.0;
                let at = Vec3::new(0.6 * angle.sin(), 0.0, 0.6 * angle.cos());
                needle(at, at + Vec3::new(0.0, 1.0, 0.0), 0.01)
            })
            .collect();
        let trunk = WoodSegment {
            start: Vec3::ZERO,
            end: Vec3::new(0.0, 2.0, 0.0),
            start_radius: 0.05,
            end_radius: 0.05,
        };
        let pole = |x: f32, z: f32| WoodSegment {
            start: Vec3::new(x, 0.2, z),
            end: Vec3::new(x, 0.8, z),
            start_radius: 0.02,
            end_radius: 0.02,
        };
        // The cameras on +z (view 0) and on −z (view 1); texels small
        // enough that every bin's samples outweigh the fit's prior.
        let options = ImpostorOptions { views: 2, texel: 0.02 };
        let wood = [trunk, pole(0.3, 0.9), pole(-0.3, -0.9)];
        let impostor = CrownImpostor::bake(&needles, &wood, &TriangleMesh::default(), options).expect("needles");
        assert!(impostor.axis.length() < 0.02, "the axis: {}", impostor.axis);
        let radii = impostor.crown_radii();
        let visibility = &impostor.wood_visibility;
        let at = |height: f32, nearness: f32| visibility.at(&radii, impostor.bottom, impostor.top(), height, nearness);
        assert!(at(0.5, 0.05) < 0.1, "the trunk in the ring: {}", at(0.5, 0.05));
        assert!(at(0.5, 0.9) > 0.9, "a pole in front: {}", at(0.5, 0.9));
        assert!(at(0.5, -0.9) < 0.1, "a pole behind: {}", at(0.5, -0.9));
        for share in visibility.shares.iter().flatten() {
            assert!((0.0..=1.0).contains(share));
        }
        // A tree without wood has nothing to hide: every share 1.
        let bare = CrownImpostor::bake(&needles, &[], &TriangleMesh::default(), options).expect("needles");
        assert_eq!(bare.wood_visibility, WoodVisibility::default());
    }

    /// The table is bilinear between its bins' middles and takes the end
    /// bins' outside them; inputs that are not finite read 1.
    #[test]
    fn wood_visibility_is_bilinear_in_its_table() {
        let mut visibility = WoodVisibility::default();
        for (step, row) in visibility.shares.iter_mut().enumerate() {
            for (bin, share) in row.iter_mut().enumerate() {
                *share = (step as f32 / 31.0) * (bin as f32 / 7.0);
            }
        }
        let radii = [2.0; CROWN_PROFILE_STEPS];
        let (bottom, top) = (0.0, 32.0);
        // Bin b's middle lies at nearness (2(b + 0.5)/8 − 1)·radius.
        let middle = |bin: f32| ((bin + 0.5) / 4.0 - 1.0) * 2.0;
        let at = |height: f32, nearness: f32| visibility.at(&radii, bottom, top, height, nearness);
        assert!((at(10.5, middle(3.0)) - 10.0 / 31.0 * 3.0 / 7.0).abs() < 1e-5);
        assert!((at(10.5, middle(3.5)) - 10.0 / 31.0 * 3.5 / 7.0).abs() < 1e-5);
        assert!((at(11.0, middle(3.0)) - 10.5 / 31.0 * 3.0 / 7.0).abs() < 1e-5);
        assert!((at(40.0, 10.0) - 1.0).abs() < 1e-5);
        assert_eq!(at(-5.0, -10.0), 0.0);
        assert_eq!(at(f32::NAN, 0.0), 1.0);
        assert_eq!(at(1.0, f32::INFINITY), 1.0);
    }

    proptest::proptest! {
        /// The two draws of a wood line, blended over a background with
        /// needle lines between them, give the wood `a·(g + (1 − g)·t)` of
        /// the pixel and the background `t·(1 − a)`, and each opacity lies
        /// in [0, 1].
        #[test]
        fn wood_layers_split_the_wood_by_its_share_in_sight(
            a in 0.0f32..=1.0,
            g in 0.0f32..=1.0,
            t in 0.0f32..=1.0,
        ) {
            let (under, over) = wood_layer_opacities(a, g);
            proptest::prop_assert!((0.0..=1.0).contains(&under) && (0.0..=1.0).contains(&over));
            // Weights of the wood and the background after each "over".
            let (mut wood, mut background) = (under, 1.0 - under);
            (wood, background) = (wood * t, background * t);
            (wood, background) = (over + wood * (1.0 - over), background * (1.0 - over));
            // At a = 1 and g = 1 the under draw divides 0 by 1e-6.
            let tolerance = 1e-4;
            proptest::prop_assert!((wood - a * (g + (1.0 - g) * t)).abs() < tolerance, "wood {wood}");
            proptest::prop_assert!((background - t * (1.0 - a)).abs() < tolerance, "background {background}");
        }

        /// Whatever the table and the point, the share lies in [0, 1].
        #[test]
        fn wood_visibility_is_a_share(
            shares in proptest::collection::vec(0.0f32..=1.0, CROWN_PROFILE_STEPS * WOOD_NEARNESS_BINS),
            radius in 0.0f32..5.0,
            height in -10.0f32..40.0,
            nearness in -20.0f32..20.0,
        ) {
            let mut visibility = WoodVisibility::default();
            for (k, share) in shares.iter().enumerate() {
                visibility.shares[k / WOOD_NEARNESS_BINS][k % WOOD_NEARNESS_BINS] = *share;
            }
            let v = visibility.at(&[radius; CROWN_PROFILE_STEPS], 0.0, 30.0, height, nearness);
            proptest::prop_assert!((0.0..=1.0).contains(&v));
        }
    }
}
