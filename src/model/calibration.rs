//! Line opacity calibrated against the needles' own coverage.
//!
//! A pixel crossed by several translucent lines is blended as if each
//! line's needles fell at random with respect to the others':
//! `1 − Π(1 − cᵢ)`. A crown's needles do not fall at random: they clump
//! in shoots, and shoots in branches, along the line of sight, so a
//! crown's lines drawn by their area ([`super::raster`]) cover more than
//! its needles do, and the more the larger the pixel (the more needles a
//! line and a pixel stand for). No property of one line can see it: it is
//! the crown's, and it depends on the pixel size.
//!
//! So the bake measures it. At [`CALIBRATION_STEPS`] pixel sizes, from
//! where every needle is a line to where the crown is
//! [`MIN_CALIBRATION_ROWS`] pixels tall, the tree is seen from
//! [`CalibrationOptions::views`] sides (orthographic, about the vertical
//! axis, over half a turn; level, and with
//! [`CalibrationOptions::elevation_degrees`] from above and below too):
//! the needles' exact silhouettes, sampled once
//! a view on a grid of binary samples ([`SideNeedles`]) and counted into
//! each size's pixels, give what they cover; the cut at that pixel size,
//! each line composed by its strip's area in each pixel
//! ([`super::raster::strip_pixel_coverage`]) at the area-preserving
//! opacity, gives what the lines cover, over the same pixels (a fixed
//! subset of about [`CalibrationOptions::max_pixels`] where a picture has
//! more). The scale of every line's opacity
//! that makes the two totals equal, averaged over the views, is the
//! table's entry ([`LineCalibration`]); the plugin multiplies each line's
//! opacity by the table at the line's pixel size, interpolated in log
//! size, so the scale changes smoothly with distance and never pops.
//!
//! The wood's lines meet the same bias from the other side. A branch
//! thinner than a pixel is a line too, drawn under the needle lines (and
//! over them, [`super::impostor::WoodVisibility`]), and blending composes
//! it with them as if they fell at random with respect to each other,
//! where a twig sits inside its own needles: on the young Norway spruce
//! at 6 cm pixels the wood lines add to the needles' coverage 1.5 times
//! what the wood adds to the needles' silhouettes, 11 % over the tree's
//! whole coverage. A trunk or a bare branch drawn as a line is not hidden
//! so, and a twig at one pixel size is as wide, relative to its pixel, as
//! a branch at another: so each size also measures a scale for the wood
//! lines at each of [`WOOD_OPACITY_NODES`] opacities (a line's width over
//! its pixel, 1/64 to 1), the lines nearest each opacity matched on their
//! own: the scale at which they add to the calibrated needle lines (and
//! the wood drawn as prisms), in total, what their silhouettes add to the
//! needles' and the prisms' ([`LineCalibration::wood_scales`]). The
//! plugin interpolates the table in log size and log opacity.
//!
//! The table is calibrated at one pixel error
//! ([`CalibrationOptions::pixel_error`], the plugin's default 1): at
//! another the cut at a pixel size is coarser or finer than calibrated.

use super::look::{PieceEnds, SampleBits, view_axes};
use super::needle::WoodSegment;
use super::prism::WOOD_LINE_FADE;
use super::raster::StripInPixels;
use super::record::LodRecord;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Pixel sizes a [`LineCalibration`] holds a scale at.
pub const CALIBRATION_STEPS: usize = 8;

/// The smallest scale a calibration holds: a crown whose lines would need
/// less is clamped to it.
pub const MIN_LINE_SCALE: f32 = 0.25;

/// The largest scale a calibration holds.
pub const MAX_LINE_SCALE: f32 = 2.0;

/// Pixels the crown's largest side spans at most at the first pixel size
/// (finer pixels than that cost more to sample than they tell).
pub const MAX_CALIBRATION_ROWS: f32 = 1024.0;

/// Pixels the crown's largest side spans at least at the last pixel size:
/// on fewer the totals are a handful of pixels.
pub const MIN_CALIBRATION_ROWS: f32 = 16.0;

/// Opacity scales of a tree's lines by pixel size, measured by
/// [`calibrate_lines`]: [`CALIBRATION_STEPS`] entries at pixel sizes
/// spaced evenly in log size from `first_pixel` to `last_pixel`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LineCalibration {
    /// Pixel size of the first entry, metres.
    pub first_pixel: f32,
    /// Pixel size of the last entry, metres (above `first_pixel`).
    pub last_pixel: f32,
    /// Scale of every line's opacity at each pixel size, in
    /// `[MIN_LINE_SCALE, MAX_LINE_SCALE]`.
    pub scales: [f32; CALIBRATION_STEPS],
    /// Scale of a wood line's opacity at each pixel size (rows) and each
    /// of [`WOOD_OPACITY_NODES`] opacities of the line (columns, see
    /// [`wood_opacity_node`]), in `[MIN_LINE_SCALE, MAX_LINE_SCALE]`: all
    /// 1 in a table read from a record older than format 11; where a size
    /// draws no wood line near an opacity, the nearest opacity's that
    /// does (1 where none does).
    #[serde(default = "unit_wood_scales")]
    pub wood_scales: [[f32; WOOD_OPACITY_NODES]; CALIBRATION_STEPS],
}

/// `a` to `b` by `t` in `[0, 1]`, exactly `a` at 0 and `b` at 1.
fn mix(a: f32, b: f32, t: f32) -> f32 {
    a * (1.0 - t) + b * t
}

/// Opacities (a wood line's width over its pixel) a
/// [`LineCalibration::wood_scales`] row holds a scale at: 1/64, 1/16, 1/4
/// and 1, evenly spaced in log opacity.
pub const WOOD_OPACITY_NODES: usize = 4;

/// Where a wood line of opacity `opacity` falls among the
/// [`WOOD_OPACITY_NODES`]: `log₄(64 · opacity)`, clamped to `[0, 3]` (a
/// NaN opacity takes 0).
pub fn wood_opacity_node(opacity: f32) -> f32 {
    // `max` takes 1e-12 for a NaN opacity.
    let node = 0.5 * ((opacity.max(1e-12)).log2() + 6.0);
    node.clamp(0.0, (WOOD_OPACITY_NODES - 1) as f32)
}

fn unit_wood_scales() -> [[f32; WOOD_OPACITY_NODES]; CALIBRATION_STEPS] {
    [[1.0; WOOD_OPACITY_NODES]; CALIBRATION_STEPS]
}

impl LineCalibration {
    /// `true` when the pixel sizes are positive, finite and increasing and
    /// every scale lies in `[MIN_LINE_SCALE, MAX_LINE_SCALE]`.
    pub fn is_valid(&self) -> bool {
        self.first_pixel.is_finite()
            && self.first_pixel > 0.0
            && self.last_pixel.is_finite()
            && self.last_pixel > self.first_pixel
            && self
                .scales
                .iter()
                .chain(self.wood_scales.as_flattened())
                .all(|s| (MIN_LINE_SCALE..=MAX_LINE_SCALE).contains(s))
    }

    /// Pixel size of entry `step`, metres.
    pub fn pixel(&self, step: usize) -> f32 {
        let t = step as f32 / (CALIBRATION_STEPS - 1) as f32;
        self.first_pixel * (self.last_pixel / self.first_pixel).powf(t)
    }

    /// Where the shader finds a pixel size in the table: `log2` of the
    /// first pixel size, and entries per doubling of the size
    /// (`step = (log2(pixel) − x) · y`).
    pub fn log_range(&self) -> [f32; 2] {
        [
            self.first_pixel.log2(),
            (CALIBRATION_STEPS - 1) as f32 / (self.last_pixel / self.first_pixel).log2(),
        ]
    }

    /// The scale at a pixel size of `pixel` metres: the table interpolated
    /// linearly in log size, its first entry below the first size and its
    /// last above the last (a NaN size takes the first). CPU reference of
    /// the shader's `line_calibration`.
    pub fn scale_at(&self, pixel: f32) -> f32 {
        let (k, f) = self.step_at(pixel);
        mix(self.scales[k], self.scales[k + 1], f)
    }

    /// The scale of a wood line of opacity `opacity` (its width over its
    /// pixel) at a pixel size of `pixel` metres: [`Self::wood_scales`]
    /// interpolated linearly in log size, as [`Self::scale_at`], and in
    /// log opacity between its nodes ([`wood_opacity_node`]), held beyond
    /// its ends. CPU reference of the shader's `wood_line_calibration`.
    pub fn wood_scale_at(&self, pixel: f32, opacity: f32) -> f32 {
        let (k, f) = self.step_at(pixel);
        let node = wood_opacity_node(opacity);
        let j = (node as usize).min(WOOD_OPACITY_NODES - 2);
        let g = node - j as f32;
        let row = |row: &[f32; WOOD_OPACITY_NODES]| mix(row[j], row[j + 1], g);
        mix(row(&self.wood_scales[k]), row(&self.wood_scales[k + 1]), f)
    }

    /// The entry below `pixel` and how far toward the next it lies, in
    /// log size: the first entry below the first size, the last above the
    /// last, the first for a NaN size.
    fn step_at(&self, pixel: f32) -> (usize, f32) {
        let [log_first, per_doubling] = self.log_range();
        let last = (CALIBRATION_STEPS - 1) as f32;
        let t = (pixel.log2() - log_first) * per_doubling;
        if t.is_nan() || t <= 0.0 {
            return (0, 0.0);
        }
        if t >= last {
            return (CALIBRATION_STEPS - 2, 1.0);
        }
        let k = (t as usize).min(CALIBRATION_STEPS - 2);
        (k, t - k as f32)
    }
}

