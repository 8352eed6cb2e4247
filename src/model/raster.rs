//! How a line covers pixels: the area of its strip inside each pixel's
//! square, not one pixel per step. CPU reference of the line quads of the
//! vertex and fragment shaders (`line_quad_corner`, `strip_coverage` in
//! `conifer_compact.wgsl`).
//!
//! A line stands for needles far thinner than a pixel: a strip of the
//! segment's length and a width `w` of a pixel or less (its opacity; a
//! merged line's equivalent width). The reference (every needle a prism,
//! supersampled) box-filters it: a pixel takes the strip's area inside its
//! square. A hardware line instead lights the pixels whose centres (or
//! MSAA samples) lie within half a pixel of the segment, each with the
//! line's whole opacity: a diagonal needle near a pixel's corner gives its
//! coverage to the pixel beside the one it crosses, and with 4× MSAA the
//! coverage is smeared a pixel wide. Summed over the crown both are right;
//! pixel by pixel they miss by about the line's opacity, which on a light
//! sky moves a dark crown's pixel by several of 255.
//!
//! Here a line is drawn as a quad around its segment, wide enough that
//! every sample of every pixel the strip touches lies in it
//! ([`LINE_QUAD_MARGIN`]), and each pixel takes the strip's area inside its
//! square ([`strip_pixel_coverage`]): the segment's length inside the
//! square at two offsets across the width (Gauss–Legendre; the length is
//! piecewise linear in the offset, so two nodes are exact wherever the
//! strip crosses no corner of the square), times the width.
//!
//! At a pixel error over one a line may stand for something wider than a
//! pixel: a branch, a needle or a bundle up to the pixel error wide. Its
//! strip is then as wide as what it stands for (up to
//! [`MAX_STRIP_WIDTH`]) and each pixel takes the strip's exact area there
//! times the line's opacity ([`line_pixel_coverage`]), where a one-pixel
//! line would lose the rest.

/// How far past its strip's half width (and past its ends) a line's quad
/// reaches, in pixels: a pixel the strip touches has its centre within
/// `√2/2` of the strip, and its MSAA samples (4×: at most `0.375` off the
/// centre on each axis, within `0.53`) within `1.24`. Every sample of such
/// a pixel lies in the quad, so the pixel's coverage is what the fragment
/// writes, not a share of it.
pub const LINE_QUAD_MARGIN: f32 = 1.25;

/// The widest strip a line is drawn as, in pixels: a wider line (a pixel
/// error over eight) keeps this width.
pub const MAX_STRIP_WIDTH: f32 = 8.0;

/// Length of the segment `a`–`b` inside the unit square whose lower corner
/// is `pixel` (all in pixels): clipped to the square's four sides
/// (Liang–Barsky). 0 where it misses the square; a segment along a side
/// counts in both squares it bounds.
pub fn segment_length_in_pixel(a: [f32; 2], b: [f32; 2], pixel: [f32; 2]) -> f32 {
    ClippedSegment::new(a, b).length_in_pixel(pixel)
}

/// A segment prepared for [`segment_length_in_pixel`] over many pixels:
/// its direction and length found once (the same bits).
#[derive(Clone, Copy, Debug)]
struct ClippedSegment {
    a: [f32; 2],
    d: [f32; 2],
    length: f32,
}

impl ClippedSegment {
    fn new(a: [f32; 2], b: [f32; 2]) -> Self {
        let d = [b[0] - a[0], b[1] - a[1]];
        Self {
            a,
            d,
            length: (d[0] * d[0] + d[1] * d[1]).sqrt(),
        }
    }

