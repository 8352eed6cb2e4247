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
        let Some(piece) = PieceRaster::new([self.width, self.height], a, b, ra, rb, ends) else {
            return;
        };
        if piece.is_narrow() {
            piece.each_sample(|index, _| self.set(index));
        } else {
            piece.each_run(|first, last| self.set_run(first, last));
        }
    }

    /// Sets every sample in the piece from `a` to `b` of half width `r`
    /// (as [`SampleBits::stamp_each`] with `ra = rb = r`) and calls `f(index,
    /// t)` for those of them also set in `mask` (of this size; none where
    /// it is not): the samples a needle covers over something already
    /// drawn, found a word at a time.
    pub fn stamp_each_over(
        &mut self,
        a: Vec2,
        b: Vec2,
        r: f32,
        ends: PieceEnds,
        mask: &SampleBits,
        mut f: impl FnMut(usize, f32),
    ) {
        let Some(piece) = PieceRaster::new([self.width, self.height], a, b, r, r, ends) else {
            return;
        };
        let same_size = (mask.width, mask.height) == (self.width, self.height);
        if piece.is_narrow() {
            piece.each_sample(|index, t| {
                self.set(index);
                if same_size && mask.is_set(index) {
                    f(index, t);
                }
            });
            return;
        }
        piece.each_run(|first, last| {
            self.set_run(first, last);
            if same_size {
                mask.for_each_set_in(first, last, |index| f(index, piece.t_of(index)));
            }
        });
    }

    /// Whether every sample of the bounding box of a piece from `a` to `b`
    /// of half width up to `r` (sample units; the box
    /// [`SampleBits::stamp`] searches, within the picture) is set: a
    /// piece stamped there changes nothing. `false` for an empty or
    /// non-finite box.
    pub fn box_is_full(&self, a: Vec2, b: Vec2, r: f32) -> bool {
        let Some(rows) = self.box_runs(a, b, r) else {
            return false;
        };
        rows.into_iter().all(|(first, last)| {
            (first / 64..=last / 64).all(|word| {
                let mask = run_mask(word, first, last);
                self.bits[word] & mask == mask
            })
        })
    }

    /// Whether every sample of the bounding box of a piece (as
    /// [`SampleBits::box_is_full`]) is set in `self`, and every one of them
    /// set in `inner` is set in `outer` too: one pass over the box for
    /// the three (`false` where they are not of one size, or for an empty
    /// or non-finite box). The impostor skips a needle whose box is so:
    /// every sample covered, no wood left unhidden under it.
    pub fn box_is_full_and_inside(&self, inner: &SampleBits, outer: &SampleBits, a: Vec2, b: Vec2, r: f32) -> bool {
        let size = (self.width, self.height);
        if (inner.width, inner.height) != size || (outer.width, outer.height) != size {
            return false;
        }
        let Some(rows) = self.box_runs(a, b, r) else {
            return false;
        };
        rows.into_iter().all(|(first, last)| {
            (first / 64..=last / 64).all(|word| {
                let mask = run_mask(word, first, last);
                self.bits[word] & mask == mask && inner.bits[word] & !outer.bits[word] & mask == 0
            })
        })
    }

    /// Each row of a piece's bounding box as a run of row-major indices;
    /// `None` for an empty or non-finite box.
    fn box_runs(&self, a: Vec2, b: Vec2, r: f32) -> Option<impl Iterator<Item = (usize, usize)>> {
        let ((i0, i1), (j0, j1)) = sample_box([self.width, self.height], a, b, r)?;
        if i0 > i1 || j0 > j1 {
            return None;
        }
        let width = self.width as usize;
        Some((j0..=j1).map(move |j| (j as usize * width + i0 as usize, j as usize * width + i1 as usize)))
    }

    /// Sets samples `first ..= last` (row-major), a word at a time.
    fn set_run(&mut self, first: usize, last: usize) {
        for word in first / 64..=last / 64 {
            self.bits[word] |= run_mask(word, first, last);
        }
    }

    /// Calls `f(index)` for every set sample among `first ..= last`
    /// (row-major), in order.
    fn for_each_set_in(&self, first: usize, last: usize, mut f: impl FnMut(usize)) {
        for word in first / 64..=last / 64 {
            let mut rest = self.bits[word] & run_mask(word, first, last);
            while rest != 0 {
                f(word * 64 + rest.trailing_zeros() as usize);
                rest &= rest - 1;
            }
        }
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

    /// How many of samples `first ..= last` (row-major) are set, a word
    /// at a time (0 for an empty range; `last` must lie in the picture).
    pub fn count_set_in(&self, first: usize, last: usize) -> u32 {
        if first > last {
            return 0;
        }
        (first / 64..=last / 64)
            .map(|word| (self.bits[word] & run_mask(word, first, last)).count_ones())
            .sum()
    }

    /// Samples `first .. first + length` (row-major, `length` at most 64)
    /// as the low bits of a word, sample `first` in bit 0; samples past
    /// the picture read as clear.
    pub fn run_bits(&self, first: usize, length: u32) -> u64 {
        if length == 0 {
            return 0;
        }
        let (word, shift) = (first / 64, first % 64);
        let low = self.bits.get(word).map_or(0, |bits| bits >> shift);
        let high = if shift > 0 && shift + length as usize > 64 {
            self.bits.get(word + 1).map_or(0, |bits| bits << (64 - shift))
        } else {
            0
        };
        let mask = if length >= 64 { u64::MAX } else { (1 << length) - 1 };
        (low | high) & mask
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
        let Some(piece) = PieceRaster::new([self.width, self.height], a, b, ra, rb, ends) else {
            return;
        };
        piece.each_sample(|index, t| {
            self.set(index);
            f(index, t);
        });
    }
}