/// How [`calibrate_lines`] measures a tree.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationOptions {
    /// Side views, evenly spaced over half a turn about the vertical axis,
    /// whose scales are averaged (default 2: looking along −Z and along
    /// −X). An orthographic view from the opposite side is the mirror
    /// image of one of these: a mature Scots pine's scales seen from 0°
    /// and 180° differed by at most 0.3 % at every size, sampling alone.
    pub views: u32,
    /// Binary samples along each axis of a pixel of the first (finest)
    /// size, at least (default 16: within 0.002 of the exact silhouettes'
    /// scale on the young trees); more where the thinnest needle would be
    /// narrower than four samples (up to 256 a pixel), within
    /// `max_samples`. Every size counts the same samples into its pixels.
    pub samples: u32,
    /// Most samples one view takes (default 2²⁴, 2 MiB of bits): a larger
    /// crown is sampled coarser, at least 2 along each axis of a pixel of
    /// the first size (at 2²⁶ an imported 48,607-needle pine, 1,024 rows at
    /// its first size, spent most of its bake here).
    pub max_samples: u64,
    /// Most pixels one view measures at one size (default 2¹⁶): a picture
    /// with more measures a fixed pseudo-random subset of about this many,
    /// the needles' and the lines' totals over the same pixels (the finest
    /// size of a 2 M-needle crown has 0.6 M pixels and 12 M line-pixel
    /// pairs to compose).
    #[serde(default = "default_max_pixels")]
    pub max_pixels: u64,
    /// The pixel error the cut is taken at: a pixel of `s` metres draws
    /// the cut at spatial error `s · pixel_error` (default 1, the plugin's).
    pub pixel_error: f32,
    /// Where above 0, each side view is also taken from this many degrees
    /// above and below the horizontal (three times the views, averaged
    /// alike). A level view sees a tree's tiers edge on, where their
    /// needles hide each other most; a camera sees a tree from a spread of
    /// elevations (its perspective alone spans ±11° of a 5 m tree 12 m
    /// away). Default 0: level views only (as is an angle that is not
    /// finite; one of 90° or more adds no views).
    #[serde(default)]
    pub elevation_degrees: f32,
}

fn default_max_pixels() -> u64 {
    1 << 16
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        Self {
            views: 2,
            samples: 16,
            max_samples: 1 << 24,
            max_pixels: default_max_pixels(),
            pixel_error: 1.0,
            elevation_degrees: 0.0,
        }
    }
}

/// The pixel sizes [`calibrate_lines`] spans, metres: from where every
/// needle is a line (the largest original-line error over the pixel
/// error), but no finer than the crown's largest side over
/// [`MAX_CALIBRATION_ROWS`], to the largest merged-line error, but no
/// coarser than that side over [`MIN_CALIBRATION_ROWS`] (and at least
/// twice the first). `None` without valid needles or with a pixel error
/// that is not positive and finite.
pub fn calibration_pixels(record: &LodRecord, options: &CalibrationOptions) -> Option<(f32, f32)> {
    let pixel_error = options.pixel_error;
    if !(pixel_error.is_finite() && pixel_error > 0.0) {
        return None;
    }
    let (lo, hi) = needle_bounds(record)?;
    let side = (hi - lo).max_element();
    if !(side.is_finite() && side > 0.0) {
        return None;
    }
    let ranges = record.part_ranges();
    let first = (ranges.original_lines.max / pixel_error).max(side / MAX_CALIBRATION_ROWS);
    let merged = ranges.merged_lines.map_or(ranges.original_lines.max, |r| r.max);
    let last = (merged / pixel_error).min(side / MIN_CALIBRATION_ROWS).max(2.0 * first);
    (first.is_finite() && first > 0.0 && last.is_finite()).then_some((first, last))
}

/// Side of the samples [`calibrate_lines`] takes of `record` whose first
/// pixel size is `first_pixel` metres: `first_pixel / options.samples`,
/// finer where the thinnest needle would be narrower than four samples
/// (at most 256 a pixel), coarser where a side view of the needles'
/// bounds (as wide as their horizontal diagonal) would take more than
/// `options.max_samples`, but at least 2 a pixel. `None` without valid
/// needles or with a first pixel size that is not positive and finite.
pub fn sample_spacing(record: &LodRecord, options: &CalibrationOptions, first_pixel: f32) -> Option<f32> {
    if !(first_pixel.is_finite() && first_pixel > 0.0) {
        return None;
    }
    let (lo, hi) = needle_bounds(record)?;
    let extent = hi - lo;
    // The thinnest needle's radius (the smallest original-line error is
    // its `2R`).
    let thinnest = 0.5 * record.part_ranges().original_lines.min;
    let wanted = options
        .samples
        .max(1)
        .max((first_pixel / (0.5 * thinnest)).ceil().min(256.0) as u32);
    let width = extent.x.hypot(extent.z) + 2.0 * first_pixel;
    let height = extent.y + 2.0 * first_pixel;
    let coarsest = (f64::from(width) * f64::from(height) / options.max_samples.max(1) as f64).sqrt() as f32;
    let spacing = (first_pixel / wanted as f32).max(coarsest).min(0.5 * first_pixel);
    (spacing.is_finite() && spacing > 0.0).then_some(spacing)
}

/// Measures `record`'s table of line opacity scales (see the module
/// docs). Each view samples the needles once ([`SideNeedles`]) and every
/// size counts those samples into its own pixels; the views, then the
/// sizes of each view, run in parallel. `None` where
/// [`calibration_pixels`] gives no range.
pub fn calibrate_lines(record: &LodRecord, options: &CalibrationOptions) -> Option<LineCalibration> {
    let (first_pixel, last_pixel) = calibration_pixels(record, options)?;
    let spacing = sample_spacing(record, options, first_pixel)?;
    let mut table = LineCalibration {
        first_pixel,
        last_pixel,
        scales: [1.0; CALIBRATION_STEPS],
        wood_scales: unit_wood_scales(),
    };
    let views = options.views.max(1);
    let tilt = options.elevation_degrees.to_radians();
    let elevations: &[f32] = if tilt > 0.0 { &[0.0, tilt, -tilt] } else { &[0.0] };
    let sides: Vec<SideNeedles> = (0..views)
        .flat_map(|view| elevations.iter().map(move |&elevation| (view, elevation)))
        .collect::<Vec<_>>()
        .into_par_iter()
        .filter_map(|(view, elevation)| {
            let azimuth = std::f32::consts::PI * view as f32 / views as f32;
            SideNeedles::tilted(record, azimuth, elevation, spacing)
        })
        .collect();
    // Each view's needle scale and the wood scales that go with it.
    let found: Vec<Vec<(f32, [Option<f32>; WOOD_OPACITY_NODES])>> = (0..CALIBRATION_STEPS)
        .into_par_iter()
        .map(|step| {
            let pixel = table.pixel(step);
            let error = pixel * options.pixel_error;
            let (lines, wood) = (cut_lines(record, error), cut_wood(record, error));
            sides
                .par_iter()
                .filter_map(|side| SideComposition::of_lines(side, &lines, &wood, pixel, options))
                .map(|composition| {
                    let scale = composition.matching_scale();
                    (scale, composition.matching_wood_scales(scale))
                })
                .collect()
        })
        .collect();
    for ((entry, wood_row), found) in table.scales.iter_mut().zip(&mut table.wood_scales).zip(found) {
        if found.is_empty() {
            continue;
        }
        *entry = found.iter().map(|f| f.0).sum::<f32>() / found.len() as f32;
        // Each node's mean over the views that draw lines near it, then
        // the nodes without any filled from the nearest that has one.
        let means: Vec<Option<f32>> = (0..WOOD_OPACITY_NODES)
            .map(|node| {
                let seen: Vec<f32> = found.iter().filter_map(|f| f.1[node]).collect();
                (!seen.is_empty()).then(|| seen.iter().sum::<f32>() / seen.len() as f32)
            })
            .collect();
        for (node, scale) in wood_row.iter_mut().enumerate() {
            let nearest = (0..WOOD_OPACITY_NODES)
                .filter_map(|other| means[other].map(|m| (node.abs_diff(other), m)))
                .min_by_key(|&(gap, _)| gap);
            *scale = nearest.map_or(1.0, |(_, m)| m);
        }
    }
    Some(table)
}

/// Most samples a [`SideNeedles`] takes whatever its spacing (512 MiB of
/// bits): a finer spacing gives `None`.
const MAX_SIDE_SAMPLES: u64 = 1 << 32;

/// A tree's needles seen from one side, orthographic, from an azimuth
/// about the vertical axis and an elevation above or below the
/// horizontal (level by default): their exact silhouettes on one grid of binary samples
/// ([`SampleBits`]) over the needles' bounds, which every pixel size of a
/// calibration counts into its own pixels ([`SideComposition::new`]).
#[derive(Clone, Debug)]
pub struct SideNeedles {
    /// Azimuth of the viewing direction about +Y, radians (0 looks along
    /// −Z; the picture's x runs along `(cos a, 0, sin a)`).
    pub azimuth: f32,
    /// How far above the horizontal the viewer looks down, radians (0 for
    /// a level view, the calibration's; negative from below).
    pub elevation: f32,
    /// Side of a sample, metres.
    pub spacing: f32,
    /// Lower left corner of the needles' bounds in the picture (x right,
    /// y up, metres), the samples' corner.
    low: Vec2,
    /// Upper right corner of the needles' bounds in the picture.
    high: Vec2,
    /// The samples, row 0 at `high.y`, rows downwards.
    bits: SampleBits,
}

impl SideNeedles {
    /// Samples `record`'s valid needles seen from `azimuth` every
    /// `spacing` metres (a sample is covered when its centre lies within a
    /// needle's radius of its axis between its ends, or in one of its
    /// prism's end caps seen at its slant, [`PieceEnds::Capped`]). `None` without
    /// valid needles, with a spacing that is not positive and finite, or
    /// one that would take more than 2³² samples.
    pub fn new(record: &LodRecord, azimuth: f32, spacing: f32) -> Option<Self> {
        Self::tilted(record, azimuth, 0.0, spacing)
    }

