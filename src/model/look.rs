//! How a whole tree looks from afar, free of Bevy: how much of its crown
//! one can see through.
//!
//! ## Crown see-through
//!
//! [`crown_see_through`] is `1 −` the mean coverage over the crown's
//! *outline*, defined on a coverage picture (alpha of the tree rendered
//! alone) and the crown's box in it (the screen box of the needles, so the
//! bare trunk below the crown is left out):
//!
//! 1. The *silhouette*: the box's pixels with coverage of at least 5 %
//!    ([`SILHOUETTE_COVERAGE`]).
//! 2. Closed at 1/16 of the crown's height ([`OUTLINE_CELLS`]): dilated,
//!    then eroded, by a square of `c = max(1, round(h / 16))` pixels, `h`
//!    the box's height. Gaps narrower than `c` (between shoots, branches,
//!    tiers) are filled; the outline's edge stays on the silhouette's.
//! 3. Filled across: in each row, every pixel from the leftmost to the
//!    rightmost of the closed silhouette.
//! 4. The see-through is `1 −` the mean coverage of the outline's pixels.
//!
//! `conifer eval` applies it to the supersampled reference; [`side_coverage`]
//! renders the picture on the CPU instead (orthographic, every needle and
//! wood segment rasterized at a fraction of its width), which the generator
//! is tuned and tested with.

use super::needle::{Needle, WoodSegment};
use glam::{Vec2, Vec3};

/// The outline's resolution: gaps narrower than the crown's height over
/// this are closed.
pub const OUTLINE_CELLS: u32 = 16;

/// Coverage from which a pixel is part of the crown's silhouette.
pub const SILHOUETTE_COVERAGE: f32 = 0.5;

/// A picture of coverage in `[0, 1]`, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct CoverageGrid {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width × height` coverages.
    pub coverage: Vec<f32>,
}

impl CoverageGrid {
    /// A grid of `width × height` zeros.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            coverage: vec![0.0; width as usize * height as usize],
        }
    }

    /// Coverage at column `x`, row `y` (0 outside).
    pub fn at(&self, x: u32, y: u32) -> f32 {
        if x < self.width && y < self.height {
            self.coverage[(y * self.width + x) as usize]
        } else {
            0.0
        }
    }
}

/// The crown's box in a picture: columns `x0..x1`, rows `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CrownBox {
    /// First column.
    pub x0: u32,
    /// First row (the crown's top).
    pub y0: u32,
    /// One past the last column.
    pub x1: u32,
    /// One past the last row (the crown's base).
    pub y1: u32,
}

/// What [`crown_see_through`] measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeeThrough {
    /// `1 −` mean coverage over the outline, in `[0, 1]`.
    pub see_through: f64,
    /// Pixels in the outline.
    pub outline_pixels: u64,
    /// Side of the closing square, pixels.
    pub closing: u32,
}

/// The crown's see-through (module docs): `None` when the box is empty or
/// holds no silhouette pixel.
pub fn crown_see_through(grid: &CoverageGrid, crown: CrownBox) -> Option<SeeThrough> {
    let (x0, x1) = (crown.x0.min(grid.width), crown.x1.min(grid.width));
    let (y0, y1) = (crown.y0.min(grid.height), crown.y1.min(grid.height));
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let closing = ((y1 - y0) as f32 / OUTLINE_CELLS as f32).round().max(1.0) as usize;
    // The box with a margin of `closing` on every side, so the dilation
    // has room; outside it nothing is silhouette.
    let margin = closing;
    let (width, height) = ((x1 - x0) as usize + 2 * margin, (y1 - y0) as usize + 2 * margin);
    let mut mask = vec![false; width * height];
    for y in y0..y1 {
        for x in x0..x1 {
            let index = (y - y0) as usize * width + (x - x0) as usize + margin * width + margin;
            mask[index] = grid.at(x, y) >= SILHOUETTE_COVERAGE;
        }
    }
    if !mask.iter().any(|&m| m) {
        return None;
    }
    let dilated = square_filter(&mask, width, height, closing, true);
    let closed = square_filter(&dilated, width, height, closing, false);
    let (mut covered, mut pixels) = (0.0f64, 0u64);
    for row in 0..height {
        let line = &closed[row * width..(row + 1) * width];
        let (Some(first), Some(last)) = (line.iter().position(|&m| m), line.iter().rposition(|&m| m)) else {
            continue;
        };
        for column in first..=last {
            let (x, y) = (column as i64 - margin as i64, row as i64 - margin as i64);
            if x >= 0 && y >= 0 {
                covered += f64::from(grid.at(x0 + x as u32, y0 + y as u32).clamp(0.0, 1.0));
            }
            pixels += 1;
        }
    }
    Some(SeeThrough {
        see_through: (1.0 - covered / pixels as f64).clamp(0.0, 1.0),
        outline_pixels: pixels,
        closing: closing as u32,
    })
}