/// The bits of word `word` among samples `first ..= last`.
fn run_mask(word: usize, first: usize, last: usize) -> u64 {
    let low = first.saturating_sub(word * 64).min(64);
    let high = (last + 1).saturating_sub(word * 64).min(64);
    let below = |n: usize| if n >= 64 { u64::MAX } else { (1u64 << n) - 1 };
    below(high) & !below(low)
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

/// A piece prepared for rasterizing on a `[width, height]` sample grid
/// (see [`SampleBits::stamp_each`]): its clipped bounding box, and each
/// row's candidate span through its bounding rectangle.
struct PieceRaster {
    width: u32,
    a: Vec2,
    axis: Vec2,
    length_sq: f32,
    ra: f32,
    rb: f32,
    length: f32,
    reach: f32,
    /// Columns and rows of the bounding box inside the grid.
    columns: (i64, i64),
    rows: (i64, i64),
    /// The rectangle's two pairs of sides, for a piece of positive length.
    rectangle: Option<[RowSpan; 2]>,
    /// Whether the piece's samples in a row are one run: a piece of one
    /// width (a strip with its caps), or with flat ends (a trapezoid). A
    /// tapered piece with round ends has a notch where an end's disc meets
    /// the narrower side.
    convex: bool,
}

impl PieceRaster {
    /// `None` for a non-finite piece or an empty grid.
    fn new([width, height]: [u32; 2], a: Vec2, b: Vec2, ra: f32, rb: f32, ends: PieceEnds) -> Option<Self> {
        let r = ra.max(rb);
        let reach = ends.reach();
        let (columns, rows) = sample_box([width, height], a, b, r)?;
        let axis = b - a;
        let length_sq = axis.length_squared();
        let length = length_sq.sqrt();
        // Each row visits only the samples of its span through the piece's
        // bounding rectangle (along the axis, `r` on each side, and `r` past
        // the ends when they are round), widened by a hundredth of a sample
        // against rounding; the exact test decides each sample. (A thin
        // diagonal needle covers a sliver of its axis-aligned box.)
        let rectangle = (length > 0.0 && length.is_finite()).then(|| {
            let along = axis / length;
            let across = Vec2::new(-along.y, along.x);
            let (past_ends, slack) = (reach * r, 0.01);
            [
                RowSpan::new(a, across, -r - slack, r + slack),
                RowSpan::new(a, along, -past_ends - slack, length + past_ends + slack),
            ]
        });
        Some(Self {
            width,
            a,
            axis,
            length_sq,
            ra,
            rb,
            length,
            reach,
            columns,
            rows,
            rectangle,
            convex: ra == rb || reach == 0.0,
        })
    }

    /// Whether the piece is under two samples wide: a row holds a sample
    /// or two of it, found faster one by one than as a run (a white pine's
    /// needles in its impostor).
    fn is_narrow(&self) -> bool {
        self.ra.max(self.rb) < 1.0
    }

    /// The columns of row `j` its bounding rectangle crosses (possibly
    /// empty: `first > last`).
    fn candidates(&self, j: i64) -> (i64, i64) {
        let y = j as f32 + 0.5;
        let (i0, i1) = self.columns;
        let (mut x0, mut x1) = (i0 as f32 + 0.5, i1 as f32 + 0.5);
        for span in self.rectangle.iter().flatten() {
            (x0, x1) = span.clip(y, x0, x1);
        }
        // Empty (or NaN) span: nothing on this row.
        if x0.partial_cmp(&x1).is_none_or(|order| order.is_gt()) {
            return (1, 0);
        }
        (ceil_to_i64(x0 - 0.5).max(i0), floor_to_i64(x1 - 0.5).min(i1))
    }

    /// Where along the axis sample `(i, j)` lies, in `[0, 1]`, when its
    /// centre is in the piece: within the half width of the axis between
    /// the ends, past each end within the end's shape.
    fn inside(&self, i: i64, j: i64) -> Option<f32> {
        let p = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
        let (a, axis, ra, rb) = (self.a, self.axis, self.ra, self.rb);
        if self.length_sq == 0.0 {
            // A piece seen end on: the disc of its end.
            return (p.distance_squared(a) <= ra * ra).then_some(0.0);
        }
        let t = (p - a).dot(axis) / self.length_sq;
        let clamped = t.clamp(0.0, 1.0);
        let half_width = ra + (rb - ra) * clamped;
        let inside = if t == clamped {
            p.distance_squared(a + axis * t) <= half_width * half_width
        } else {
            // Past an end: within the half ellipse of the end's half
            // width across and `reach` times it along.
            let past = (t - clamped).abs() * self.length;
            let across = (p - a).perp_dot(axis) / self.length;
            let reach = self.reach;
            reach > 0.0 && past * past + (reach * across).powi(2) <= (reach * half_width).powi(2)
        };
        inside.then_some(clamped)
    }

    /// Calls `f(index, t)` for every sample in the piece (row-major
    /// `index`, `t` from [`Self::inside`]).
    fn each_sample(&self, mut f: impl FnMut(usize, f32)) {
        for j in self.rows.0..=self.rows.1 {
            let (first, last) = self.candidates(j);
            let row = j as usize * self.width as usize;
            for i in first..=last {
                if let Some(t) = self.inside(i, j) {
                    f(row + i as usize, t);
                }
            }
        }
    }

    /// Calls `f(first, last)` for every run of consecutive samples in the
    /// piece along a row (row-major indices, inclusive): the samples
    /// [`Self::each_sample`] visits, a row's in one run where the piece is
    /// convex (its first and last found by the exact test, the ones
    /// between taken as inside).
    fn each_run(&self, mut f: impl FnMut(usize, usize)) {
        for j in self.rows.0..=self.rows.1 {
            let (first, last) = self.candidates(j);
            let row = j as usize * self.width as usize;
            if self.convex {
                let Some(start) = (first..=last).find(|&i| self.inside(i, j).is_some()) else {
                    continue;
                };
                let end = (start + 1..=last)
                    .rev()
                    .find(|&i| self.inside(i, j).is_some())
                    .unwrap_or(start);
                f(row + start as usize, row + end as usize);
                continue;
            }
            let mut run: Option<(i64, i64)> = None;
            for i in first..=last {
                match (self.inside(i, j).is_some(), run) {
                    (true, Some((start, end))) if end + 1 == i => run = Some((start, i)),
                    (true, _) => {
                        if let Some((start, end)) = run {
                            f(row + start as usize, row + end as usize);
                        }
                        run = Some((i, i));
                    }
                    (false, _) => {}
                }
            }
            if let Some((start, end)) = run {
                f(row + start as usize, row + end as usize);
            }
        }
    }

    /// [`Self::inside`]'s `t` of sample `index` (row-major), for a sample
    /// known to be in the piece.
    fn t_of(&self, index: usize) -> f32 {
        let (i, j) = (index % self.width as usize, index / self.width as usize);
        self.inside(i as i64, j as i64).unwrap_or(0.0)
    }
}

/// The columns and rows of a `[width, height]` sample grid whose centres
/// lie in the box of a piece from `a` to `b` of half width up to `r`
/// (either range empty, `first > last`, where none do); `None` for a
/// non-finite box or an empty grid.
fn sample_box([width, height]: [u32; 2], a: Vec2, b: Vec2, r: f32) -> Option<((i64, i64), (i64, i64))> {
    let (min, max) = (a.min(b) - r, a.max(b) + r);
    if !(min.is_finite() && max.is_finite()) || width == 0 || height == 0 {
        return None;
    }
    Some((
        (
            ceil_to_i64(min.x - 0.5).max(0),
            floor_to_i64(max.x - 0.5).min(i64::from(width) - 1),
        ),
        (
            ceil_to_i64(min.y - 0.5).max(0),
            floor_to_i64(max.y - 0.5).min(i64::from(height) - 1),
        ),
    ))
}

/// `⌈x⌉` as an integer, saturating, 0 for NaN (as `x.ceil() as i64`),
/// without the libm call `f32::ceil` costs on a baseline x86-64 target.
fn ceil_to_i64(x: f32) -> i64 {
    let truncated = x as i64;
    truncated.saturating_add(i64::from((truncated as f32) < x))
}

/// `⌊x⌋` as an integer, saturating, 0 for NaN (as `x.floor() as i64`).
fn floor_to_i64(x: f32) -> i64 {
    let truncated = x as i64;
    truncated.saturating_sub(i64::from((truncated as f32) > x))
}

/// One pair of sides of a piece's bounding rectangle, `low ≤ (p −
/// a)·direction ≤ high`, prepared once a piece to give each sample row's
/// span of `x` without a division.
#[derive(Clone, Copy)]
struct RowSpan {
    a: Vec2,
    direction: Vec2,
    low: f32,
    high: f32,
    /// `1 / direction.x`, or 0 where `direction` is (nearly) vertical and
    /// the pair bounds rows, not columns.
    inverse_x: f32,
}

impl RowSpan {
    fn new(a: Vec2, direction: Vec2, low: f32, high: f32) -> Self {
        let inverse_x = if direction.x.abs() < 1e-6 {
            0.0
        } else {
            direction.x.recip()
        };
        Self {
            a,
            direction,
            low,
            high,
            inverse_x,
        }
    }

    /// The span `x0 ..= x1` of the row at `y` clipped to this pair of
    /// sides (`x1` is −∞ where the row misses them).
    fn clip(&self, y: f32, x0: f32, x1: f32) -> (f32, f32) {
        let offset = (y - self.a.y) * self.direction.y;
        if self.inverse_x == 0.0 {
            let misses = offset < self.low || offset > self.high;
            return (x0, if misses { f32::NEG_INFINITY } else { x1 });
        }
        let u = self.a.x + (self.low - offset) * self.inverse_x;
        let v = self.a.x + (self.high - offset) * self.inverse_x;
        (x0.max(u.min(v)), x1.min(u.max(v)))
    }
}

/// Largest side of the sample grid: pictures above it take fewer samples.
const MAX_SAMPLE_SIDE: u64 = 40_000;

/// Right, up and toward the viewer of a side view from `azimuth` about +Y
/// (0 looks along −Z) and `elevation` above the horizontal, in the tree's
/// frame; level (`elevation` 0), up is +Y exactly.
pub(crate) fn view_axes(azimuth: f32, elevation: f32) -> [Vec3; 3] {
    let right = Vec3::new(azimuth.cos(), 0.0, azimuth.sin());
    let level_toward = right.cross(Vec3::Y);
    let (sin, cos) = elevation.sin_cos();
    [
        right,
        Vec3::Y * cos - level_toward * sin,
        level_toward * cos + Vec3::Y * sin,
    ]
}

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
    let [right, _, toward] = view_axes(view.azimuth, 0.0);
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

    /// Every sample of a piece the reference test ([`PieceRaster::inside`]
    /// on each candidate) finds, as a set.
    fn reference_samples(size: [u32; 2], a: Vec2, b: Vec2, ra: f32, rb: f32, ends: PieceEnds) -> Vec<(usize, f32)> {
        let mut samples = Vec::new();
        if let Some(piece) = PieceRaster::new(size, a, b, ra, rb, ends) {
            piece.each_sample(|index, t| samples.push((index, t)));
        }
        samples
    }

    fn piece_ends(kind: u8, slant: f32) -> PieceEnds {
        match kind % 3 {
            0 => PieceEnds::Flat,
            1 => PieceEnds::Round,
            _ => PieceEnds::Capped { slant },
        }
    }

    proptest::proptest! {
        /// `stamp` sets a row's samples a run at a time: exactly the
        /// samples the per-sample test finds, for pieces of one width and
        /// tapered ones (whose round ends leave a notch, drawn sample by
        /// sample), thin and wide, in and partly out of the picture.
        #[test]
        fn runs_set_exactly_the_samples_the_exact_test_finds(
            ax in -5.0f32..45.0, ay in -5.0f32..35.0, bx in -5.0f32..45.0, by in -5.0f32..35.0,
            ra in 0.01f32..6.0, taper in 0.2f32..1.5, tapered in proptest::bool::ANY,
            kind in 0u8..3, slant in 0.0f32..1.0,
        ) {
            let size = [40, 30];
            let (a, b) = (Vec2::new(ax, ay), Vec2::new(bx, by));
            let rb = if tapered { ra * taper } else { ra };
            let ends = piece_ends(kind, slant);
            let mut stamped = SampleBits::new(size[0], size[1]);
            stamped.stamp(a, b, ra, rb, ends);
            let mut expected = SampleBits::new(size[0], size[1]);
            for (index, _) in reference_samples(size, a, b, ra, rb, ends) {
                expected.set(index);
            }
            proptest::prop_assert_eq!(stamped, expected);
        }

        /// `count_set_in` counts the set samples of a run as one by one,
        /// and `run_bits` reads them in order.
        #[test]
        fn a_run_counts_its_set_samples(seed in 0u64..u64::MAX, first in 0usize..300, length in 0usize..300) {
            let mut bits = SampleBits::new(20, 15);
            let mut state = seed | 1;
            for index in 0..300 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                if state % 3 == 0 {
                    bits.set(index);
                }
            }
            let last = (first + length).min(299);
            let one_by_one = (first..=last).filter(|&index| bits.is_set(index)).count() as u32;
            proptest::prop_assert_eq!(bits.count_set_in(first, last), one_by_one);
            let run = (length % 65) as u32;
            let read = bits.run_bits(first, run);
            for k in 0..64 {
                let expected = k < run as usize && first + k < 300 && bits.is_set(first + k);
                proptest::prop_assert_eq!(read >> k & 1 == 1, expected, "sample {} of a run of {}", k, run);
            }
        }

        /// `stamp_each_over` sets what `stamp` sets and calls back exactly
        /// for the piece's samples set in the mask, with the reference's
        /// `t`; `box_is_full` holds only where stamping changes nothing,
        /// and `box_is_full_and_inside` sees every masked sample of the
        /// box.
        #[test]
        fn stamping_over_a_mask_calls_back_where_the_mask_is(
            ax in 0.0f32..40.0, ay in 0.0f32..30.0, bx in 0.0f32..40.0, by in 0.0f32..30.0,
            r in 0.05f32..4.0, kind in 0u8..3, slant in 0.0f32..1.0,
            mask_seed in 0u64..u64::MAX, fill in 0.0f32..1.0,
        ) {
            let size = [40, 30];
            let (a, b) = (Vec2::new(ax, ay), Vec2::new(bx, by));
            let ends = piece_ends(kind, slant);
            let mut mask = SampleBits::new(size[0], size[1]);
            let mut state = mask_seed | 1;
            for index in 0..1200 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                if (state >> 40) as f32 / (1u64 << 24) as f32 <= fill {
                    mask.set(index);
                }
            }
            let mut over = SampleBits::new(size[0], size[1]);
            let mut called = Vec::new();
            over.stamp_each_over(a, b, r, ends, &mask, |index, t| called.push((index, t)));
            let reference = reference_samples(size, a, b, r, r, ends);
            let expected: Vec<(usize, f32)> = reference.iter().copied().filter(|(index, _)| mask.is_set(*index)).collect();
            proptest::prop_assert_eq!(&called, &expected);
            let mut stamped = SampleBits::new(size[0], size[1]);
            stamped.stamp(a, b, r, r, ends);
            proptest::prop_assert_eq!(&over, &stamped);

            // Full: the mask with the piece stamped on it changes no more.
            let mut covered = mask.clone();
            covered.stamp(a, b, r, r, ends);
            let mut again = covered.clone();
            if covered.box_is_full(a, b, r) {
                again.stamp(a, b, r, r, ends);
                proptest::prop_assert_eq!(&again, &covered);
            }
            let mut everything = SampleBits::new(size[0], size[1]);
            for index in 0..1200 {
                everything.set(index);
            }
            // (An empty box, holding no sample centre, is not full.)
            proptest::prop_assert_eq!(everything.box_is_full(a, b, r), box_holds_a_masked_sample(&everything, a, b, r));
            // Full and inside: `everything` is full wherever the box holds
            // a sample; the mask lies inside itself, and inside nothing
            // only where the box holds none of it.
            let nothing = SampleBits::new(size[0], size[1]);
            proptest::prop_assert_eq!(
                everything.box_is_full_and_inside(&mask, &mask, a, b, r),
                box_holds_a_masked_sample(&everything, a, b, r)
            );
            proptest::prop_assert_eq!(
                everything.box_is_full_and_inside(&mask, &nothing, a, b, r),
                box_holds_a_masked_sample(&everything, a, b, r) && !box_holds_a_masked_sample(&mask, a, b, r)
            );
            proptest::prop_assert_eq!(
                covered.box_is_full_and_inside(&nothing, &nothing, a, b, r),
                covered.box_is_full(a, b, r)
            );
        }
    }

    /// Whether a sample of the piece's bounding box (clamped to the
    /// picture) is set in `mask`, sample by sample.
    fn box_holds_a_masked_sample(mask: &SampleBits, a: Vec2, b: Vec2, r: f32) -> bool {
        let (min, max) = (a.min(b) - r, a.max(b) + r);
        (0..mask.height).any(|j| {
            (0..mask.width).any(|i| {
                let p = Vec2::new(i as f32 + 0.5, j as f32 + 0.5);
                p.x >= min.x && p.x <= max.x && p.y >= min.y && p.y <= max.y && mask.get(i, j)
            })
        })
    }

    /// A strongly tapered piece with round ends, seen with its axis at
    /// 29° to the rows, leaves a gap in a row between its wide side and
    /// its narrow end's disc (the notch where they meet): `stamp` draws
    /// such a piece sample by sample and sets exactly what the exact test
    /// finds, gap included.
    #[test]
    fn a_tapered_round_piece_keeps_the_gap_its_notch_leaves_in_a_row() {
        let size = [80, 60];
        let direction = Vec2::new(29f32.to_radians().cos(), 29f32.to_radians().sin());
        let (a, b) = (Vec2::new(20.0, 16.0), Vec2::new(20.0, 16.0) + direction * 20.0);
        let (ra, rb) = (16.0, 3.0);
        let reference = reference_samples(size, a, b, ra, rb, PieceEnds::Round);
        let rows_with_a_gap = (0..size[1] as usize)
            .filter(|&j| {
                let columns: Vec<usize> = reference
                    .iter()
                    .map(|(index, _)| *index)
                    .filter(|index| index / size[0] as usize == j)
                    .map(|index| index % size[0] as usize)
                    .collect();
                columns.windows(2).any(|pair| pair[1] > pair[0] + 1)
            })
            .count();
        assert!(rows_with_a_gap > 0, "the notch leaves no gap in a row");
        let mut stamped = SampleBits::new(size[0], size[1]);
        stamped.stamp(a, b, ra, rb, PieceEnds::Round);
        let mut expected = SampleBits::new(size[0], size[1]);
        for (index, _) in reference {
            expected.set(index);
        }
        assert_eq!(stamped, expected);
    }

    #[test]
    fn a_run_spans_the_words_it_touches() {
        assert_eq!(run_mask(0, 0, 63), u64::MAX);
        assert_eq!(run_mask(0, 3, 5), 0b111000);
        assert_eq!(run_mask(1, 60, 66), 0b111);
        assert_eq!(run_mask(0, 60, 66), 0xF << 60);
        assert_eq!(run_mask(2, 60, 66), 0);
        assert_eq!(
            (
                ceil_to_i64(2.0),
                ceil_to_i64(2.1),
                ceil_to_i64(-2.1),
                ceil_to_i64(f32::NAN)
            ),
            (2, 3, -2, 0)
        );
        assert_eq!(
            (
                floor_to_i64(2.0),
                floor_to_i64(2.9),
                floor_to_i64(-2.1),
                floor_to_i64(1e30)
            ),
            (2, 2, -3, i64::MAX)
        );
        assert_eq!(ceil_to_i64(1e30), i64::MAX);
    }
}