    fn length_in_pixel(&self, pixel: [f32; 2]) -> f32 {
        let (a, d) = (self.a, self.d);
        let mut t0 = 0.0f32;
        let mut t1 = 1.0f32;
        for axis in 0..2 {
            let (lo, hi) = (pixel[axis] - a[axis], pixel[axis] + 1.0 - a[axis]);
            if d[axis].abs() < 1e-12 {
                if lo > 0.0 || hi < 0.0 {
                    return 0.0;
                }
            } else {
                let (ta, tb) = (lo / d[axis], hi / d[axis]);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        (t1 - t0).max(0.0) * self.length
    }
}

/// The strip of `width` (pixels) centred on the segment `a`–`b`: its area
/// inside the pixel square at `pixel` divided by `width`, i.e. the
/// segment's mean length inside the square over offsets across the width.
/// The width is cut into [`strip_pieces`] equal pieces, each taken at its
/// two Gauss–Legendre nodes (`±1/(2√3)` of the piece about its middle):
/// exact where the strip crosses no corner of the square, and where a
/// side of the square runs along the strip (a vertical trunk's line on a
/// column's edge) off by at most `1/(2√3)` of a piece's share (0.072 of
/// a pixel's coverage: a piece is at most a quarter pixel). The pixel's
/// coverage by a line of opacity `w` (coverage per pixel of its length) is
/// `min(w · strip_pixel_coverage(a, b, w, pixel), 1)`; summed over every
/// pixel it is the segment's length. A degenerate segment covers nothing.
/// The width is clamped to `[0, 1]`. ([`StripInPixels`]
/// prepares one strip for many pixels; [`line_pixel_coverage`] is a
/// line's coverage of a pixel, wide or thin.)
pub fn strip_pixel_coverage(a: [f32; 2], b: [f32; 2], width: f32, pixel: [f32; 2]) -> f32 {
    StripInPixels::new(a, b, width).coverage(pixel)
}

/// The strip a line is drawn as, in pixels: its own `width` where it is
/// wider than a pixel (at most [`MAX_STRIP_WIDTH`]), else its `opacity`
/// (a line thinner than a pixel covers a strip as wide as its opacity
/// whole, so its fade and its layers thin the strip). CPU reference of the
/// shader's `strip_of`.
pub fn line_strip_width(opacity: f32, width: f32) -> f32 {
    if width > 1.0 {
        width.min(MAX_STRIP_WIDTH)
    } else {
        opacity.clamp(0.0, 1.0)
    }
}

/// The coverage of the pixel at `pixel` by a line from `a` to `b` (pixels)
/// of `opacity` that stands for something `width` pixels wide. A line
/// thinner than a pixel: `min(opacity · strip_pixel_coverage(a, b,
/// opacity, pixel), 1)`. A wider one: its strip of [`line_strip_width`]
/// covers the pixel by its exact area there ([`strip_area_in_pixel`]),
/// times the opacity (what the line's fade and layers leave, at most 1).
/// Summed over the pixels it is the segment's length times the opacity,
/// times the strip's width where that is over a pixel. CPU reference of
/// the shader's `line_coverage`.
pub fn line_pixel_coverage(a: [f32; 2], b: [f32; 2], opacity: f32, width: f32, pixel: [f32; 2]) -> f32 {
    joined_line_pixel_coverage(a, b, opacity, width, LineJoints::NONE, pixel)
}

/// Which ends of a line go on into the next piece of one strip: a
/// branch's next segment, or the next section of a segment the wind bends.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineJoints {
    /// The line's start (`a`) is the end of the piece before it.
    pub start: bool,
    /// The line's end (`b`) is the start of the piece after it.
    pub end: bool,
}

impl LineJoints {
    /// Both ends open: the line is a strip of its own.
    pub const NONE: Self = Self {
        start: false,
        end: false,
    };
}

/// How far past a joined end a line's strip reaches for the pixels it
/// owns, in pixels: a pixel's square lies within `√2/2` of its centre.
pub const JOINT_REACH: f32 = 1.0;

/// [`line_pixel_coverage`] of a line whose ends `joints` go on into the
/// next piece of one strip (a branch drawn as segments end to end). Two
/// strips meeting inside a pixel would each cover part of it, and blended
/// as independent layers they cover `1 − (1 − c₁)(1 − c₂)` of it, short of
/// `c₁ + c₂`: a fully covered pixel at a joint drawn at `1 − ½·½`, a pale
/// stripe across a wide branch. So a line wider than a pixel covers only
/// the pixels whose centres lie between its joined ends (measured along
/// it: the pixel at a joint belongs to one piece), each by the area of its
/// strip extended [`JOINT_REACH`] past those ends, which is the whole
/// strip's area there where the pieces run on straight. An open end stays
/// square. A line thinner than a pixel keeps [`line_pixel_coverage`]'s
/// rule whatever its joints (the line calibration measures it so).
pub fn joined_line_pixel_coverage(
    a: [f32; 2],
    b: [f32; 2],
    opacity: f32,
    width: f32,
    joints: LineJoints,
    pixel: [f32; 2],
) -> f32 {
    let opacity = opacity.clamp(0.0, 1.0);
    if width.is_nan() || width <= 1.0 {
        return (opacity * strip_pixel_coverage(a, b, opacity, pixel)).min(1.0);
    }
    let strip = line_strip_width(opacity, width);
    let d = [b[0] - a[0], b[1] - a[1]];
    let length_squared = d[0] * d[0] + d[1] * d[1];
    if length_squared.is_nan() || length_squared <= 1e-12 {
        return 0.0;
    }
    let along = ((pixel[0] + 0.5 - a[0]) * d[0] + (pixel[1] + 0.5 - a[1]) * d[1]) / length_squared;
    if (joints.start && along < 0.0) || (joints.end && along >= 1.0) {
        return 0.0;
    }
    let reach = JOINT_REACH / length_squared.sqrt();
    let at = |t: f32| [a[0] + t * d[0], a[1] + t * d[1]];
    let from = if joints.start { at(-reach) } else { a };
    let to = if joints.end { at(1.0 + reach) } else { b };
    (opacity * strip_area_in_pixel(from, to, strip, pixel)).min(1.0)
}

/// The exact area, inside the unit square at `pixel`, of the rectangle of
/// `width` (pixels) centred on the segment `a`–`b`, its ends square:
/// the rectangle clipped to the square's four sides (Sutherland–Hodgman)
/// and measured by the shoelace formula. A wide strip's quadrature would
/// err wherever a column's edge cuts one of its pieces, in every pixel
/// inside a vertical trunk's strip; this does not. 0 for a degenerate
/// segment or a width of 0 or less.
pub fn strip_area_in_pixel(a: [f32; 2], b: [f32; 2], width: f32, pixel: [f32; 2]) -> f32 {
    let d = [b[0] - a[0], b[1] - a[1]];
    let length = (d[0] * d[0] + d[1] * d[1]).sqrt();
    if length.is_nan() || length <= 1e-6 || width.is_nan() || width <= 0.0 {
        return 0.0;
    }
    let half = 0.5 * width;
    let n = [-d[1] / length * half, d[0] / length * half];
    let mut polygon = [[0.0f32; 2]; 8];
    polygon[..4].copy_from_slice(&[
        [a[0] + n[0], a[1] + n[1]],
        [b[0] + n[0], b[1] + n[1]],
        [b[0] - n[0], b[1] - n[1]],
        [a[0] - n[0], a[1] - n[1]],
    ]);
    let mut count = 4;
    // Each side of the square: keep where `sign · (p[axis] − bound) ≤ 0`.
    for (axis, bound, sign) in [
        (0, pixel[0], -1.0f32),
        (0, pixel[0] + 1.0, 1.0),
        (1, pixel[1], -1.0),
        (1, pixel[1] + 1.0, 1.0),
    ] {
        let mut clipped = [[0.0f32; 2]; 8];
        let mut kept = 0;
        for i in 0..count {
            let p = polygon[i];
            let q = polygon[(i + 1) % count];
            let (dp, dq) = (sign * (p[axis] - bound), sign * (q[axis] - bound));
            if dp <= 0.0 {
                clipped[kept] = p;
                kept += 1;
            }
            if (dp < 0.0 && dq > 0.0) || (dp > 0.0 && dq < 0.0) {
                let t = dp / (dp - dq);
                clipped[kept] = [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])];
                kept += 1;
            }
        }
        polygon = clipped;
        count = kept;
        if count < 3 {
            return 0.0;
        }
    }
    let mut twice = 0.0;
    for i in 0..count {
        let (p, q) = (polygon[i], polygon[(i + 1) % count]);
        twice += p[0] * q[1] - q[0] * p[1];
    }
    (0.5 * twice.abs()).min(1.0)
}