/// `mask` dilated (`grow`) or eroded by a `side × side` square: a pixel is
/// set when any (dilation) or every (erosion) pixel of the square around it
/// is; outside the mask counts as unset. Separable: rows, then columns.
fn square_filter(mask: &[bool], width: usize, height: usize, side: usize, grow: bool) -> Vec<bool> {
    // The erosion's window is the dilation's reflected, so that the closing
    // of a shape is the shape itself when it has no gaps (even sides too).
    let (before, after) = if grow {
        ((side - 1) / 2, side / 2)
    } else {
        (side / 2, (side - 1) / 2)
    };
    let pass = |input: &[bool], length: usize, lines: usize, at: &dyn Fn(usize, usize) -> usize| {
        let mut output = vec![false; input.len()];
        for line in 0..lines {
            for i in 0..length {
                let lo = i.checked_sub(before);
                let hi = i + after;
                let window_inside = lo.is_some() && hi < length;
                let (lo, hi) = (lo.unwrap_or(0), hi.min(length - 1));
                let mut window = (lo..=hi).map(|j| input[at(line, j)]);
                output[at(line, i)] = if grow {
                    window.any(|m| m)
                } else {
                    window_inside && window.all(|m| m)
                };
            }
        }
        output
    };
    let rows = pass(mask, width, height, &|row, x| row * width + x);
    pass(&rows, height, width, &|column, y| y * width + column)
}

/// A side view for [`side_coverage`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SideView {
    /// Azimuth of the viewing direction about +Y, radians (0 looks along −Z).
    pub azimuth: f32,
    /// Side of a picture pixel, metres (at 100 m with a 45° field of view
    /// over 256 rows: 0.32 m).
    pub pixel: f32,
    /// Samples per pixel along each axis; `0` picks enough for the
    /// thinnest needle to be about one sample wide (at most 256).
    pub samples: u32,
}

impl SideView {
    /// The view `conifer eval` takes at `distance` metres with a vertical
    /// field of view `fov_y` (radians) over `rows` rows, from the front.
    pub fn like_eval(distance: f32, fov_y: f32, rows: u32) -> Self {
        Self {
            azimuth: 0.0,
            pixel: 2.0 * distance * (0.5 * fov_y).tan() / rows.max(1) as f32,
            samples: 0,
        }
    }
}

/// A picture made by [`side_coverage`], with the crown's box in it.
#[derive(Clone, Debug, PartialEq)]
pub struct SidePicture {
    /// Coverage of each pixel.
    pub grid: CoverageGrid,
    /// The needles' box.
    pub crown: CrownBox,
    /// Samples per pixel along each axis that were taken.
    pub samples: u32,
}