    /// [`Self::new`] seen from `elevation` radians above the horizontal
    /// (below it when negative; the picture's y axis tilts with the view).
    /// `None` also for an elevation that is not finite or not within a
    /// quarter turn of the horizontal.
    pub fn tilted(record: &LodRecord, azimuth: f32, elevation: f32, spacing: f32) -> Option<Self> {
        if !(spacing.is_finite()
            && spacing > 0.0
            && azimuth.is_finite()
            && elevation.abs() < std::f32::consts::FRAC_PI_2)
        {
            return None;
        }
        let [right, up, toward] = view_axes(azimuth, elevation);
        let (mut low, mut high) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        for n in record.needles.iter().filter(|n| n.is_valid()) {
            for p in [n.base, n.tip] {
                let q = Vec2::new(p.dot(right), p.dot(up));
                low = low.min(q - n.radius);
                high = high.max(q + n.radius);
            }
        }
        if !(low.is_finite() && high.is_finite()) {
            // No valid needle.
            return None;
        }
        let width = ((high.x - low.x) / spacing).ceil().max(1.0);
        let height = ((high.y - low.y) / spacing).ceil().max(1.0);
        if f64::from(width) * f64::from(height) > MAX_SIDE_SAMPLES as f64 {
            return None;
        }
        let mut bits = SampleBits::new(width as u32, height as u32);
        let to_samples = |p: Vec3| side_sample(p, [right, up], low, high, spacing);
        for n in record.needles.iter().filter(|n| n.is_valid()) {
            let r = n.radius / spacing;
            let (a, b) = (to_samples(n.base), to_samples(n.tip));
            // Deep in a dense crown a needle often falls where every
            // sample is set already.
            if !bits.box_is_full(a, b, r) {
                bits.stamp(a, b, r, r, PieceEnds::of_cylinder(n.tip - n.base, toward));
            }
        }
        Some(Self {
            azimuth,
            elevation,
            spacing,
            low,
            high,
            bits,
        })
    }

    /// Samples across and down.
    pub fn size(&self) -> [u32; 2] {
        [self.bits.width, self.bits.height]
    }

    /// The picture's right and up and the direction toward the viewer, in
    /// the tree's frame.
    pub fn axes(&self) -> [Vec3; 3] {
        view_axes(self.azimuth, self.elevation)
    }
}

/// A tree seen from one side at one pixel size: what its needles cover in
/// each pixel, and what the lines of its cut at that size cover composed
/// as the plugin blends them, at any scale of their opacity, over the
/// pixels it measures.
#[derive(Clone, Debug, PartialEq)]
pub struct SideComposition {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// Side of a pixel, metres.
    pub pixel: f32,
    /// Each pixel's coverage by the needles' silhouettes (row-major): its
    /// covered samples over the samples whose centres it holds.
    pub needles: Vec<f32>,
    /// Whether each pixel is measured (row-major): all of them, or about
    /// [`CalibrationOptions::max_pixels`] chosen by a hash of the pixel's
    /// index where the picture has more.
    pub measured: Vec<bool>,
    /// Lines of the cut drawn (original and merged).
    pub lines: usize,
    /// Each line's unscaled coverage of each measured pixel it touches:
    /// its opacity times its strip's mean length inside the pixel, with
    /// the pixel's index.
    touches: Vec<(u32, f32)>,
    /// Each pixel's coverage by the wood drawn as prisms at this size
    /// (row-major): opaque, composed with the lines as they are.
    pub wood_prisms: Vec<f32>,
    /// For each of [`WOOD_OPACITY_NODES`], each pixel's coverage by the
    /// wood lines nearest that opacity where neither a needle nor a wood
    /// prism covers it (row-major, their samples within the needles'
    /// bounds): what those lines' silhouettes add.
    pub wood_bare: [Vec<f32>; WOOD_OPACITY_NODES],
    /// Wood segments drawn as lines at this size.
    pub wood_lines: usize,
    /// Each wood line's unscaled coverage of each measured pixel it
    /// touches, as `touches`, the line clipped to the needles' bounds
    /// (the wood's samples cover no more), with the opacity node nearest
    /// the line's opacity.
    wood_touches: Vec<(u32, f32, u8)>,
}

impl SideComposition {
    /// Measures `record` at pixels of `pixel` metres from `side`, its
    /// needles' samples (the picture is their bounds and two pixels of
    /// margin), at `options.pixel_error`, over about
    /// `options.max_pixels` pixels at most: `None` with a pixel size or
    /// pixel error that is not positive and finite, or a pixel smaller
    /// than a sample or giving more than 2³² pixels. Lines take the
    /// area-preserving opacity `min(w / s, 1)` (`w` a line's needles'
    /// summed side area over its length, `s` the pixel size), each pixel
    /// `min(opacity · strip_pixel_coverage, 1)`; a needle the cut draws as
    /// a prism (a pixel finer than the calibration's range) counts as its
    /// original line. Wood segments are drawn as the plugin draws them at
    /// this size (`cut_wood`): prisms where they are wider than the
    /// spatial error, lines of opacity `min((r₀ + r₁) / s, 1)` from there
    /// to [`WOOD_LINE_FADE`] times that, nothing past it.
    pub fn new(record: &LodRecord, side: &SideNeedles, pixel: f32, options: &CalibrationOptions) -> Option<Self> {
        let error = pixel * options.pixel_error;
        if !(error.is_finite() && error > 0.0) {
            return None;
        }
        Self::of_lines(
            side,
            &cut_lines(record, error),
            &cut_wood(record, error),
            pixel,
            options,
        )
    }

    /// [`Self::new`] for the lines [`cut_lines`] and the wood
    /// [`cut_wood`] give (a calibration cuts once a size for all its
    /// views).
    fn of_lines(
        side: &SideNeedles,
        lines: &[CutLine],
        wood: &CutWood,
        pixel: f32,
        options: &CalibrationOptions,
    ) -> Option<Self> {
        let pixel_error = options.pixel_error;
        if !(pixel.is_finite() && pixel >= side.spacing && pixel_error.is_finite() && pixel_error > 0.0) {
            return None;
        }
        // Two pixels of margin: a line's strip reaches half a pixel past
        // its segment.
        let margin = 2.0 * pixel;
        let (lo, hi) = (side.low - margin, side.high + margin);
        let (width, height) = (
            ((hi.x - lo.x) / pixel).ceil().max(1.0),
            ((hi.y - lo.y) / pixel).ceil().max(1.0),
        );
        if f64::from(width) * f64::from(height) > MAX_SIDE_SAMPLES as f64 {
            return None;
        }
        let (width, height) = (width as u32, height as u32);
        let pixels = width as usize * height as usize;
        // Picture metres to pixel units (x right, y down from the top).
        let top = lo.y + height as f32 * pixel;
        let [right, up, _] = side.axes();
        let in_picture = |p: Vec3| Vec2::new(p.dot(right), p.dot(up));
        let to_pixels_2d = |q: Vec2| Vec2::new((q.x - lo.x) / pixel, (top - q.y) / pixel);
        let to_pixels = |p: Vec3| to_pixels_2d(in_picture(p));

        // Which pixel column each sample column falls in (its centre), and
        // how many sample columns each pixel column holds, counting the
        // clear samples past the needles' bounds the same way; rows alike.
        let spacing = side.spacing;
        let [sample_columns, sample_rows] = side.size();
        let columns = SampleAxis::new(sample_columns, width, side.low.x - lo.x, pixel, spacing);
        let rows = SampleAxis::new(sample_rows, height, top - side.high.y, pixel, spacing);
        let sample_width = sample_columns as usize;
        // Each pixel column's run of sample columns (`pixel_of` never
        // decreases): a row's samples in a pixel are counted a word at a
        // time.
        let column_runs = columns.runs();
        let coverage = |bits: &SampleBits| -> Vec<f32> {
            let mut counts = vec![0u32; pixels];
            for (v, &pixel_row) in rows.pixel_of.iter().enumerate() {
                let (row, counts_row) = (v * sample_width, pixel_row as usize * width as usize);
                for &(pixel_column, first, last) in &column_runs {
                    counts[counts_row + pixel_column as usize] += bits.count_set_in(row + first, row + last);
                }
            }
            counts
                .into_iter()
                .enumerate()
                .map(|(k, c)| {
                    let held = rows.held[k / width as usize] * columns.held[k % width as usize];
                    (c as f32 / held.max(1) as f32).min(1.0)
                })
                .collect()
        };
        let needles = coverage(&side.bits);
        // The wood on the needles' samples, as cones with round ends (they
        // meet their neighbours): its prisms, and its lines by the opacity
        // node nearest each line's.
        let to_samples = |p: Vec3| side_sample(p, [right, up], side.low, side.high, spacing);
        let stamp = |bits: &mut SampleBits, w: &WoodSegment| {
            bits.stamp(
                to_samples(w.start),
                to_samples(w.end),
                w.start_radius / spacing,
                w.end_radius / spacing,
                PieceEnds::Round,
            );
        };
        let mut prism_bits = SampleBits::new(sample_columns, sample_rows);
        for w in &wood.prisms {
            stamp(&mut prism_bits, w);
        }
        let wood_prisms = coverage(&prism_bits);
        let hiding = side.bits.union(&prism_bits)?;
        let node_of = |line: &CutLine| wood_opacity_node((line.area_per_length / pixel).min(1.0)).round() as usize;
        let wood_bare: [Vec<f32>; WOOD_OPACITY_NODES] = std::array::from_fn(|node| {
            let mut bits = SampleBits::new(sample_columns, sample_rows);
            for (w, line) in wood.line_segments.iter().zip(&wood.lines) {
                if node_of(line) == node {
                    stamp(&mut bits, w);
                }
            }
            coverage(&bits.minus(&hiding).unwrap_or(bits))
        });

        let fraction = options.max_pixels as f64 / pixels as f64;
        let measured: Vec<bool> = if fraction >= 1.0 {
            vec![true; pixels]
        } else {
            let threshold = (fraction * u32::MAX as f64) as u32;
            (0..pixels as u64).map(|k| pixel_hash(k) <= threshold).collect()
        };

        let mut touches = Vec::new();
        for line in lines {
            let opacity = (line.area_per_length / pixel).min(1.0);
            strip_touches(
                to_pixels(line.a),
                to_pixels(line.b),
                opacity,
                [width, height],
                &measured,
                &mut touches,
            );
        }
        // The wood is sampled over the needles' bounds only: its lines are
        // clipped to them too.
        let (mut wood_touches, mut touches_of_line) = (Vec::new(), Vec::new());
        for line in &wood.lines {
            let Some((a, b)) = clip_to_box(in_picture(line.a), in_picture(line.b), side.low, side.high) else {
                continue;
            };
            let opacity = (line.area_per_length / pixel).min(1.0);
            let node = node_of(line) as u8;
            strip_touches(
                to_pixels_2d(a),
                to_pixels_2d(b),
                opacity,
                [width, height],
                &measured,
                &mut touches_of_line,
            );
            wood_touches.extend(touches_of_line.drain(..).map(|(p, c)| (p, c, node)));
        }
        Some(Self {
            width,
            height,
            pixel,
            needles,
            measured,
            lines: lines.len(),
            touches,
            wood_prisms,
            wood_bare,
            wood_lines: wood.lines.len(),
            wood_touches,
        })
    }