/// One strip prepared for the many pixels it touches: its segments at the
/// nodes across its width found once. `StripInPixels::new(a, b,
/// width).coverage(pixel)` is [`strip_pixel_coverage`]`(a, b, width,
/// pixel)`.
#[derive(Clone, Copy, Debug)]
pub struct StripInPixels {
    /// The segment at each node across the width, two a piece (at most
    /// four pieces).
    nodes: [ClippedSegment; 8],
    /// How many of `nodes` there are; 0 for a degenerate segment.
    count: usize,
}

impl StripInPixels {
    /// The strip of `width` (pixels, clamped to `[0, 1]`) centred on
    /// `a`–`b` (pixels).
    pub fn new(a: [f32; 2], b: [f32; 2], width: f32) -> Self {
        let d = [b[0] - a[0], b[1] - a[1]];
        let length = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let mut strip = Self {
            nodes: [ClippedSegment::new(a, b); 8],
            count: 0,
        };
        if length.is_nan() || length <= 1e-6 {
            return strip;
        }
        let normal = [-d[1] / length, d[0] / length];
        let width = width.clamp(0.0, 1.0);
        let pieces = strip_pieces(width);
        let piece = width / pieces as f32;
        let node = piece / (2.0 * 3f32.sqrt());
        for k in 0..pieces {
            let middle = -0.5 * width + (k as f32 + 0.5) * piece;
            for s in [middle - node, middle + node] {
                let shift = [normal[0] * s, normal[1] * s];
                strip.nodes[strip.count] =
                    ClippedSegment::new([a[0] + shift[0], a[1] + shift[1]], [b[0] + shift[0], b[1] + shift[1]]);
                strip.count += 1;
            }
        }
        strip
    }