/// How a piece stamped on [`SampleBits`] ends past its two end points.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PieceEnds {
    /// Cut square across its axis at both ends: a line's strip.
    Flat,
    /// A half disc of the end's half width past each end: a wood segment,
    /// which meets its neighbours.
    Round,
    /// The end caps of a capped cylinder (a needle's prism) seen at a
    /// slant: past each end, a half ellipse of the end's half width across
    /// the axis and `slant` times it along, the end's disc seen from a view
    /// whose cosine with the cylinder's axis is `slant` (0 side on, where
    /// the caps add nothing, 1 end on). Leaving them out under-counts a
    /// crown of short needles: seen from the front at 12 m, the young
    /// Lawson cypress's scale leaves cover 7.4 % more pixels with their
    /// caps, the young Norway spruce's needles 0.7 %
    /// (`tests/reference_silhouettes.rs`).
    Capped {
        /// `|cos|` of the angle between the axis and the view, in `[0, 1]`.
        slant: f32,
    },
}

impl PieceEnds {
    /// The caps of a cylinder along `axis` seen along `view` (neither
    /// need be unit; a zero or non-finite one gives flat ends).
    pub fn of_cylinder(axis: Vec3, view: Vec3) -> Self {
        let slant = axis.normalize_or_zero().dot(view.normalize_or_zero()).abs();
        Self::Capped {
            slant: if slant.is_finite() { slant.min(1.0) } else { 0.0 },
        }
    }

    /// How far past each end the piece reaches, as a share of the end's
    /// half width: 0 flat, 1 round.
    fn reach(self) -> f32 {
        match self {
            Self::Flat => 0.0,
            Self::Round => 1.0,
            Self::Capped { slant } if slant.is_nan() => 0.0,
            Self::Capped { slant } => slant.clamp(0.0, 1.0),
        }
    }
}

/// Binary samples over a picture, one bit each: sample `(i, j)` has its
/// centre at `(i + ½, j + ½)` in sample units (`x` right, `y` down).
#[derive(Clone, Debug, PartialEq)]
pub struct SampleBits {
    /// Samples across.
    pub width: u32,
    /// Samples down.
    pub height: u32,
    bits: Vec<u64>,
}

impl SampleBits {
    /// `width × height` samples, none set.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            bits: vec![0; (width as usize * height as usize).div_ceil(64)],
        }
    }

    /// Whether sample `(i, j)` is set (`false` outside).
    pub fn get(&self, i: u32, j: u32) -> bool {
        if i >= self.width || j >= self.height {
            return false;
        }
        self.is_set(j as usize * self.width as usize + i as usize)
    }

    /// Sets every sample whose centre lies in the piece from `a` to `b`
    /// (see [`SampleBits::stamp_each`]).
    pub fn stamp(&mut self, a: Vec2, b: Vec2, ra: f32, rb: f32, ends: PieceEnds) {
        self.stamp_each(a, b, ra, rb, ends, |_, _| {});
    }

    /// Sets sample `index` (row-major).
    pub fn set(&mut self, index: usize) {
        self.bits[index / 64] |= 1 << (index % 64);
    }

    /// Whether sample `index` (row-major) is set.
    pub fn is_set(&self, index: usize) -> bool {
        self.bits[index / 64] & (1 << (index % 64)) != 0
    }

    /// The samples set in `self` or in `other`; `None` where the two are
    /// not of one size.
    pub fn union(&self, other: &Self) -> Option<Self> {
        ((self.width, self.height) == (other.width, other.height)).then(|| Self {
            width: self.width,
            height: self.height,
            bits: self.bits.iter().zip(&other.bits).map(|(a, b)| a | b).collect(),
        })
    }

    /// The samples set in `self` and not in `other`; `None` where the two
    /// are not of one size.
    pub fn minus(&self, other: &Self) -> Option<Self> {
        ((self.width, self.height) == (other.width, other.height)).then(|| Self {
            width: self.width,
            height: self.height,
            bits: self.bits.iter().zip(&other.bits).map(|(a, b)| a & !b).collect(),
        })
    }

    /// How many samples are set.
    pub fn count_set(&self) -> u64 {
        self.bits.iter().map(|word| u64::from(word.count_ones())).sum()
    }

    /// Calls `f(index)` for every set sample, in row-major order.
    pub fn for_each_set(&self, mut f: impl FnMut(usize)) {
        for (word, &bits) in self.bits.iter().enumerate() {
            let mut rest = bits;
            while rest != 0 {
                f(word * 64 + rest.trailing_zeros() as usize);
                rest &= rest - 1;
            }
        }
    }

    /// Sets every sample whose centre lies in the piece from `a` to `b`
    /// (sample units) whose half width runs from `ra` at `a` to `rb` at
    /// `b`, and calls `f(index, t)` for each (`index` row-major, `t` in
    /// `[0, 1]` where along the axis it lies): within that half width of
    /// the axis between its ends, and past each end within the end's shape
    /// ([`PieceEnds`]). Samples outside the picture and non-finite pieces
    /// are skipped.
    pub fn stamp_each(&mut self, a: Vec2, b: Vec2, ra: f32, rb: f32, ends: PieceEnds, mut f: impl FnMut(usize, f32)) {
        let bits = &mut self.bits;
        each_sample_in([self.width, self.height], a, b, ra, rb, ends, |index, t| {
            bits[index / 64] |= 1 << (index % 64);
            f(index, t);
        });
    }
}