    /// Each pixel's coverage by the lines, every line's opacity times
    /// `scale`: `1 − Π(1 − min(scale · c, 1))` over the lines touching it
    /// (row-major; 0 where a pixel is not measured). The strip's width
    /// stays the unscaled opacity (the scale changes a strip's mean length
    /// inside a pixel little).
    pub fn lines_at(&self, scale: f32) -> Vec<f32> {
        let mut log_clear = vec![0.0f32; self.needles.len()];
        for &(pixel, c) in &self.touches {
            log_clear[pixel as usize] += (-(scale * c).min(1.0)).ln_1p().max(-30.0);
        }
        log_clear.into_iter().map(|l| 1.0 - l.exp()).collect()
    }

    /// Summed coverage of the needles over the measured pixels, pixels.
    pub fn needle_total(&self) -> f32 {
        self.needles
            .iter()
            .zip(&self.measured)
            .filter(|(_, m)| **m)
            .map(|(n, _)| n)
            .sum()
    }

    /// Summed coverage of the lines at `scale` over the measured pixels,
    /// pixels.
    pub fn line_total(&self, scale: f32) -> f32 {
        self.lines_at(scale).iter().sum()
    }

    /// Mean per-pixel difference between the lines at `scale` and the
    /// needles, over the needles' summed coverage, on the measured pixels
    /// (`Σ|lines − needles| / Σ needles`; 0 for a view without coverage).
    pub fn pixel_error(&self, scale: f32) -> f32 {
        let total = self.needle_total();
        if total <= 0.0 {
            return 0.0;
        }
        let lines = self.lines_at(scale);
        lines
            .iter()
            .zip(&self.needles)
            .zip(&self.measured)
            .filter(|(_, m)| **m)
            .map(|((l, n), _)| (l - n).abs())
            .sum::<f32>()
            / total
    }

    /// The scale of every line's opacity at which the lines cover, in
    /// total, what the needles cover, clamped to `[MIN_LINE_SCALE,
    /// MAX_LINE_SCALE]` (1 for a view without coverage). The total grows
    /// with the scale; found by regula falsi (Illinois) in log scale.
    pub fn matching_scale(&self) -> f32 {
        let target = self.needle_total();
        if target <= 0.0 || self.touches.is_empty() {
            return 1.0;
        }
        matching(target, |scale| self.line_total(scale))
    }

    /// What the silhouettes of the wood lines nearest opacity node `node`
    /// (all of them with `None`) add to the needles' and the wood
    /// prisms', summed over the measured pixels, pixels.
    pub fn wood_target(&self, node: Option<usize>) -> f32 {
        self.wood_bare
            .iter()
            .enumerate()
            .filter(|(n, _)| node.is_none_or(|node| node == *n))
            .flat_map(|(_, bare)| bare.iter().zip(&self.measured))
            .filter(|(_, m)| **m)
            .map(|(b, _)| b)
            .sum()
    }

    /// What the wood lines nearest opacity node `node` (all of them with
    /// `None`), each node's lines' opacity times its scale in
    /// `wood_scales`, add to the needle lines at `needle_scale` and the
    /// wood prisms, summed over the measured pixels: `Σ (1 − L)·(1 − P)·(1
    /// − Π(1 − min(k·c, 1)))`, `L` the needle lines' coverage, `P` the
    /// prisms', `c` each wood line's (blending composes them as
    /// independent), pixels.
    pub fn wood_added(&self, needle_scale: f32, wood_scales: [f32; WOOD_OPACITY_NODES], node: Option<usize>) -> f32 {
        let lines = self.lines_at(needle_scale);
        self.wood_added_over(&lines, wood_scales, node)
    }

    fn wood_added_over(&self, lines: &[f32], wood_scales: [f32; WOOD_OPACITY_NODES], node: Option<usize>) -> f32 {
        self.wood_added_pixels(lines, wood_scales, node)
            .iter()
            .zip(&self.measured)
            .filter(|(_, m)| **m)
            .map(|(added, _)| added)
            .sum()
    }

    /// Per pixel, what the wood lines nearest opacity node `node` (all of
    /// them with `None`), scaled by `wood_scales`, add over the needle
    /// lines' coverage `lines` and the wood prisms: `(1 − L)·(1 − P)·(1 −
    /// Π(1 − min(k·c, 1)))`, the term [`Self::wood_added`] sums.
    fn wood_added_pixels(
        &self,
        lines: &[f32],
        wood_scales: [f32; WOOD_OPACITY_NODES],
        node: Option<usize>,
    ) -> Vec<f32> {
        let mut log_clear = vec![0.0f32; self.needles.len()];
        for &(pixel, c, line_node) in &self.wood_touches {
            if node.is_some_and(|n| n != line_node as usize) {
                continue;
            }
            let scale = wood_scales[line_node as usize];
            log_clear[pixel as usize] += (-(scale * c).min(1.0)).ln_1p().max(-30.0);
        }
        (0..self.needles.len())
            .map(|k| (1.0 - lines[k]) * (1.0 - self.wood_prisms[k]) * (1.0 - log_clear[k].exp()))
            .collect()
    }

    /// For each opacity node, the scale of the wood lines nearest it at
    /// which they add to the needle lines at `needle_scale` (and the
    /// prisms) what their silhouettes add to the needles' (and the
    /// prisms', [`Self::wood_target`]), in total, clamped to
    /// `[MIN_LINE_SCALE, MAX_LINE_SCALE]`; `None` for a node no line is
    /// near.
    pub fn matching_wood_scales(&self, needle_scale: f32) -> [Option<f32>; WOOD_OPACITY_NODES] {
        let lines = self.lines_at(needle_scale);
        std::array::from_fn(|node| {
            if !self.wood_touches.iter().any(|t| t.2 as usize == node) {
                return None;
            }
            Some(matching(self.wood_target(Some(node)), |scale| {
                self.wood_added_over(&lines, [scale; WOOD_OPACITY_NODES], Some(node))
            }))
        })
    }
}

/// The scale in `[MIN_LINE_SCALE, MAX_LINE_SCALE]` at which `total` (growing
/// with the scale) meets `target`, clamped to the range's ends; found by
/// regula falsi (Illinois) in log scale.
fn matching(target: f32, total: impl Fn(f32) -> f32) -> f32 {
    let miss = |log_scale: f32| total(log_scale.exp()) - target;
    let (mut a, mut b) = (MIN_LINE_SCALE.ln(), MAX_LINE_SCALE.ln());
    let (mut fa, mut fb) = (miss(a), miss(b));
    if fa >= 0.0 {
        return MIN_LINE_SCALE;
    }
    if fb <= 0.0 {
        return MAX_LINE_SCALE;
    }
    let tolerance = 1e-5 * target;
    let mut side = 0i8;
    for _ in 0..60 {
        let c = (a * fb - b * fa) / (fb - fa);
        let fc = miss(c);
        if fc.abs() <= tolerance || (b - a).abs() < 1e-6 {
            return c.exp();
        }
        if fc < 0.0 {
            a = c;
            fa = fc;
            if side == -1 {
                fb *= 0.5;
            }
            side = -1;
        } else {
            b = c;
            fb = fc;
            if side == 1 {
                fa *= 0.5;
            }
            side = 1;
        }
    }
    ((a + b) * 0.5).exp()
}

/// One line of a cut, as [`SideComposition`] composes it.
struct CutLine {
    /// One end.
    a: Vec3,
    /// The other end.
    b: Vec3,
    /// Its needles' summed side area over its length, metres: its
    /// area-preserving opacity at pixels of 1 m.
    area_per_length: f32,
}

/// The lines of `record`'s cut at spatial error `error` (original and
/// merged; a needle the cut draws as a prism counts as its original line)
/// that have a finite length and some needle area.
fn cut_lines(record: &LodRecord, error: f32) -> Vec<CutLine> {
    let cut = record.cut(error);
    cut.prisms
        .iter()
        .map(|&(i, _)| i)
        .chain(cut.original_lines.iter().copied())
        .chain(cut.merged_lines.iter().copied())
        .filter_map(|node| {
            let [(a, _), (b, _)] = record.node_ends(node);
            let area_per_length = record.node_needle_area(node) / a.distance(b).max(1e-12);
            (area_per_length > 0.0 && area_per_length.is_finite() && a.is_finite() && b.is_finite())
                .then_some(CutLine { a, b, area_per_length })
        })
        .collect()
}

/// Where `p` falls on the samples of a side view whose picture x and y
/// run along `right` and `up` and whose samples, `spacing` apart, span
/// `low` to `high` (picture metres; sample rows from `high.y` downwards).
fn side_sample(p: Vec3, [right, up]: [Vec3; 2], low: Vec2, high: Vec2, spacing: f32) -> Vec2 {
    Vec2::new((p.dot(right) - low.x) / spacing, (high.y - p.dot(up)) / spacing)
}