    /// The strip's area inside the unit square at `pixel` over its width
    /// (see [`strip_pixel_coverage`]); 0 for a degenerate segment.
    pub fn coverage(&self, pixel: [f32; 2]) -> f32 {
        if self.count == 0 {
            return 0.0;
        }
        let mut sum = 0.0;
        for node in &self.nodes[..self.count] {
            sum += node.length_in_pixel(pixel);
        }
        sum / self.count as f32
    }
}

/// How many pieces [`strip_pixel_coverage`] cuts a strip of `width`
/// (pixels, at most 1) into: one per quarter pixel, at least one.
pub fn strip_pieces(width: f32) -> u32 {
    ((width.clamp(0.0, 1.0) * 4.0).ceil() as u32).max(1)
}

/// Corner `corner` (0–5: two triangles) of the quad drawn for the segment
/// `a`–`b` (pixels) whose strip is `width` wide: each end pushed out along
/// the segment, and to either side, by `width/2 + LINE_QUAD_MARGIN`.
/// Corners 0, 3 lie at `a`'s right, 1 at `b`'s right, 2, 4 at `b`'s left, 5
/// at `a`'s left (right of the direction `a → b`). A segment shorter than
/// a millionth of a pixel is taken along x.
pub fn line_quad_corner(a: [f32; 2], b: [f32; 2], width: f32, corner: u32) -> [f32; 2] {
    let (at_b, left) = line_quad_corner_ends(corner);
    let along = quad_direction(a, b);
    let reach = 0.5 * width.clamp(0.0, MAX_STRIP_WIDTH) + LINE_QUAD_MARGIN;
    let (end, sign_along) = if at_b { (b, 1.0) } else { (a, -1.0) };
    let sign_across = if left { 1.0 } else { -1.0 };
    let across = [-along[1], along[0]];
    [
        end[0] + reach * (sign_along * along[0] + sign_across * across[0]),
        end[1] + reach * (sign_along * along[1] + sign_across * across[1]),
    ]
}

/// Corner `corner` (0–5, as [`line_quad_corner`]) of the quad a shadow
/// view draws for the segment `a`–`b` (texels) whose strip is `width`
/// wide (at most [`MAX_STRIP_WIDTH`]): the strip itself, at least a texel
/// wide, its ends exact. A shadow view keeps each texel whose centre the
/// quad covers with the line's opacity (hashed), and a strip thinner than
/// a texel has its width as its opacity, so the texels kept cover the
/// strip's area times its opacity on average, with no fragment off it
/// (where a camera's quad reaches [`LINE_QUAD_MARGIN`] past the strip to
/// cover each pixel by its exact area).
pub fn shadow_line_quad_corner(a: [f32; 2], b: [f32; 2], width: f32, corner: u32) -> [f32; 2] {
    let (at_b, left) = line_quad_corner_ends(corner);
    let along = quad_direction(a, b);
    let half_width = 0.5 * width.clamp(0.0, MAX_STRIP_WIDTH).max(1.0);
    let end = if at_b { b } else { a };
    let sign_across = if left { 1.0 } else { -1.0 };
    let across = [-along[1], along[0]];
    [
        end[0] + half_width * sign_across * across[0],
        end[1] + half_width * sign_across * across[1],
    ]
}