impl SampleBits {
    /// Sets every sample whose centre lies in the triangle `corners`
    /// (sample units, either winding; on an edge counts as inside) and
    /// calls `f(index, weights)` for each, `weights` its barycentric
    /// weights of the three corners. Samples outside the picture,
    /// non-finite and zero-area triangles are skipped.
    pub fn stamp_triangle_each(&mut self, corners: [Vec2; 3], mut f: impl FnMut(usize, [f32; 3])) {
        let [a, b, c] = corners;
        let area = (b - a).perp_dot(c - a);
        let (min, max) = (a.min(b).min(c), a.max(b).max(c));
        if !(area != 0.0 && area.is_finite() && min.is_finite() && max.is_finite())
            || self.width == 0
            || self.height == 0
        {
            return;
        }
        let i0 = ((min.x - 0.5).ceil() as i64).max(0);
        let i1 = ((max.x - 0.5).floor() as i64).min(i64::from(self.width) - 1);
        let j0 = ((min.y - 0.5).ceil() as i64).max(0);
        let j1 = ((max.y - 0.5).floor() as i64).min(i64::from(self.height) - 1);
        for j in j0..=j1 {
            for i in i0..=i1 {
                let p = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
                // Each corner's weight: the sub-triangle opposite it over
                // the whole, all ≥ 0 inside whatever the winding.
                let weights = [
                    (c - b).perp_dot(p - b) / area,
                    (a - c).perp_dot(p - c) / area,
                    (b - a).perp_dot(p - a) / area,
                ];
                if weights.iter().all(|&w| w >= 0.0) {
                    let index = j as usize * self.width as usize + i as usize;
                    self.set(index);
                    f(index, weights);
                }
            }
        }
    }
}