/// The wood of a cut, as [`SideComposition`] composes it.
struct CutWood {
    /// Segments drawn as prisms (opaque).
    prisms: Vec<WoodSegment>,
    /// Segments drawn as lines, their opacity at pixels of 1 m the sum of
    /// their end radii (their mean width).
    lines: Vec<CutLine>,
    /// The segments of `lines`, in order.
    line_segments: Vec<WoodSegment>,
}

/// `record`'s valid wood segments as the plugin draws them at spatial
/// error `error`: a prism where the error is under the segment's larger
/// diameter, a line from there to [`WOOD_LINE_FADE`] times it, nothing
/// past that.
fn cut_wood(record: &LodRecord, error: f32) -> CutWood {
    let mut wood = CutWood {
        prisms: Vec::new(),
        lines: Vec::new(),
        line_segments: Vec::new(),
    };
    for w in record.wood.iter().filter(|w| w.is_valid()) {
        let line_from = 2.0 * w.start_radius.max(w.end_radius);
        if error < line_from {
            wood.prisms.push(*w);
        } else if error < WOOD_LINE_FADE * line_from {
            wood.lines.push(CutLine {
                a: w.start,
                b: w.end,
                area_per_length: w.start_radius + w.end_radius,
            });
            wood.line_segments.push(*w);
        }
    }
    wood
}