/// The unit direction `a → b` a line's quad is laid along: along x for a
/// segment shorter than a millionth of a pixel.
fn quad_direction(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    let d = [b[0] - a[0], b[1] - a[1]];
    let length = (d[0] * d[0] + d[1] * d[1]).sqrt();
    if length > 1e-6 {
        [d[0] / length, d[1] / length]
    } else {
        [1.0, 0.0]
    }
}

/// Which end (`true`: `b`) and side (`true`: left) a quad corner lies at.
pub fn line_quad_corner_ends(corner: u32) -> (bool, bool) {
    match corner % 6 {
        0 | 3 => (false, false),
        1 => (true, false),
        2 | 4 => (true, true),
        _ => (false, true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The strip's exact area in the pixel over its width, from a dense
    /// grid of point samples.
    fn sampled(a: [f32; 2], b: [f32; 2], width: f32, pixel: [f32; 2]) -> f32 {
        let n = 160;
        let d = [b[0] - a[0], b[1] - a[1]];
        let length = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let mut inside = 0u32;
        for i in 0..n {
            for j in 0..n {
                let p = [
                    pixel[0] + (i as f32 + 0.5) / n as f32,
                    pixel[1] + (j as f32 + 0.5) / n as f32,
                ];
                let r = [p[0] - a[0], p[1] - a[1]];
                let t = (r[0] * d[0] + r[1] * d[1]) / length;
                let s = (-r[0] * d[1] + r[1] * d[0]) / length;
                if (0.0..=length).contains(&t) && s.abs() <= 0.5 * width {
                    inside += 1;
                }
            }
        }
        inside as f32 / (n * n) as f32 / width
    }

    fn distance_to_segment(a: [f32; 2], b: [f32; 2], p: [f32; 2]) -> f32 {
        let d = [b[0] - a[0], b[1] - a[1]];
        let dd = d[0] * d[0] + d[1] * d[1];
        let t = if dd > 0.0 {
            (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / dd).clamp(0.0, 1.0)
        } else {
            0.0
        };
        ((p[0] - a[0] - t * d[0]).powi(2) + (p[1] - a[1] - t * d[1]).powi(2)).sqrt()
    }

    /// Whether `p` lies in the quad's two triangles.
    fn in_quad(a: [f32; 2], b: [f32; 2], width: f32, p: [f32; 2]) -> bool {
        let corners: Vec<[f32; 2]> = (0..6).map(|k| line_quad_corner(a, b, width, k)).collect();
        let in_triangle = |t: &[[f32; 2]]| {
            let side = |u: [f32; 2], v: [f32; 2]| (v[0] - u[0]) * (p[1] - u[1]) - (v[1] - u[1]) * (p[0] - u[0]);
            let s = [side(t[0], t[1]), side(t[1], t[2]), side(t[2], t[0])];
            s.iter().all(|&x| x >= -1e-4) || s.iter().all(|&x| x <= 1e-4)
        };
        in_triangle(&corners[0..3]) || in_triangle(&corners[3..6])
    }

    #[test]
    fn a_joint_inside_a_pixel_leaves_no_pale_stripe() {
        // A 3-pixel-wide horizontal strip cut at x = 5.5, through the
        // centres of column 5: each piece covers half of pixel (5, 4).
        let (a, joint, b) = ([1.0, 4.5], [5.5, 4.5], [10.0, 4.5]);
        let pixel = [5.0, 4.0];
        let (end_joined, start_joined) = (
            LineJoints {
                start: false,
                end: true,
            },
            LineJoints {
                start: true,
                end: false,
            },
        );
        let open = [
            line_pixel_coverage(a, joint, 1.0, 3.0, pixel),
            line_pixel_coverage(joint, b, 1.0, 3.0, pixel),
        ];
        assert!((open[0] - 0.5).abs() < 1e-5 && (open[1] - 0.5).abs() < 1e-5, "{open:?}");
        // Blended as independent layers: three quarters, a pale stripe.
        assert!((1.0 - (1.0 - open[0]) * (1.0 - open[1]) - 0.75).abs() < 1e-5);
        let joined = [
            joined_line_pixel_coverage(a, joint, 1.0, 3.0, end_joined, pixel),
            joined_line_pixel_coverage(joint, b, 1.0, 3.0, start_joined, pixel),
        ];
        // The centre (5.5, 4.5) is the second piece's: it covers the pixel whole.
        assert_eq!(joined[0], 0.0);
        assert!((joined[1] - 1.0).abs() < 1e-5, "{joined:?}");
        // Open ends stay square; a thin line keeps its rule.
        assert_eq!(
            joined_line_pixel_coverage(a, joint, 1.0, 3.0, end_joined, [0.0, 4.0]),
            line_pixel_coverage(a, joint, 1.0, 3.0, [0.0, 4.0])
        );
        assert_eq!(
            joined_line_pixel_coverage(joint, b, 0.6, 0.8, start_joined, pixel),
            line_pixel_coverage(joint, b, 0.6, 0.8, pixel)
        );
    }

    #[test]
    fn a_segment_inside_one_pixel_gives_it_its_length() {
        let length = segment_length_in_pixel([3.2, 5.3], [3.8, 5.6], [3.0, 5.0]);
        assert!((length - (0.36f32 + 0.09).sqrt()).abs() < 1e-6);
        assert_eq!(segment_length_in_pixel([3.2, 5.3], [3.8, 5.6], [4.0, 5.0]), 0.0);
        // A horizontal segment through a row gives each square one pixel.
        assert!((segment_length_in_pixel([0.0, 2.5], [10.0, 2.5], [4.0, 2.0]) - 1.0).abs() < 1e-6);
        assert_eq!(segment_length_in_pixel([0.0, 2.5], [10.0, 2.5], [4.0, 3.0]), 0.0);
    }

    #[test]
    fn a_diagonal_line_splits_its_coverage_where_it_crosses() {
        // From (0.5, 0.2) to (2.5, 1.2): y = 1 at x = 2.1, so through
        // pixels (0,0), (1,0), (2,0), (2,1).
        let (a, b) = ([0.5, 0.2], [2.5, 1.2]);
        let per_pixel: Vec<f32> = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0]]
            .iter()
            .map(|&p| strip_pixel_coverage(a, b, 0.01, p))
            .collect();
        let slope = (1.0f32 + 0.25).sqrt();
        // x 0.5–1 in (0,0); 1–2 in (1,0); 2–2.1 in (2,0); 2.1–2.5 in (2,1).
        for (got, want) in per_pixel
            .iter()
            .zip([0.5 * slope, 1.0 * slope, 0.1 * slope, 0.4 * slope])
        {
            assert!((got - want).abs() < 1e-3, "{per_pixel:?}");
        }
        assert_eq!(strip_pixel_coverage(a, b, 0.01, [1.0, 1.0]), 0.0);
    }

    proptest! {
        /// A line wider than a pixel covers the pixels inside its strip
        /// wholly (times its opacity) and, summed, its strip's area times
        /// its opacity; a thinner one keeps the thin rule, and at a width
        /// of one pixel both rules agree.
        #[test]
        fn a_wide_line_covers_its_strips_area(
            ax in 2.0f32..6.0, ay in 2.0f32..6.0, angle in 0.0f32..std::f32::consts::TAU, length in 1.0f32..5.0,
            width in 1.01f32..3.5, opacity in 0.05f32..0.7,
        ) {
            let a = [ax, ay];
            let b = [ax + length * angle.cos(), ay + length * angle.sin()];
            let (mut sum, mut thin_sum) = (0.0, 0.0);
            for x in -6..14 {
                for y in -6..14 {
                    let pixel = [x as f32, y as f32];
                    let got = line_pixel_coverage(a, b, opacity, width, pixel);
                    prop_assert!((0.0..=opacity + 1e-6).contains(&got));
                    // Exact: the area a dense grid of samples finds; nothing
                    // in a square the rectangle does not reach.
                    if distance_to_segment(a, b, [pixel[0] + 0.5, pixel[1] + 0.5]) > 0.5 * width + 0.75 {
                        prop_assert_eq!(got, 0.0);
                    } else {
                        let want = opacity * width * sampled(a, b, width, pixel);
                        prop_assert!((got - want).abs() < 0.01, "pixel {pixel:?}: {got} vs {want}");
                    }
                    sum += got;
                    // Wholly inside the strip (its square's corners within
                    // the half width, off the ends): the opacity itself.
                    let corners = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]].map(|c| [pixel[0] + c[0], pixel[1] + c[1]]);
                    let d = [b[0] - a[0], b[1] - a[1]];
                    let inside = corners.iter().all(|p| {
                        let r = [p[0] - a[0], p[1] - a[1]];
                        let t = (r[0] * d[0] + r[1] * d[1]) / length;
                        let s = (-r[0] * d[1] + r[1] * d[0]) / length;
                        (0.0..=length).contains(&t) && s.abs() <= 0.5 * width
                    });
                    if inside {
                        prop_assert!((got - opacity).abs() < 1e-3, "pixel {pixel:?} inside: {got}");
                    }
                    let thin = line_pixel_coverage(a, b, opacity, 0.5, pixel);
                    prop_assert!((thin - (opacity * strip_pixel_coverage(a, b, opacity, pixel)).min(1.0)).abs() < 1e-6);
                    thin_sum += thin;
                    // At a width of one pixel the wide rule is the thin one
                    // at full opacity, within the thin rule's quadrature.
                    let at_one = line_pixel_coverage(a, b, 1.0, 1.0, pixel);
                    prop_assert!((at_one - line_pixel_coverage(a, b, 1.0, 1.0 + 1e-4, pixel)).abs() < 0.075);
                }
            }
            prop_assert!((sum - opacity * width * length).abs() < 2e-3 * width * length, "{sum} vs {}", opacity * width * length);
            prop_assert!((thin_sum - opacity * length).abs() < 2e-3 * length);
        }

        /// A shadow view's quad (the strip, at least a texel wide) holds the
        /// centres of as many texels as its area on average over where the
        /// segment falls, so its texels kept with the line's opacity (a
        /// thin strip's being its width) cover the strip's area times its
        /// opacity, as the camera's exact coverage does.
        #[test]
        fn a_shadow_quad_keeps_its_strips_area(
            angle in 0.0f32..std::f32::consts::TAU, length in 2.0f32..12.0, width in 0.05f32..10.0,
        ) {
            let along = [angle.cos(), angle.sin()];
            let (mut centres, offsets) = (0u32, 16);
            // The segment starts at the middles of 16 × 16 steps across a
            // texel: from the steps' starts, an axis-aligned quad (angle 0)
            // has its edges on texel centres, which the inclusive test
            // below counts on both sides where a rasterizer's fill rule
            // counts them once (0.1096 texels kept for a strip of 0.1 at
            // angle 0, length 2, width 0.05).
            for i in 0..offsets {
                for j in 0..offsets {
                    let a = [20.0 + (i as f32 + 0.5) / offsets as f32, 20.0 + (j as f32 + 0.5) / offsets as f32];
                    let b = [a[0] + length * along[0], a[1] + length * along[1]];
                    let corners = [0, 1, 2, 5].map(|c| shadow_line_quad_corner(a, b, width, c));
                    for x in 0..48 {
                        for y in 0..48 {
                            let p = [x as f32 + 0.5, y as f32 + 0.5];
                            // On one side of every edge, whichever way the
                            // corners wind.
                            let sides = [0, 1, 2, 3].map(|k| {
                                let (u, v) = (corners[k], corners[(k + 1) % 4]);
                                (v[0] - u[0]) * (p[1] - u[1]) - (v[1] - u[1]) * (p[0] - u[0])
                            });
                            let inside = sides.iter().all(|&c| c >= 0.0) || sides.iter().all(|&c| c <= 0.0);
                            centres += u32::from(inside);
                        }
                    }
                }
            }
            let strip = width.min(MAX_STRIP_WIDTH);
            let mean = centres as f32 / (offsets * offsets) as f32;
            // Kept with the opacity: a strip under a texel wide is drawn a
            // texel wide at its width's opacity.
            let kept = mean * strip.min(1.0);
            let want = strip * length;
            prop_assert!((kept - want).abs() <= 0.02 * want, "{kept} texels kept for a strip of {want}");
        }

        /// A wide straight strip drawn as pieces end to end, each joined to
        /// the next, covers every pixel as the whole strip does, each pixel
        /// by one piece alone (blending composes nothing), however short
        /// the inner pieces (an open end has at least 0.75 px of strip
        /// behind it, past a pixel's reach from any joint).
        #[test]
        fn joined_pieces_cover_as_one_strip(
            ax in 2.0f32..6.0, ay in 2.0f32..6.0, angle in 0.0f32..std::f32::consts::TAU, length in 1.6f32..8.0,
            width in 1.01f32..4.0, opacity in 0.05f32..1.0, mut cuts in proptest::collection::vec(0.0f32..1.0, 1..6),
            axis_aligned in proptest::bool::ANY,
        ) {
            let angle = if axis_aligned { (angle / std::f32::consts::FRAC_PI_2).round() * std::f32::consts::FRAC_PI_2 } else { angle };
            cuts.sort_by(f32::total_cmp);
            let along = [angle.cos(), angle.sin()];
            let at = |t: f32| [ax + t * along[0], ay + t * along[1]];
            let mut stops = vec![0.0];
            stops.extend(cuts.iter().map(|c| 0.75 + c * (length - 1.5)));
            stops.push(length);
            let pieces = stops.len() - 1;
            for x in -8..18 {
                for y in -8..18 {
                    let pixel = [x as f32, y as f32];
                    let whole = line_pixel_coverage(at(0.0), at(length), opacity, width, pixel);
                    let covering: Vec<f32> = (0..pieces)
                        .map(|k| {
                            let joints = LineJoints { start: k > 0, end: k + 1 < pieces };
                            joined_line_pixel_coverage(at(stops[k]), at(stops[k + 1]), opacity, width, joints, pixel)
                        })
                        .filter(|&c| c > 0.0)
                        .collect();
                    prop_assert!(covering.len() <= 1, "pixel {pixel:?}: {covering:?}");
                    let got = covering.first().copied().unwrap_or(0.0);
                    prop_assert!((got - whole).abs() < 2e-3, "pixel {pixel:?}: {got} vs {whole}");
                }
            }
        }

        /// The nodes follow the strip's exact area in a pixel within a few
        /// hundredths of a pixel (exact where the strip crosses no corner),
        /// and summed over the pixels it keeps the segment's length.
        #[test]
        fn a_strip_covers_each_pixel_by_its_area_there(
            ax in 2.0f32..6.0, ay in 2.0f32..6.0, angle in 0.0f32..std::f32::consts::TAU, length in 0.3f32..4.0, width in 0.01f32..1.0,
            axis_aligned in proptest::bool::ANY,
        ) {
            // Trunks and branches run along pixel columns and rows.
            let angle = if axis_aligned { (angle / std::f32::consts::FRAC_PI_2).round() * std::f32::consts::FRAC_PI_2 } else { angle };
            let a = [ax, ay];
            let b = [ax + length * angle.cos(), ay + length * angle.sin()];
            let mut sum = 0.0;
            for x in -4..12 {
                for y in -4..12 {
                    let pixel = [x as f32, y as f32];
                    let got = strip_pixel_coverage(a, b, width, pixel);
                    sum += got;
                    if distance_to_segment(a, b, [pixel[0] + 0.5, pixel[1] + 0.5]) > 0.5 * width + 0.75 {
                        prop_assert_eq!(got, 0.0);
                        continue;
                    }
                    let want = sampled(a, b, width, pixel);
                    // As coverage (times the width): within 0.075 of a pixel
                    // (a node 1/(2√3) of a quarter pixel off a column's edge).
                    prop_assert!(width * (got - want).abs() < 0.075, "pixel {pixel:?}: {got} vs {want}");
                }
            }
            prop_assert!((sum - length).abs() < 1e-3 * length.max(1.0), "sum {sum} vs length {length}");
        }

        /// Every MSAA sample (4×, Vulkan's standard positions) of every
        /// pixel the strip touches lies in the quad: the pixel's coverage is
        /// written whole.
        #[test]
        fn the_quad_holds_every_sample_of_every_pixel_the_strip_touches(
            ax in 3.0f32..5.0, ay in 3.0f32..5.0, angle in 0.0f32..std::f32::consts::TAU, length in 0.0f32..3.0, width in 0.0f32..3.0,
        ) {
            let a = [ax, ay];
            let b = [ax + length * angle.cos(), ay + length * angle.sin()];
            let samples = [[0.375, 0.125], [0.875, 0.375], [0.125, 0.625], [0.625, 0.875], [0.5, 0.5]];
            for x in -1..11 {
                for y in -1..11 {
                    let pixel = [x as f32, y as f32];
                    // Every pixel whose square reaches the strip (a superset
                    // of those it covers).
                    if distance_to_segment(a, b, [pixel[0] + 0.5, pixel[1] + 0.5]) <= 0.5 * width + std::f32::consts::FRAC_1_SQRT_2 {
                        for s in samples {
                            let p = [pixel[0] + s[0], pixel[1] + s[1]];
                            prop_assert!(in_quad(a, b, width, p), "sample {p:?} of {pixel:?}");
                        }
                    }
                }
            }
        }
    }
}