/// The samples of a `[width, height]` grid in a piece (see
/// [`SampleBits::stamp_each`]).
fn each_sample_in(
    [width, height]: [u32; 2],
    a: Vec2,
    b: Vec2,
    ra: f32,
    rb: f32,
    ends: PieceEnds,
    mut f: impl FnMut(usize, f32),
) {
    let r = ra.max(rb);
    let reach = ends.reach();
    let (min, max) = (a.min(b) - r, a.max(b) + r);
    if !(min.is_finite() && max.is_finite()) || width == 0 || height == 0 {
        return;
    }
    let i0 = ((min.x - 0.5).ceil() as i64).max(0);
    let i1 = ((max.x - 0.5).floor() as i64).min(i64::from(width) - 1);
    let j0 = ((min.y - 0.5).ceil() as i64).max(0);
    let j1 = ((max.y - 0.5).floor() as i64).min(i64::from(height) - 1);
    let axis = b - a;
    let length_sq = axis.length_squared();
    let length = length_sq.sqrt();
    // Each row visits only the samples of its span through the piece's
    // bounding rectangle (along the axis, `r` on each side, and `r` past
    // the ends when they are round), widened by a hundredth of a sample
    // against rounding; the exact test below decides each sample. (A
    // thin diagonal needle covers a sliver of its axis-aligned box.)
    let rectangle = (length > 0.0 && length.is_finite()).then(|| {
        let along = axis / length;
        let across = Vec2::new(-along.y, along.x);
        let (past_ends, slack) = (reach * r, 0.01);
        [
            (across, -r - slack, r + slack),
            (along, -past_ends - slack, length + past_ends + slack),
        ]
    });
    for j in j0..=j1 {
        let y = j as f32 + 0.5;
        let (mut x0, mut x1) = (i0 as f32 + 0.5, i1 as f32 + 0.5);
        for &(direction, low, high) in rectangle.iter().flatten() {
            // low ≤ (p − a)·direction ≤ high, for p = (x, y).
            let offset = (y - a.y) * direction.y;
            if direction.x.abs() < 1e-6 {
                if offset < low || offset > high {
                    x1 = f32::NEG_INFINITY;
                }
                continue;
            }
            let (u, v) = (a.x + (low - offset) / direction.x, a.x + (high - offset) / direction.x);
            x0 = x0.max(u.min(v));
            x1 = x1.min(u.max(v));
        }
        // Empty (or NaN) span: nothing on this row.
        if x0.partial_cmp(&x1).is_none_or(|order| order.is_gt()) {
            continue;
        }
        let (first, last) = (((x0 - 0.5).ceil() as i64).max(i0), ((x1 - 0.5).floor() as i64).min(i1));
        for i in first..=last {
            let p = Vec2::new(i as f32 + 0.5, y);
            if length_sq == 0.0 {
                // A piece seen end on: the disc of its end.
                if p.distance_squared(a) <= ra * ra {
                    f(j as usize * width as usize + i as usize, 0.0);
                }
                continue;
            }
            let t = (p - a).dot(axis) / length_sq;
            let clamped = t.clamp(0.0, 1.0);
            let half_width = ra + (rb - ra) * clamped;
            let inside = if t == clamped {
                p.distance_squared(a + axis * t) <= half_width * half_width
            } else {
                // Past an end: within the half ellipse of the end's half
                // width across and `reach` times it along.
                let past = (t - clamped).abs() * length;
                let across = (p - a).perp_dot(axis) / length;
                reach > 0.0 && past * past + (reach * across).powi(2) <= (reach * half_width).powi(2)
            };
            if inside {
                f(j as usize * width as usize + i as usize, clamped);
            }
        }
    }
}

/// Largest side of the sample grid: pictures above it take fewer samples.
const MAX_SAMPLE_SIDE: u64 = 40_000;