/// The part of the segment from `a` to `b` inside the box from `low` to
/// `high` (Liang–Barsky), `None` where none is.
fn clip_to_box(a: Vec2, b: Vec2, low: Vec2, high: Vec2) -> Option<(Vec2, Vec2)> {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (p, q) in [
        (-d.x, a.x - low.x),
        (d.x, high.x - a.x),
        (-d.y, a.y - low.y),
        (d.y, high.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1 && t0.is_finite() && t1.is_finite()).then(|| (a + d * t0, a + d * t1))
}

/// The samples along one axis of a [`SideComposition`]: each sample's
/// pixel, and how many samples of the unbounded grid (the needles'
/// samples and the clear ones past their bounds) each pixel holds.
struct SampleAxis {
    /// Pixel of each of the needles' samples.
    pixel_of: Vec<u32>,
    /// Samples each pixel holds.
    held: Vec<u32>,
}

impl SampleAxis {
    /// `samples` samples whose `k`-th centre lies `offset + (k + ½) ·
    /// spacing` metres into a picture of `pixels` pixels of `pixel`
    /// metres (a sample in a pixel when its centre is).
    fn new(samples: u32, pixels: u32, offset: f32, pixel: f32, spacing: f32) -> Self {
        let pixel_at = |k: i64| ((offset + (k as f32 + 0.5) * spacing) / pixel).floor();
        let last = (pixels - 1) as f32;
        let pixel_of = (0..i64::from(samples))
            .map(|k| pixel_at(k).clamp(0.0, last) as u32)
            .collect();
        let mut held = vec![0u32; pixels as usize];
        let first = (-offset / spacing).floor() as i64 - 1;
        let end = ((pixels as f32 * pixel - offset) / spacing).ceil() as i64 + 1;
        for k in first..=end {
            let p = pixel_at(k);
            if (0.0..=last).contains(&p) {
                held[p as usize] += 1;
            }
        }
        Self { pixel_of, held }
    }

    /// Each pixel's run of samples, `(pixel, first, last)` (inclusive), in
    /// order: `pixel_of` never decreases along the axis.
    fn runs(&self) -> Vec<(u32, usize, usize)> {
        let mut runs: Vec<(u32, usize, usize)> = Vec::new();
        for (k, &pixel) in self.pixel_of.iter().enumerate() {
            match runs.last_mut() {
                Some((run_pixel, _, last)) if *run_pixel == pixel => *last = k,
                _ => runs.push((pixel, k, k)),
            }
        }
        runs
    }
}

/// A fixed pseudo-random 32 bits of a pixel index (SplitMix64's
/// finalizer).
fn pixel_hash(index: u64) -> u32 {
    let mut z = index.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    ((z ^ (z >> 31)) >> 32) as u32
}

/// Bounds of `record`'s valid needles' ends, `None` without any.
fn needle_bounds(record: &LodRecord) -> Option<(Vec3, Vec3)> {
    super::needle::bounds(
        record
            .needles
            .iter()
            .filter(|n| n.is_valid())
            .flat_map(|n| [n.base, n.tip]),
    )
}

/// Appends the unscaled coverage `opacity ·`
/// [`strip_pixel_coverage`](super::raster::strip_pixel_coverage) of the
/// strip from `a` to `b` (pixel units, `opacity` wide) of every pixel of a
/// `[width, height]` picture it touches that is `measured` (row-major, in
/// order). Each row visits only the columns within the strip's half
/// width of the segment's part within that half width of the row.
fn strip_touches(
    a: Vec2,
    b: Vec2,
    opacity: f32,
    [width, height]: [u32; 2],
    measured: &[bool],
    out: &mut Vec<(u32, f32)>,
) {
    // Every point of the strip lies within half its width of the segment
    // (a hundredth of a pixel more against rounding): a row or column
    // farther than that from the segment's part in it holds none.
    let reach = 0.5 * opacity + 0.01;
    let (y_lo, y_hi) = (a.y.min(b.y), a.y.max(b.y));
    let j0 = ((y_lo - reach).floor().max(0.0)) as u32;
    let j1 = ((y_hi + reach).floor().min(height as f32 - 1.0)).max(-1.0);
    if j1 < 0.0 {
        return;
    }
    let d = b - a;
    let length_sq = d.length_squared();
    let far = 0.5 * opacity + std::f32::consts::FRAC_1_SQRT_2 + 1e-3;
    let far_sq = far * far;
    let strip = StripInPixels::new(a.to_array(), b.to_array(), opacity);
    for j in j0..=j1 as u32 {
        let (x_lo, x_hi) = if d.y.abs() < 1e-6 {
            (a.x.min(b.x), a.x.max(b.x))
        } else {
            let t0 = ((j as f32 - reach - a.y) / d.y).clamp(0.0, 1.0);
            let t1 = ((j as f32 + 1.0 + reach - a.y) / d.y).clamp(0.0, 1.0);
            let (x0, x1) = (a.x + d.x * t0, a.x + d.x * t1);
            (x0.min(x1), x0.max(x1))
        };
        let i0 = ((x_lo - reach).floor().max(0.0)) as u32;
        let i1 = (x_hi + reach).floor().min(width as f32 - 1.0);
        if i1 < 0.0 {
            continue;
        }
        for i in i0..=i1 as u32 {
            if !measured[(j * width + i) as usize] {
                continue;
            }
            // The strip reaches no point of a square whose centre lies
            // farther than half its width and half the square's diagonal
            // from the segment.
            let centre = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
            let t = if length_sq > 0.0 {
                ((centre - a).dot(d) / length_sq).clamp(0.0, 1.0)
            } else {
                0.0
            };
            if centre.distance_squared(a + d * t) > far_sq {
                continue;
            }
            let g = strip.coverage([i as f32, j as f32]);
            if g > 0.0 {
                out.push((j * width + i, opacity * g));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::bake::{BakeOptions, bake};
    use crate::model::needle::{FoliageMaterial, Needle, TreeInput};
    use crate::model::raster::strip_pixel_coverage;
    use proptest::prelude::*;

    /// `layers` copies, 5 cm apart along z, of `count` horizontal needles
    /// 3 cm long at heights 8 cm apart, each its own group, turned by a
    /// golden angle: seen along z (azimuth 0) the layers lie exactly on
    /// one another; seen along x (azimuth 90°) side by side.
    fn needles_in_layers(count: usize, layers: usize) -> LodRecord {
        let mut needles = Vec::new();
        for layer in 0..layers {
            for k in 0..count {
                let angle = k as f32 * 2.399_963;
                let base = Vec3::new(0.0, 0.08 * k as f32, 0.05 * layer as f32);
                let tip = base + 0.03 * Vec3::new(angle.cos(), 0.0, angle.sin().abs() * 0.3);
                needles.push(Needle {
                    base,
                    tip,
                    radius: 5e-4,
                    normal: Vec3::Y,
                    group: (layer * count + k) as u32,
                });
            }
        }
        baked(needles, Vec::new())
    }

    /// `needles` and `wood` baked without an impostor or a calibration.
    fn baked(needles: Vec<Needle>, wood: Vec<WoodSegment>) -> LodRecord {
        let input = TreeInput {
            name: "test".into(),
            needles,
            wood,
            wood_mesh: Default::default(),
            material: FoliageMaterial::default(),
        };
        let options = BakeOptions {
            impostor: None,
            line_calibration: None,
            ..BakeOptions::default()
        };
        bake(&input, &options, &()).unwrap()
    }

    /// Two sleeves of twelve vertical needles 1.5 mm in radius 0.4 m
    /// long, standing 2 mm from the vertical axes through the origin and
    /// through (0.3, 0, 0.3), and a vertical twig 1 mm in radius and 0.4 m
    /// long, in segments of 5 cm: in the first sleeve (seen from any side
    /// its needles cover it) or, `apart`, on the axis through (0.15, 0,
    /// 0.15), where no needle lies in front of or behind it seen along −Z
    /// or −X (the calibration's two views).
    fn twig(apart: bool) -> LodRecord {
        let needles = (0..24)
            .map(|k| {
                let angle = std::f32::consts::TAU * (k % 12) as f32 / 12.0;
                let axis = if k < 12 { Vec3::ZERO } else { Vec3::new(0.3, 0.0, 0.3) };
                let base = axis + 0.002 * Vec3::new(angle.cos(), 0.0, angle.sin());
                Needle {
                    base,
                    tip: base + Vec3::Y * 0.4,
                    radius: 1.5e-3,
                    normal: Vec3::X,
                    group: k as u32,
                }
            })
            .collect();
        let axis = if apart { Vec3::new(0.15, 0.0, 0.15) } else { Vec3::ZERO };
        let wood = (0..8)
            .map(|k| WoodSegment {
                start: axis + Vec3::Y * 0.05 * k as f32,
                end: axis + Vec3::Y * 0.05 * (k + 1) as f32,
                start_radius: 1e-3,
                end_radius: 1e-3,
            })
            .collect();
        baked(needles, wood)
    }

    /// The wood's table is read bilinearly: in log size as the needles',
    /// and in log opacity between its nodes at 1/64, 1/16, 1/4 and 1,
    /// held past the ends (a NaN opacity takes the first node).
    #[test]
    fn wood_scales_are_bilinear_in_log_size_and_log_opacity() {
        let mut wood_scales = [[1.0; WOOD_OPACITY_NODES]; CALIBRATION_STEPS];
        for (step, row) in wood_scales.iter_mut().enumerate() {
            *row = [0.3, 0.5, 0.9, 1.2].map(|s| s + 0.05 * step as f32);
        }
        let table = LineCalibration {
            first_pixel: 0.01,
            last_pixel: 0.64,
            scales: [1.0; CALIBRATION_STEPS],
            wood_scales,
        };
        assert!(table.is_valid());
        let near = |a: f32, b: f32| (a - b).abs() < 1e-4;
        for (node, want) in [(1.0 / 64.0, 0.3), (1.0 / 16.0, 0.5), (0.25, 0.9), (1.0, 1.2)] {
            assert!(near(table.wood_scale_at(0.01, node), want));
        }
        // Half way in log opacity between 1/16 and 1/4, and half way in log
        // size between the third and fourth entries.
        assert!(near(table.wood_scale_at(0.01, 0.125), 0.7));
        let pixel = (table.pixel(2) * table.pixel(3)).sqrt();
        assert!(near(table.wood_scale_at(pixel, 0.125), 0.7 + 0.125));
        assert!(near(table.wood_scale_at(0.01, 1e-5), 0.3));
        assert!(near(table.wood_scale_at(0.01, f32::NAN), 0.3));
        assert!(near(table.wood_scale_at(10.0, 2.0), 1.2 + 0.35));
        assert!(near(table.wood_scale_at(f32::NAN, 1.0), 1.2));
        assert_eq!(wood_opacity_node(0.0), 0.0);
        assert_eq!(wood_opacity_node(f32::INFINITY), 3.0);
    }

    /// A twig hidden in a sleeve of needles from every side adds nothing
    /// to their silhouettes: its lines take the least scale wherever it is
    /// a line, and the table keeps 1 where it is a prism. The same twig
    /// standing apart adds what its line covers: its scale is not cut,
    /// 1.0–1.15 (its segments' lines meet in a pixel and blend there as
    /// if they fell independently, a few % short, as on the GPU, and the
    /// scale moves a line this wide, 0.3–0.7 of a pixel, less than its
    /// own size).
    #[test]
    fn wood_lines_add_to_the_needles_what_the_wood_adds() {
        let (hidden_twig, apart_twig) = (twig(false), twig(true));
        let hidden = calibrate_lines(&hidden_twig, &CalibrationOptions::default()).unwrap();
        let apart = calibrate_lines(&apart_twig, &CalibrationOptions::default()).unwrap();
        println!("hidden {hidden:?}\napart {apart:?}");
        for step in 0..CALIBRATION_STEPS {
            let pixel = hidden.pixel(step);
            let side = view(&hidden_twig, 0.0, pixel).unwrap();
            if side.wood_lines == 0 {
                assert_eq!(hidden.wood_scales[step], [1.0; WOOD_OPACITY_NODES], "{step}");
                continue;
            }
            let target = side.wood_target(None);
            assert!(target < 1e-3 * side.needle_total(), "{target}");
            assert_eq!(hidden.wood_scales[step], [MIN_LINE_SCALE; WOOD_OPACITY_NODES], "{step}");
        }
        assert!(hidden.wood_scales.contains(&[MIN_LINE_SCALE; WOOD_OPACITY_NODES]));
        for step in 0..CALIBRATION_STEPS {
            let row = apart.wood_scales[step];
            if cut_wood(&apart_twig, apart.pixel(step)).lines.is_empty() {
                assert_eq!(row, [1.0; WOOD_OPACITY_NODES]);
            } else {
                assert!(row.iter().all(|s| (1.0..1.15).contains(s)), "{apart:?}");
            }
        }
    }

    /// `record` seen from `azimuth_degrees` and `elevation_degrees` above
    /// the horizontal at pixels of `pixel` metres, its needles sampled as
    /// a calibration whose first size that is would sample them (up to
    /// 2²⁶ samples), on `max_pixels` pixels at most.
    fn side_at(
        record: &LodRecord,
        azimuth_degrees: f32,
        elevation_degrees: f32,
        pixel: f32,
        max_pixels: u64,
    ) -> Option<SideComposition> {
        let options = CalibrationOptions {
            max_samples: 1 << 26,
            max_pixels,
            ..CalibrationOptions::default()
        };
        let spacing = sample_spacing(record, &options, pixel)?;
        let needles = SideNeedles::tilted(
            record,
            azimuth_degrees.to_radians(),
            elevation_degrees.to_radians(),
            spacing,
        )?;
        SideComposition::new(record, &needles, pixel, &options)
    }

    /// [`side_at`] on the default pixels.
    fn tilted_view(
        record: &LodRecord,
        azimuth_degrees: f32,
        elevation_degrees: f32,
        pixel: f32,
    ) -> Option<SideComposition> {
        side_at(record, azimuth_degrees, elevation_degrees, pixel, default_max_pixels())
    }

    /// A tilted view turns the picture with the viewer: three layers of
    /// needles exactly behind one another seen level (they cover what one
    /// layer does) lie apart seen from 30° above or below (three times
    /// what one layer covers so). Elevations off a quarter turn give none.
    #[test]
    fn tilted_views_turn_the_picture_with_the_viewer() {
        let (one, three) = (needles_in_layers(6, 1), needles_in_layers(6, 3));
        let spacing = 2e-4;
        let covered = |record: &LodRecord, elevation: f32| {
            SideNeedles::tilted(record, 0.0, elevation.to_radians(), spacing)
                .unwrap()
                .bits
                .count_set() as f64
        };
        assert_eq!(covered(&three, 0.0), covered(&one, 0.0));
        assert_eq!(
            SideNeedles::new(&three, 0.0, spacing).unwrap().bits.count_set() as f64,
            covered(&three, 0.0)
        );
        for elevation in [30.0, -30.0] {
            let ratio = covered(&three, elevation) / covered(&one, elevation);
            assert!((ratio - 3.0).abs() < 0.03, "{elevation}°: {ratio}");
        }
        for elevation in [f32::NAN, 90.0, -90.0, f32::INFINITY] {
            assert!(SideNeedles::tilted(&three, 0.0, elevation.to_radians(), spacing).is_none());
        }
    }

    /// A level view sees a spruce's tiers edge on, where their needles
    /// hide each other most: on the shipped young Norway spruce at 6.33 cm
    /// pixels (12.22 m in `conifer eval --quick`), the scale at which its
    /// lines cover what its needles do is lowest seen level and rises by
    /// over 0.03 seen from 8° above or below and over 0.05 from 12°; the
    /// Scots pine's moves by under 0.01. Calibrated from ±11° as well
    /// (`elevation_degrees`), the spruce's table at that size rises by
    /// over 0.03, its finest size's by under 0.01.
    #[test]
    fn level_views_see_a_spruces_tiers_edge_on() {
        let pixel = 0.0633;
        let mean_scale = |record: &LodRecord, elevations: &[f32]| {
            let scales: Vec<f32> = elevations
                .iter()
                .flat_map(|&elevation| {
                    [0.0, 90.0].map(|azimuth| tilted_view(record, azimuth, elevation, pixel).unwrap().matching_scale())
                })
                .collect();
            scales.iter().sum::<f32>() / scales.len() as f32
        };
        let read = |tree: &str| {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("assets/trees/{tree}.conifer"));
            crate::model::read_record(&path).unwrap()
        };
        let spruce = read("norway-spruce");
        let level = mean_scale(&spruce, &[0.0]);
        let (eight, twelve) = (mean_scale(&spruce, &[8.0, -8.0]), mean_scale(&spruce, &[12.0, -12.0]));
        println!("norway-spruce: level {level:.3}, ±8° {eight:.3}, ±12° {twelve:.3}");
        assert!(eight > level + 0.03 && twelve > level + 0.05);
        let pine = read("scots-pine");
        let (level_pine, twelve_pine) = (mean_scale(&pine, &[0.0]), mean_scale(&pine, &[12.0, -12.0]));
        println!("scots-pine: level {level_pine:.3}, ±12° {twelve_pine:.3}");
        assert!((twelve_pine - level_pine).abs() < 0.01);

        let table = |elevation_degrees: f32| {
            let options = CalibrationOptions {
                elevation_degrees,
                ..CalibrationOptions::default()
            };
            calibrate_lines(&spruce, &options).unwrap()
        };
        let (flat, tilted) = (table(0.0), table(11.0));
        println!(
            "norway-spruce's table at {pixel} m: level {:.3}, ±11° {:.3}",
            flat.scale_at(pixel),
            tilted.scale_at(pixel)
        );
        assert!(tilted.scale_at(pixel) > flat.scale_at(pixel) + 0.03);
        assert!((tilted.scales[0] - flat.scales[0]).abs() < 0.01);
    }

    fn view(record: &LodRecord, azimuth_degrees: f32, pixel: f32) -> Option<SideComposition> {
        tilted_view(record, azimuth_degrees, 0.0, pixel)
    }

    /// What the end caps of `record`'s needles (seen from `azimuth_degrees`,
    /// at their slant) add to their strips, as a share of the strips' area.
    fn cap_share(record: &LodRecord, azimuth_degrees: f32) -> f32 {
        let [_, _, toward] = view_axes(azimuth_degrees.to_radians(), 0.0);
        let (mut strips, mut caps) = (0.0, 0.0);
        for n in &record.needles {
            let axis = n.tip - n.base;
            let across = (axis - toward * axis.dot(toward)).length();
            strips += 2.0 * n.radius * across;
            caps += std::f32::consts::PI * n.radius * n.radius * axis.normalize().dot(toward).abs();
        }
        caps / strips
    }

    /// Needles that never overlap in any side view: the lines cover what
    /// the needles' strips cover, and the scale adds what the strips lack,
    /// the prisms' end caps at their slant (a few per cent: the needles lie
    /// at every angle to the view, some end on); the sampled needle coverage
    /// is their strips' and caps' area.
    #[test]
    fn lines_of_needles_apart_need_no_scale_but_their_caps() {
        let record = needles_in_layers(40, 1);
        let table = calibrate_lines(&record, &CalibrationOptions::default()).unwrap();
        assert!(table.is_valid(), "{table:?}");
        // Where the cut is every needle's own line.
        let merged_from = record.part_ranges().merged_lines.unwrap().min;
        let originals = (0..CALIBRATION_STEPS).filter(|&k| table.pixel(k) < merged_from);
        assert!(originals.clone().count() >= 2, "{table:?}");
        let shares: Vec<f32> = (0..36).map(|k| cap_share(&record, 5.0 * k as f32)).collect();
        let (least, most) = shares
            .iter()
            .fold((f32::INFINITY, 0.0f32), |(l, m), &s| (l.min(s), m.max(s)));
        assert!(least > 0.01 && most < 0.2, "{least} .. {most}");
        for k in originals {
            let scale = table.scales[k];
            assert!(
                (1.0 + least - 0.02..1.0 + most + 0.02).contains(&scale),
                "step {k} ({} m): {scale}, caps {least} .. {most}",
                table.pixel(k)
            );
        }
        // Seen from the front, every needle's strip (a shorter projection
        // of its side area) and caps.
        let pixel = 0.004;
        let strips: f32 = record
            .needles
            .iter()
            .map(|n| 2.0 * n.radius * Vec2::new(n.tip.x - n.base.x, n.tip.y - n.base.y).length())
            .sum();
        let area = strips * (1.0 + cap_share(&record, 0.0)) / (pixel * pixel);
        let front = view(&record, 0.0, pixel).unwrap();
        assert!(
            (front.needle_total() / area - 1.0).abs() < 0.02,
            "{} vs {area}",
            front.needle_total()
        );
        for azimuth in [0.0, 90.0, 180.0, 270.0] {
            let side = view(&record, azimuth, pixel).unwrap();
            let ratio = side.line_total(1.0) * (1.0 + cap_share(&record, azimuth)) / side.needle_total();
            assert!((ratio - 1.0).abs() < 0.01, "{azimuth}°: {ratio}");
        }
    }

    /// Three layers seen exactly on one another: blended as independent,
    /// their lines cover more than twice what the needles do, and the
    /// scale that matches the totals is about a third; seen side by side
    /// they need none but their caps'.
    #[test]
    fn lines_of_needles_on_one_another_are_scaled_down() {
        let record = needles_in_layers(40, 3);
        let pixel = 0.004;
        let stacked = view(&record, 0.0, pixel).unwrap();
        // Lines a quarter pixel wide: 1 − (1 − ¼)³ = 2.31 times a layer's.
        let before = stacked.line_total(1.0) / stacked.needle_total();
        // (a little more: a line crossing a pixel's corner covers it less).
        assert!((2.3..2.45).contains(&before), "{before}");
        let scale = stacked.matching_scale();
        assert!((0.3..0.42).contains(&scale), "{scale}");
        let after = stacked.line_total(scale) / stacked.needle_total();
        assert!((after - 1.0).abs() < 1e-3, "{after}");
        assert!(stacked.pixel_error(scale) < 0.5 * stacked.pixel_error(1.0));
        // Side by side, what the caps add (here, many needles end on).
        let apart = view(&record, 90.0, pixel).unwrap();
        let caps = cap_share(&record, 90.0);
        assert!(
            (apart.matching_scale() / (1.0 + caps) - 1.0).abs() < 0.05,
            "{} (caps {caps})",
            apart.matching_scale()
        );
    }

    /// The shipped young Norway spruce (40,000 needles clumped in shoots
    /// and branches):
    /// the calibrated scale falls as the pixel grows, and at a view and
    /// pixel sizes it was not calibrated at, the table brings the lines'
    /// total to within 3 % of the needles' (uncalibrated they over-cover
    /// by more) and lowers the per-pixel error.
    #[test]
    fn a_young_spruces_table_holds_between_its_views() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/norway-spruce.conifer");
        let record = crate::model::read_record(&path).unwrap();
        let table = calibrate_lines(&record, &CalibrationOptions::default()).unwrap();
        println!("table {table:?}");
        assert!(table.is_valid());
        // Up to the 4 % its short needles' end caps add to their strips.
        assert!(table.scales.iter().all(|&s| s <= 1.06), "{table:?}");
        assert!(table.scales[7] < table.scales[0] - 0.05, "{table:?}");
        for (step, azimuth) in [(3.5, 45.0), (4.5, 135.0), (5.5, 300.0), (6.5, 20.0)] {
            let pixel = table.first_pixel * (table.last_pixel / table.first_pixel).powf(step / 7.0);
            let side = view(&record, azimuth, pixel).unwrap();
            let scale = table.scale_at(pixel);
            let (before, after) = (
                side.line_total(1.0) / side.needle_total(),
                side.line_total(scale) / side.needle_total(),
            );
            let (error_before, error_after) = (side.pixel_error(1.0), side.pixel_error(scale));
            println!(
                "{azimuth}°, {pixel:.4} m: scale {scale:.3}, total {before:.3} -> {after:.3}, per-pixel error {error_before:.3} -> {error_after:.3}"
            );
            assert!((after - 1.0).abs() < 0.03, "{after}");
            assert!(before > 1.03, "{before}");
            assert!(error_after < error_before);
        }
    }

    /// The shipped young trees' wood lines sit inside their needles: drawn
    /// at their area's opacity they add to the needle lines more than the
    /// wood adds to the needles' silhouettes, and the table's wood scales
    /// (below 1 for the thin lines, twigs) bring what they add to within
    /// 10 % and the coverage of the needles and the wood lines together to
    /// within 2 % of the silhouettes' at views and sizes the table was
    /// not calibrated at (from 5–12 % over on the spruce).
    #[test]
    fn young_trees_wood_lines_add_what_their_wood_adds() {
        for tree in ["norway-spruce", "scots-pine"] {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("assets/trees/{tree}.conifer"));
            let record = crate::model::read_record(&path).unwrap();
            let table = calibrate_lines(&record, &CalibrationOptions::default()).unwrap();
            println!("{tree}: wood scales {:?}", table.wood_scales);
            assert!(table.is_valid());
            for (pixel, azimuth) in [(0.0633, 0.0), (0.0633, 60.0), (0.138, 135.0), (0.03, 300.0)] {
                let side = view(&record, azimuth, pixel).unwrap();
                let scale = table.scale_at(pixel);
                // Each node's scale at this size.
                let wood = std::array::from_fn(|node| table.wood_scale_at(pixel, 4f32.powi(node as i32 - 3)));
                let lines: f32 = side
                    .lines_at(scale)
                    .iter()
                    .zip(&side.measured)
                    .filter(|(_, m)| **m)
                    .map(|(v, _)| v)
                    .sum();
                let (target, unit) = (side.wood_target(None), [1.0; WOOD_OPACITY_NODES]);
                let silhouettes = side.needle_total() + target;
                let (added_before, added_after) =
                    (side.wood_added(scale, unit, None), side.wood_added(scale, wood, None));
                let (before, after) = (
                    (lines + added_before) / silhouettes,
                    (lines + added_after) / silhouettes,
                );
                println!(
                    "{tree} {azimuth}°, {pixel} m: {} wood lines, scales {wood:.3?}, added over the wood's {:.3} -> {:.3}, needles and wood over their silhouettes' {before:.3} -> {after:.3}",
                    side.wood_lines,
                    added_before / target,
                    added_after / target,
                );
                assert!(side.wood_lines > 0);
                assert!(wood[0] < 1.0, "{wood:?}");
                assert!((added_after / target - 1.0).abs() < 0.1, "{}", added_after / target);
                assert!(before > 1.01, "{before}");
                assert!((after - 1.0).abs() < 0.02, "{after}");
                assert!((after - 1.0).abs() < (before - 1.0).abs(), "{after} {before}");
                if tree == "norway-spruce" {
                    assert!(before > 1.04, "{before}");
                }
            }
        }
    }

    /// A picture of more than `max_pixels` pixels measures a subset of
    /// about that many, and the scale it finds is the whole picture's: on
    /// the shipped young spruce at its first size (0.5 M pixels), within
    /// 1 % from 2¹⁶ and within 3 % from 2¹²; the view from the opposite
    /// side (the mirror image) finds the same scale within 0.5 %.
    #[test]
    fn a_subset_of_pixels_finds_the_whole_pictures_scale() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/norway-spruce.conifer");
        let record = crate::model::read_record(&path).unwrap();
        let (pixel, _) = calibration_pixels(&record, &CalibrationOptions::default()).unwrap();
        let whole = side_at(&record, 30.0, 0.0, pixel, u64::MAX).unwrap();
        let pixels = whole.needles.len();
        assert!(pixels > 1 << 18, "{pixels}");
        assert!(whole.measured.iter().all(|&m| m));
        let exact = whole.matching_scale();
        for (most, within) in [(1u64 << 16, 0.01), (1 << 12, 0.03)] {
            let subset = side_at(&record, 30.0, 0.0, pixel, most).unwrap();
            let measured = subset.measured.iter().filter(|&&m| m).count() as f64;
            assert!((measured / most as f64 - 1.0).abs() < 0.1, "{measured} of {most}");
            let scale = subset.matching_scale();
            println!("{most} pixels: scale {scale:.4} against {exact:.4} from {pixels}");
            assert!((scale / exact - 1.0).abs() < within, "{scale} vs {exact}");
        }
        let mirrored = side_at(&record, 210.0, 0.0, pixel, u64::MAX).unwrap().matching_scale();
        assert!((mirrored / exact - 1.0).abs() < 0.005, "{mirrored} vs {exact}");
    }

    /// Bad input gets no table or no view, never a panic.
    #[test]
    fn bad_input_gets_none() {
        let record = needles_in_layers(4, 1);
        let nan = CalibrationOptions {
            pixel_error: f32::NAN,
            ..CalibrationOptions::default()
        };
        assert!(calibrate_lines(&record, &nan).is_none());
        assert!(view(&record, 0.0, 0.0).is_none());
        assert!(view(&record, 0.0, f32::INFINITY).is_none());
        for spacing in [0.0, -1.0, f32::NAN, f32::INFINITY, 1e-9] {
            assert!(SideNeedles::new(&record, 0.0, spacing).is_none(), "{spacing}");
        }
        let needles = SideNeedles::new(&record, 0.0, 0.001).unwrap();
        let options = CalibrationOptions::default();
        // Pixels smaller than a sample, or not finite, or a NaN pixel error.
        for pixel in [0.0005, f32::NAN, f32::INFINITY] {
            assert!(
                SideComposition::new(&record, &needles, pixel, &options).is_none(),
                "{pixel}"
            );
        }
        assert!(SideComposition::new(&record, &needles, 0.01, &nan).is_none());
        let valid = view(&record, 0.0, 0.01).unwrap();
        assert!(valid.line_total(1.0) > 0.0 && valid.needle_total() > 0.0);
        // A record without valid needles has nothing to sample.
        let mut invalid = record.clone();
        for needle in &mut invalid.needles {
            needle.radius = f32::NAN;
        }
        assert!(SideNeedles::new(&invalid, 0.0, 0.001).is_none());
        assert!(calibrate_lines(&invalid, &options).is_none());
    }

    proptest! {
        /// Every pixel holds the samples whose centres it holds: ⌊s/σ⌋ or
        /// ⌈s/σ⌉ of them (s the pixel, σ the spacing), each sample is
        /// counted in the pixel it is assigned to, and all of them in the
        /// picture are counted once.
        #[test]
        fn sample_axes_count_every_sample_in_its_pixel(
            spacing in 0.001f32..0.01,
            per_pixel in 1.0f32..40.0,
            offset in 0.0f32..0.5,
            pixels in 1u32..60,
        ) {
            let pixel = spacing * per_pixel;
            let samples = ((pixels as f32 * pixel - offset) / spacing).max(0.0) as u32;
            let axis = SampleAxis::new(samples, pixels, offset, pixel, spacing);
            let (fewest, most) = ((pixel / spacing).floor() as u32, (pixel / spacing).ceil() as u32);
            for (p, &held) in axis.held.iter().enumerate() {
                prop_assert!(held + 1 >= fewest && held <= most + 1, "pixel {}: {} not near [{}, {}]", p, held, fewest, most);
            }
            let inside = (-1000i64..100_000)
                .filter(|&k| (0.0..pixels as f32 * pixel).contains(&(offset + (k as f32 + 0.5) * spacing)))
                .count() as u32;
            prop_assert!(axis.held.iter().sum::<u32>().abs_diff(inside) <= 1);
            for (k, &p) in axis.pixel_of.iter().enumerate() {
                let centre = offset + (k as f32 + 0.5) * spacing;
                prop_assert!((centre / pixel - p as f32) > -1e-3 && (centre / pixel - p as f32) < 1.0 + 1e-3);
            }
            // The runs hold every sample once, in order, each in its pixel.
            let mut next = 0;
            for (p, first, last) in axis.runs() {
                prop_assert_eq!(first, next);
                prop_assert!(first <= last);
                prop_assert!(axis.pixel_of[first..=last].iter().all(|&q| q == p));
                next = last + 1;
            }
            prop_assert_eq!(next, axis.pixel_of.len());
        }

        /// A strip's touches are every pixel of the picture it covers
        /// (`strip_pixel_coverage` above 0, tried on every pixel), each
        /// once, in row-major order, with its coverage times the opacity:
        /// the rows and columns it skips hold none of it.
        #[test]
        fn strip_touches_find_every_pixel_the_strip_covers(
            ax in -2.0f32..14.0, ay in -2.0f32..10.0, bx in -2.0f32..14.0, by in -2.0f32..10.0,
            opacity in 0.01f32..1.0, snap in proptest::bool::ANY, seed in 0u64..u64::MAX,
        ) {
            let (width, height) = (12u32, 8u32);
            // Ends on pixel edges too, where a strip runs along a side.
            let at = |v: f32| if snap { v.round() } else { v };
            let (a, b) = (Vec2::new(at(ax), at(ay)), Vec2::new(at(bx), at(by)));
            let measured: Vec<bool> = (0..(width * height) as u64).map(|k| !pixel_hash(k ^ seed).is_multiple_of(4)).collect();
            let mut touches = Vec::new();
            strip_touches(a, b, opacity, [width, height], &measured, &mut touches);
            let expected: Vec<(u32, f32)> = (0..height)
                .flat_map(|j| (0..width).map(move |i| (i, j)))
                .filter(|&(i, j)| measured[(j * width + i) as usize])
                .filter_map(|(i, j)| {
                    let g = strip_pixel_coverage(a.to_array(), b.to_array(), opacity, [i as f32, j as f32]);
                    (g > 0.0).then_some((j * width + i, opacity * g))
                })
                .collect();
            prop_assert_eq!(touches, expected);
        }

        /// The table is interpolated in log size: each entry at its own
        /// size, the ends held beyond, every value between its neighbours.
        #[test]
        fn scale_at_interpolates_the_table_in_log_size(
            first in 0.001f32..0.1,
            ratio in 1.5f32..200.0,
            scales in proptest::array::uniform8(MIN_LINE_SCALE..MAX_LINE_SCALE),
            at in 0.0f32..1.0,
        ) {
            let table = LineCalibration {
                first_pixel: first,
                last_pixel: first * ratio,
                scales,
                wood_scales: scales.map(|s| [MIN_LINE_SCALE + MAX_LINE_SCALE - s; WOOD_OPACITY_NODES]),
            };
            prop_assert!(table.is_valid());
            for (k, &scale) in scales.iter().enumerate() {
                prop_assert!((table.scale_at(table.pixel(k)) - scale).abs() < 1e-3 * scale.max(1.0));
            }
            prop_assert_eq!(table.scale_at(first * 0.5), scales[0]);
            prop_assert_eq!(table.scale_at(f32::NAN), scales[0]);
            prop_assert_eq!(table.scale_at(0.0), scales[0]);
            prop_assert_eq!(table.scale_at(first * ratio * 2.0), scales[7]);
            prop_assert_eq!(table.scale_at(f32::INFINITY), scales[7]);
            let t = at * (CALIBRATION_STEPS - 1) as f32;
            let pixel = first * ratio.powf(at);
            let k = (t as usize).min(CALIBRATION_STEPS - 2);
            let (lo, hi) = (scales[k].min(scales[k + 1]), scales[k].max(scales[k + 1]));
            let s = table.scale_at(pixel);
            prop_assert!(s >= lo - 1e-4 && s <= hi + 1e-4, "{} not in [{}, {}]", s, lo, hi);
            // The wood's table is read the same way.
            let mirrored = MIN_LINE_SCALE + MAX_LINE_SCALE - s;
            prop_assert!((table.wood_scale_at(pixel, at) - mirrored).abs() < 1e-4 * mirrored.max(1.0));
        }
    }

    /// Where the wood lines add more than the wood's silhouettes: split
    /// by how much of each pixel the needles' silhouettes cover, on the
    /// shipped young spruce at 6.33 cm pixels (12.22 m in `conifer
    /// eval`'s quick pictures), unscaled. The thick wood (the opacity-1
    /// node: the trunk and branch bases) adds about what its silhouettes add,
    /// in the open as among the needles (5 % over, which its table entry
    /// of about 0.95 takes back); the twigs (node 1/16) add over twice
    /// theirs among the needles, where they sit inside their shoots.
    #[test]
    fn thick_wood_lines_add_their_silhouettes_and_twigs_inside_needles_add_more() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/norway-spruce.conifer");
        let record = crate::model::read_record(&path).unwrap();
        let table = calibrate_lines(&record, &CalibrationOptions::default()).unwrap();
        for azimuth in [0.0, 90.0] {
            let pixel = 0.0633;
            let side = view(&record, azimuth, pixel).unwrap();
            let lines = side.lines_at(table.scale_at(pixel));
            // Per opacity node, [open, partly covered, covered] pixels:
            // (what the lines add, what the silhouettes add).
            let split = |node: usize| {
                let added = side.wood_added_pixels(&lines, [1.0; WOOD_OPACITY_NODES], Some(node));
                let mut classes = [(0.0f32, 0.0f32); 3];
                for k in (0..side.needles.len()).filter(|&k| side.measured[k]) {
                    let class = match side.needles[k] {
                        n if n < 0.1 => 0,
                        n if n < 0.9 => 1,
                        _ => 2,
                    };
                    classes[class].0 += added[k];
                    classes[class].1 += side.wood_bare[node][k];
                }
                classes
            };
            let (thick, twigs) = (split(WOOD_OPACITY_NODES - 1), split(1));
            println!(
                "{azimuth}°: opacity 1 (added, silhouettes) open / partly / covered {thick:.1?}; 1/16 {twigs:.1?}"
            );
            for (added, silhouettes) in &thick[..2] {
                assert!(*silhouettes > 2.0, "{thick:?}");
                assert!((added / silhouettes - 1.0).abs() < 0.1, "{thick:?}");
            }
            assert!(twigs[1].0 > 2.0 * twigs[1].1, "{twigs:?}");
            assert!(thick[2].0 + twigs[2].0 < 0.5, "{thick:?} {twigs:?}");
        }
    }
}