/// The tree's coverage seen from the side, orthographic, on the CPU: every
/// needle its capped cylinder's silhouette (a strip `2r` wide and its end
/// caps at the needle's slant, [`PieceEnds::Capped`]) and every wood
/// segment a trapezoid with round ends, rasterized
/// on a grid of `samples × samples` binary samples a pixel (a sample is
/// covered when its centre is within the piece's half width of its axis),
/// box-filtered to pixels. `None` without valid needles or with a pixel
/// size that is not positive and finite.
pub fn side_coverage(needles: &[Needle], wood: &[WoodSegment], view: SideView) -> Option<SidePicture> {
    if !(view.pixel.is_finite() && view.pixel > 0.0) {
        return None;
    }
    let right = Vec3::new(view.azimuth.cos(), 0.0, view.azimuth.sin());
    let toward = right.cross(Vec3::Y);
    let project = |p: Vec3| Vec2::new(p.dot(right), p.y);
    let valid: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
    let thinnest = valid.iter().map(|n| n.radius).fold(f32::INFINITY, f32::min);
    if valid.is_empty() {
        return None;
    }
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for n in &valid {
        for p in [project(n.base), project(n.tip)] {
            lo = lo.min(p - n.radius);
            hi = hi.max(p + n.radius);
        }
    }
    let crown_lo = lo;
    let crown_hi = hi;
    for w in wood.iter().filter(|w| w.is_valid()) {
        let r = w.start_radius.max(w.end_radius);
        for p in [project(w.start), project(w.end)] {
            lo = lo.min(p - r);
            hi = hi.max(p + r);
        }
    }
    let width = ((hi.x - lo.x) / view.pixel).ceil().max(1.0) as u32;
    let height = ((hi.y - lo.y) / view.pixel).ceil().max(1.0) as u32;
    let wanted = if view.samples == 0 {
        (view.pixel / (2.0 * thinnest)).ceil().clamp(1.0, 256.0) as u32
    } else {
        view.samples
    };
    let longest = u64::from(width.max(height));
    let samples = wanted.min((MAX_SAMPLE_SIDE / longest).max(1) as u32);
    let (sw, sh) = (width * samples, height * samples);
    let step = view.pixel / samples as f32;
    // Sample (i, j) has its centre at lo + ((i + ½), (top − j − ½))·step.
    let top = lo.y + height as f32 * view.pixel;
    let mut bits = SampleBits::new(sw, sh);
    // Picture metres to sample units (x right, y down from the top).
    let at = |p: Vec2| Vec2::new((p.x - lo.x) / step, (top - p.y) / step);
    for n in &valid {
        bits.stamp(
            at(project(n.base)),
            at(project(n.tip)),
            n.radius / step,
            n.radius / step,
            PieceEnds::of_cylinder(n.tip - n.base, toward),
        );
    }
    for w in wood.iter().filter(|w| w.is_valid()) {
        let (a, b) = (at(project(w.start)), at(project(w.end)));
        bits.stamp(a, b, w.start_radius / step, w.end_radius / step, PieceEnds::Round);
    }
    let mut grid = CoverageGrid::new(width, height);
    let per_pixel = (samples * samples) as f32;
    for j in 0..sh {
        for i in 0..sw {
            if bits.get(i, j) {
                grid.coverage[((j / samples) * width + i / samples) as usize] += 1.0 / per_pixel;
            }
        }
    }
    let column = |x: f32| ((x - lo.x) / view.pixel).clamp(0.0, width as f32);
    let row = |y: f32| ((top - y) / view.pixel).clamp(0.0, height as f32);
    let crown = CrownBox {
        x0: column(crown_lo.x).floor() as u32,
        x1: column(crown_hi.x).ceil() as u32,
        y0: row(crown_hi.y).floor() as u32,
        y1: row(crown_lo.y).ceil() as u32,
    };
    Some(SidePicture { grid, crown, samples })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A capped cylinder seen at a slant covers its strip and, past each
    /// end, half the ellipse its end disc projects to: `2rL' + πr²·slant`
    /// samples (`L'` the projected length); flat ends the strip alone,
    /// round ends a capsule, and a cylinder seen end on its disc.
    #[test]
    fn stamped_caps_cover_the_cylinders_silhouette() {
        let radius = 40.0;
        let view = Vec3::Z;
        for (slant_degrees, turn) in [(0.0f32, 0.3f32), (20.0, 1.1), (45.0, 2.0), (70.0, 0.7), (89.0, 2.9)] {
            let length = 300.0;
            let tilt = slant_degrees.to_radians();
            // The axis at `tilt` out of the picture's plane, turned `turn` in it.
            let axis = Vec3::new(tilt.cos() * turn.cos(), tilt.cos() * turn.sin(), tilt.sin()) * length;
            let a = Vec2::new(500.0, 500.0);
            let b = a + Vec2::new(axis.x, axis.y);
            let ends = PieceEnds::of_cylinder(axis, view);
            assert!((ends.reach() - tilt.sin()).abs() < 1e-5, "{ends:?}");
            let strip = 2.0 * radius * a.distance(b);
            let caps = std::f32::consts::PI * radius * radius;
            for (ends, expected) in [
                (PieceEnds::Flat, strip),
                (PieceEnds::Round, strip + caps),
                (ends, strip + caps * tilt.sin()),
            ] {
                let mut bits = SampleBits::new(1000, 1000);
                bits.stamp(a, b, radius, radius, ends);
                let covered = bits.count_set() as f32;
                assert!(
                    (covered / expected - 1.0).abs() < 0.01,
                    "{slant_degrees}°, {ends:?}: {covered} vs {expected}"
                );
            }
        }
        // End on: the disc, whatever the ends.
        for ends in [PieceEnds::Flat, PieceEnds::of_cylinder(Vec3::Z, view)] {
            let mut bits = SampleBits::new(200, 200);
            let centre = Vec2::splat(100.0);
            bits.stamp(centre, centre, radius, radius, ends);
            let disc = std::f32::consts::PI * radius * radius;
            assert!((bits.count_set() as f32 / disc - 1.0).abs() < 0.01, "{ends:?}");
        }
        // Degenerate views give flat ends, and a NaN slant reaches nowhere.
        assert_eq!(PieceEnds::of_cylinder(Vec3::ZERO, view).reach(), 0.0);
        assert_eq!(PieceEnds::of_cylinder(Vec3::X, Vec3::NAN).reach(), 0.0);
        assert_eq!(PieceEnds::Capped { slant: f32::NAN }.reach(), 0.0);
    }

    /// A needle from `base` to `tip` (the model tests' shorthand).
    pub(crate) fn needle(base: Vec3, tip: Vec3, radius: f32) -> Needle {
        Needle {
            base,
            tip,
            radius,
            normal: Vec3::Z,
            group: 0,
        }
    }

    fn crown(width: u32, height: u32) -> CrownBox {
        CrownBox {
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
        }
    }

    #[test]
    fn a_solid_crown_is_not_see_through_and_an_empty_one_has_no_outline() {
        // A solid triangle (a spruce's side view): its outline is exactly
        // its silhouette, however coarse the closing.
        let mut grid = CoverageGrid::new(64, 64);
        for y in 0..64 {
            let half = y / 2;
            for x in 32 - half..=32 + half.min(31) {
                grid.coverage[(y * 64 + x) as usize] = 1.0;
            }
        }
        let solid = crown_see_through(&grid, crown(64, 64)).expect("a silhouette");
        assert_eq!(solid.see_through, 0.0, "{solid:?}");
        assert_eq!(solid.closing, 4);
        assert_eq!(crown_see_through(&CoverageGrid::new(32, 32), crown(32, 32)), None);
        assert_eq!(crown_see_through(&grid, CrownBox { x1: 0, ..crown(64, 64) }), None);
    }

    #[test]
    fn gaps_narrower_than_the_closing_count_and_the_outside_does_not() {
        // A 32-row crown (closing 2 px) of 16 columns: every third row
        // inside it is empty (gaps of 1 px are closed), and the columns
        // outside are empty (not in the outline).
        let gap = |y: u32| y % 3 == 1 && y < 30;
        let mut grid = CoverageGrid::new(40, 32);
        for y in 0..32 {
            for x in 12..28 {
                if !gap(y) {
                    grid.coverage[(y * 40 + x) as usize] = 0.8;
                }
            }
        }
        let measured = crown_see_through(&grid, crown(40, 32)).expect("a silhouette");
        let empty_rows = (0..32).filter(|&y| gap(y)).count() as f64;
        let expected = 1.0 - 0.8 * (32.0 - empty_rows) / 32.0;
        assert!(
            (measured.see_through - expected).abs() < 1e-6,
            "{measured:?} vs {expected}"
        );
        assert_eq!(measured.outline_pixels, 32 * 16);
    }

    #[test]
    fn faint_pixels_do_not_widen_the_outline_and_wide_gaps_stay_open_at_the_edge() {
        let mut grid = CoverageGrid::new(40, 32);
        for y in 0..32 {
            for x in 10..30 {
                grid.coverage[(y * 40 + x) as usize] = 0.5;
            }
            grid.coverage[(y * 40) as usize] = 0.04;
        }
        // A notch 6 px deep into the right edge over 8 rows: wider than
        // the closing (2 px), so it is not outline.
        for y in 10..18 {
            for x in 24..30 {
                grid.coverage[(y * 40 + x) as usize] = 0.0;
            }
        }
        let measured = crown_see_through(&grid, crown(40, 32)).expect("a silhouette");
        assert!((measured.see_through - 0.5).abs() < 1e-6, "{measured:?}");
        assert_eq!(measured.outline_pixels, 32 * 20 - 8 * 6);
    }

    /// A triangle sets the samples of its area whatever its winding, each
    /// with weights that sum to one and place the sample.
    #[test]
    fn a_triangle_sets_its_area_with_its_weights() {
        let corners = [Vec2::new(10.0, 10.0), Vec2::new(110.0, 10.0), Vec2::new(10.0, 70.0)];
        for winding in [corners, [corners[0], corners[2], corners[1]]] {
            let mut bits = SampleBits::new(128, 128);
            let mut count = 0u64;
            bits.stamp_triangle_each(winding, |index, w| {
                count += 1;
                assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
                let p = winding[0] * w[0] + winding[1] * w[1] + winding[2] * w[2];
                let sample = Vec2::new((index % 128) as f32 + 0.5, (index / 128) as f32 + 0.5);
                assert!(p.distance(sample) < 1e-3, "{p} {sample}");
            });
            // 100 × 60 / 2 samples, give or take the edges.
            assert!((count as f32 - 3000.0).abs() < 100.0, "{count}");
            assert_eq!(bits.count_set(), count);
        }
        let mut bits = SampleBits::new(8, 8);
        bits.stamp_triangle_each([Vec2::ZERO, Vec2::ONE, Vec2::splat(2.0)], |_, _| panic!("no area"));
        bits.stamp_triangle_each([Vec2::NAN, Vec2::ONE, Vec2::X], |_, _| panic!("not finite"));
    }

    #[test]
    fn a_side_view_covers_a_needle_by_its_area() {
        // One needle 1 m long and 2 cm wide, crossing 0.1 m pixels: its
        // summed coverage is its area over the pixel area.
        let n = needle(Vec3::new(0.013, 0.0, 0.0), Vec3::new(0.013, 1.0, 0.0), 0.01);
        let view = SideView {
            azimuth: 0.0,
            pixel: 0.1,
            samples: 40,
        };
        let picture = side_coverage(&[n], &[], view).expect("a needle");
        let summed: f32 = picture.grid.coverage.iter().sum();
        let expected = 1.0 * 0.02 / (0.1 * 0.1);
        assert!((summed - expected).abs() < 0.06 * expected, "{summed} vs {expected}");
        assert_eq!(picture.crown.y1 - picture.crown.y0, picture.grid.height);
    }

    #[test]
    fn needles_behind_each_other_do_not_add_coverage_and_wood_is_left_out_of_the_crown_box() {
        let front = needle(Vec3::ZERO, Vec3::Y, 0.05);
        let behind = needle(Vec3::new(0.0, 0.0, -3.0), Vec3::new(0.0, 1.0, -3.0), 0.05);
        let view = SideView {
            azimuth: 0.0,
            pixel: 0.1,
            samples: 20,
        };
        let one = side_coverage(&[front], &[], view).expect("a needle");
        let two = side_coverage(&[front, behind], &[], view).expect("needles");
        assert_eq!(one.grid, two.grid);
        let trunk = WoodSegment {
            start: Vec3::new(0.0, -2.0, 0.0),
            end: Vec3::ZERO,
            start_radius: 0.2,
            end_radius: 0.1,
        };
        let with_trunk = side_coverage(&[front], &[trunk], view).expect("a needle");
        assert!(with_trunk.grid.height > one.grid.height);
        // The crown box leaves the trunk out (it may straddle one more row:
        // the grid's origin moved with the trunk).
        let crown_rows = with_trunk.crown.y1 - with_trunk.crown.y0;
        assert!(crown_rows.abs_diff(one.grid.height) <= 1, "{crown_rows} rows");
        assert!(with_trunk.grid.height >= crown_rows + 20);
        assert!(side_coverage(&[], &[trunk], view).is_none());
        assert!(
            side_coverage(
                &[front],
                &[],
                SideView {
                    pixel: f32::NAN,
                    ..view
                }
            )
            .is_none()
        );
    }
}
