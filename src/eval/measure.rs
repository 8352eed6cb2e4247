//! Image measures of `conifer eval`, free of Bevy: box-filtered
//! supersampling, the tree's screen box, coverage and colour errors,
//! picture change along a dolly, and popping statistics.
//!
//! Pictures are RGBA8 renders of one tree over a plain background whose
//! alpha channel is the tree's coverage (the clear colour has alpha 0, and
//! blending accumulates `a + (1 − a)·dst`), while the colour channels are
//! already composited over the background.

use crate::preview::{linear_to_srgb, srgb_to_linear};
use glam::{Mat4, Vec3, Vec4Swizzles};
use image::RgbaImage;

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PixelRect {
    /// First column.
    pub x0: u32,
    /// First row.
    pub y0: u32,
    /// One past the last column.
    pub x1: u32,
    /// One past the last row.
    pub y1: u32,
}

impl PixelRect {
    /// The whole of a `width × height` image.
    pub fn full(width: u32, height: u32) -> Self {
        Self {
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
        }
    }

    /// Pixels inside (0 when empty).
    pub fn area(&self) -> u64 {
        u64::from(self.x1.saturating_sub(self.x0)) * u64::from(self.y1.saturating_sub(self.y0))
    }

    /// The smallest rectangle holding both.
    pub fn union(&self, other: &PixelRect) -> PixelRect {
        PixelRect {
            x0: self.x0.min(other.x0),
            y0: self.y0.min(other.y0),
            x1: self.x1.max(other.x1),
            y1: self.y1.max(other.y1),
        }
    }

    /// Every pixel inside, row by row.
    pub fn pixels(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        (self.y0..self.y1).flat_map(move |y| (self.x0..self.x1).map(move |x| (x, y)))
    }
}

/// The screen rectangle of the box `[min, max]` seen from `eye` looking at
/// `target` (up +Y) with vertical field of view `fov_y` on a
/// `width × height` picture, widened by one pixel and clamped to the
/// picture. A box reaching behind the camera gets the whole picture.
pub fn screen_rect(min: Vec3, max: Vec3, eye: Vec3, target: Vec3, fov_y: f32, width: u32, height: u32) -> PixelRect {
    let full = PixelRect::full(width, height);
    if width == 0 || height == 0 || !(min.is_finite() && max.is_finite() && eye.is_finite()) {
        return full;
    }
    let view = Mat4::look_at_rh(eye, target, Vec3::Y);
    let projection = Mat4::perspective_rh(fov_y, width as f32 / height as f32, 1e-3, 1e6);
    let clip_from_world = projection * view;
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
    for k in 0..8 {
        let corner = Vec3::new(
            if k & 1 == 0 { min.x } else { max.x },
            if k & 2 == 0 { min.y } else { max.y },
            if k & 4 == 0 { min.z } else { max.z },
        );
        let clip = clip_from_world * corner.extend(1.0);
        if clip.w <= 1e-6 {
            return full;
        }
        let ndc = clip.xy() / clip.w;
        let pixel = glam::Vec2::new((ndc.x + 1.0) * 0.5 * width as f32, (1.0 - ndc.y) * 0.5 * height as f32);
        lo = lo.min(pixel);
        hi = hi.max(pixel);
    }
    let clamp = |v: f32, limit: u32| (v.max(0.0) as u32).min(limit);
    PixelRect {
        x0: clamp(lo.x.floor() - 1.0, width),
        y0: clamp(lo.y.floor() - 1.0, height),
        x1: clamp(hi.x.ceil() + 1.0, width),
        y1: clamp(hi.y.ceil() + 1.0, height),
    }
}

/// `image` reduced by `factor` in each direction with a box filter (the mean
/// of each `factor × factor` block), colour averaged in linear light, alpha
/// averaged as it is. The size is rounded down; `factor` 0 or 1 returns a
/// copy.
pub fn downsample(image: &RgbaImage, factor: u32) -> RgbaImage {
    if factor <= 1 {
        return image.clone();
    }
    let (width, height) = (image.width() / factor, image.height() / factor);
    let lut: Vec<f32> = (0..=255u8).map(srgb_to_linear).collect();
    let samples = (factor * factor) as f32;
    RgbaImage::from_fn(width, height, |x, y| {
        let mut sum = [0.0f32; 4];
        for dy in 0..factor {
            for dx in 0..factor {
                let p = image.get_pixel(x * factor + dx, y * factor + dy).0;
                for c in 0..3 {
                    sum[c] += lut[p[c] as usize];
                }
                sum[3] += f32::from(p[3]);
            }
        }
        image::Rgba([
            linear_to_srgb(sum[0] / samples),
            linear_to_srgb(sum[1] / samples),
            linear_to_srgb(sum[2] / samples),
            (sum[3] / samples).round() as u8,
        ])
    })
}

/// Whether `a` and `b` can be compared over `rect`: the same size, and
/// `rect` inside them and not empty.
pub fn check_sizes(a: &RgbaImage, b: &RgbaImage, rect: &PixelRect) -> Result<(), MeasureError> {
    if a.dimensions() != b.dimensions() {
        return Err(MeasureError::SizeMismatch(a.dimensions(), b.dimensions()));
    }
    if rect.x1 > a.width() || rect.y1 > a.height() {
        return Err(MeasureError::RectOutside);
    }
    if rect.area() == 0 {
        return Err(MeasureError::EmptyRect);
    }
    Ok(())
}

/// Why two pictures cannot be compared.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MeasureError {
    /// The pictures differ in size.
    #[error("pictures differ in size: {0:?} and {1:?}")]
    SizeMismatch((u32, u32), (u32, u32)),
    /// The rectangle reaches outside the pictures.
    #[error("the rectangle reaches outside the pictures")]
    RectOutside,
    /// The rectangle holds no pixel.
    #[error("the rectangle is empty")]
    EmptyRect,
}

/// Mean absolute difference of coverage (alpha / 255) over `rect`, in [0, 1].
pub fn coverage_error(reference: &RgbaImage, test: &RgbaImage, rect: &PixelRect) -> Result<f64, MeasureError> {
    check_sizes(reference, test, rect)?;
    let sum: u64 = rect
        .pixels()
        .map(|(x, y)| u64::from(reference.get_pixel(x, y).0[3].abs_diff(test.get_pixel(x, y).0[3])))
        .sum();
    Ok(sum as f64 / (255.0 * rect.area() as f64))
}

/// Sum of the absolute differences of two pixels' RGB channels.
fn rgb_difference(a: [u8; 4], b: [u8; 4]) -> u64 {
    (0..3).map(|c| u64::from(a[c].abs_diff(b[c]))).sum()
}

/// Mean absolute difference of the RGB channels over `rect`, 0–255.
pub fn color_error(reference: &RgbaImage, test: &RgbaImage, rect: &PixelRect) -> Result<f64, MeasureError> {
    check_sizes(reference, test, rect)?;
    let sum: u64 = rect
        .pixels()
        .map(|(x, y)| {
            let (a, b) = (reference.get_pixel(x, y).0, test.get_pixel(x, y).0);
            rgb_difference(a, b)
        })
        .sum();
    Ok(sum as f64 / (3.0 * rect.area() as f64))
}

/// Reference coverage from which a pixel is in the crown's outline
/// ([`crown_color_error`]): 10 %.
pub const CROWN_COVERAGE: u8 = 26;

/// Mean absolute difference of the RGB channels, 0–255, over the pixels of
/// `rect` the reference's crown covers (coverage at least
/// [`CROWN_COVERAGE`]): the colour of the tree itself, not diluted by the
/// background round it as [`color_error`]'s box is. 0 when the reference
/// covers none.
pub fn crown_color_error(reference: &RgbaImage, test: &RgbaImage, rect: &PixelRect) -> Result<f64, MeasureError> {
    check_sizes(reference, test, rect)?;
    let (sum, count) = rect
        .pixels()
        .map(|(x, y)| (reference.get_pixel(x, y).0, test.get_pixel(x, y).0))
        .filter(|(a, _)| a[3] >= CROWN_COVERAGE)
        .fold((0u64, 0u64), |(sum, count), (a, b)| {
            (sum + rgb_difference(a, b), count + 1)
        });
    Ok(if count == 0 {
        0.0
    } else {
        sum as f64 / (3.0 * count as f64)
    })
}

/// [`crown_shade_error`]: the crown's colour error with the coverage
/// difference taken out.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CrownShade {
    /// Mean absolute difference of the RGB channels, 0–255, over the crown
    /// pixels the test covers too, each test pixel's own colour composited
    /// with the reference's coverage.
    pub error: f64,
    /// Share of the crown's pixels that were compared (the test covers at
    /// least [`CROWN_COVERAGE`] of them), in [0, 1]; 0 when none.
    pub compared: f64,
}

/// The part of [`crown_color_error`] that is the tree's colour and not its
/// coverage. A pixel's colour is `a·c + (1 − a)·b` in linear light (`c` the
/// tree's own colour, `b` the plain `background`, given in sRGB 0–1, `a`
/// the coverage in alpha); on a light background a coverage difference of
/// 0.05 alone moves a dark crown's pixel by ~10 of 255. Here each test
/// pixel's `c` is unmixed, `c = (p − (1 − a)·b) / a`, composited again
/// with the reference's coverage and compared with the reference, over the
/// crown's pixels (reference coverage ≥ [`CROWN_COVERAGE`]) that the test
/// also covers by as much: a test that differs only in coverage scores ~0
/// (8-bit rounding: up to ~2 of 255 where both cover little), one that
/// differs only in colour scores its
/// [`crown_color_error`].
pub fn crown_shade_error(
    reference: &RgbaImage,
    test: &RgbaImage,
    rect: &PixelRect,
    background: [f32; 3],
) -> Result<CrownShade, MeasureError> {
    check_sizes(reference, test, rect)?;
    let background = background.map(|c| srgb_to_linear((c.clamp(0.0, 1.0) * 255.0).round() as u8));
    let (mut sum, mut compared, mut crown) = (0u64, 0u64, 0u64);
    for (x, y) in rect.pixels() {
        let (a, b) = (reference.get_pixel(x, y).0, test.get_pixel(x, y).0);
        if a[3] < CROWN_COVERAGE {
            continue;
        }
        crown += 1;
        if b[3] < CROWN_COVERAGE {
            continue;
        }
        compared += 1;
        let (reference_alpha, test_alpha) = (f32::from(a[3]) / 255.0, f32::from(b[3]) / 255.0);
        let recomposited: [u8; 4] = std::array::from_fn(|c| {
            if c == 3 {
                return a[3];
            }
            let own = ((srgb_to_linear(b[c]) - (1.0 - test_alpha) * background[c]) / test_alpha).clamp(0.0, 1.0);
            linear_to_srgb(reference_alpha * own + (1.0 - reference_alpha) * background[c])
        });
        sum += rgb_difference(a, recomposited);
    }
    Ok(CrownShade {
        error: if compared == 0 {
            0.0
        } else {
            sum as f64 / (3.0 * compared as f64)
        },
        compared: if crown == 0 {
            0.0
        } else {
            compared as f64 / crown as f64
        },
    })
}

/// [`coverage_bias`]: where a picture covers more or less than the
/// reference, signed, split at the crown's outline.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CoverageBias {
    /// Mean of test coverage minus reference coverage, in [−1, 1], over the
    /// crown's pixels (reference coverage ≥ [`CROWN_COVERAGE`], the pixels
    /// [`crown_color_error`] reads); 0 when there are none.
    pub crown: f64,
    /// The same over the fringe: the pixels of the box the reference covers
    /// by less than [`CROWN_COVERAGE`] where either picture covers anything;
    /// 0 when there are none.
    pub fringe: f64,
    /// Pixels in the crown.
    pub crown_pixels: u64,
    /// Pixels in the fringe.
    pub fringe_pixels: u64,
}

/// The signed coverage difference (test − reference, alpha as coverage)
/// inside the crown's outline and on its fringe ([`CoverageBias`]).
/// [`coverage_error`] is unsigned over the whole box, so a method that
/// over-covers a crown's inside and under-covers its edges can score the
/// same as one that errs at random; a crown pixel's composited colour moves
/// with its coverage on a light background (by ~10 of 255 for 0.05 on a dark
/// crown), so `crown` tells how much of [`crown_color_error`] is coverage
/// and which way.
pub fn coverage_bias(reference: &RgbaImage, test: &RgbaImage, rect: &PixelRect) -> Result<CoverageBias, MeasureError> {
    check_sizes(reference, test, rect)?;
    let (mut crown, mut fringe) = ((0i64, 0u64), (0i64, 0u64));
    for (x, y) in rect.pixels() {
        let (a, b) = (reference.get_pixel(x, y).0[3], test.get_pixel(x, y).0[3]);
        let difference = i64::from(b) - i64::from(a);
        if a >= CROWN_COVERAGE {
            crown = (crown.0 + difference, crown.1 + 1);
        } else if a > 0 || b > 0 {
            fringe = (fringe.0 + difference, fringe.1 + 1);
        }
    }
    let mean = |(sum, count): (i64, u64)| {
        if count == 0 {
            0.0
        } else {
            sum as f64 / (255.0 * count as f64)
        }
    };
    Ok(CoverageBias {
        crown: mean(crown),
        fringe: mean(fringe),
        crown_pixels: crown.1,
        fringe_pixels: fringe.1,
    })
}

/// The background `image` shows: the mean colour, sRGB in `[0, 1]`, of its
/// pixels nothing covers (alpha 0). A camera that renders into a high
/// dynamic range texture tone-maps its clear colour with the picture, so
/// the background is read from the picture rather than taken from the
/// clear colour. `None` when every pixel is covered.
pub fn background_color(image: &RgbaImage) -> Option<[f32; 3]> {
    let (sum, count) = image
        .pixels()
        .filter(|p| p.0[3] == 0)
        .fold(([0u64; 3], 0u64), |(sum, count), p| {
            (std::array::from_fn(|c| sum[c] + u64::from(p.0[c])), count + 1)
        });
    (count > 0).then(|| sum.map(|s| s as f32 / (255.0 * count as f32)))
}

/// The crown's see-through on `image` (its alpha as coverage) within
/// `crown`, the needles' screen box: [`crate::model::look::crown_see_through`].
/// `None` for a blank crown.
pub fn crown_see_through(image: &RgbaImage, crown: &PixelRect) -> Option<f64> {
    let grid = crate::model::look::CoverageGrid {
        width: image.width(),
        height: image.height(),
        coverage: image.pixels().map(|p| f32::from(p.0[3]) / 255.0).collect(),
    };
    let crown = crate::model::look::CrownBox {
        x0: crown.x0,
        y0: crown.y0,
        x1: crown.x1,
        y1: crown.y1,
    };
    crate::model::look::crown_see_through(&grid, crown).map(|s| s.see_through)
}

/// Mean coverage (alpha / 255) over `rect`: 0 for a blank render.
pub fn mean_coverage(image: &RgbaImage, rect: &PixelRect) -> f64 {
    if rect.area() == 0 || rect.x1 > image.width() || rect.y1 > image.height() {
        return 0.0;
    }
    let sum: u64 = rect.pixels().map(|(x, y)| u64::from(image.get_pixel(x, y).0[3])).sum();
    sum as f64 / (255.0 * rect.area() as f64)
}

/// The RGB pixels of `rect`, tightly packed (FLIP's input).
pub fn crop_rgb(image: &RgbaImage, rect: &PixelRect) -> Vec<u8> {
    rect.pixels()
        .flat_map(|(x, y)| {
            let p = image.get_pixel(x, y).0;
            [p[0], p[1], p[2]]
        })
        .collect()
}

/// Popping along a dolly: per step, how much more a method's picture
/// changed than the reference's did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Popping {
    /// Largest excess change over the steps, 0–255 scale.
    pub max: f64,
    /// 99th percentile of the excess change, 0–255 scale.
    pub p99: f64,
    /// Mean excess change over the steps, 0–255 scale (negative where the
    /// method changes less than the reference).
    pub mean: f64,
}

/// Popping statistics of `method_changes[i]` (mean absolute change of the
/// method's picture at step `i` from step `i − 1`) against
/// `reference_changes[i]` (the same for the reference): the excess
/// `method − reference` per step, its maximum, 99th percentile and mean. Steps
/// beyond the shorter list are ignored; no steps give zeros.
pub fn popping(method_changes: &[f64], reference_changes: &[f64]) -> Popping {
    let mut excess: Vec<f64> = method_changes
        .iter()
        .zip(reference_changes)
        .map(|(m, r)| m - r)
        .filter(|d| d.is_finite())
        .collect();
    if excess.is_empty() {
        return Popping::default();
    }
    excess.sort_by(f64::total_cmp);
    Popping {
        max: *excess.last().expect("not empty"),
        p99: percentile_sorted(&excess, 0.99),
        mean: mean(&excess),
    }
}

/// The mean of the finite `values`; 0 for none.
pub fn mean(values: &[f64]) -> f64 {
    let (sum, n) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((0.0, 0usize), |(sum, n), v| (sum + v, n + 1));
    sum / n.max(1) as f64
}

/// The `q`-quantile of sorted `values` (nearest rank); 0 for none.
pub fn percentile_sorted(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let rank = (q.clamp(0.0, 1.0) * values.len() as f64).ceil() as usize;
    values[rank.clamp(1, values.len()) - 1]
}

/// The median of `values` (mean of the middle two for an even count); 0
/// for none.
pub fn median(values: &[f64]) -> f64 {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.is_empty() {
        return 0.0;
    }
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    }
}

/// Distances of a geometric dolly of `steps` pictures from `near` to `far`
/// (both included; at least 2 steps; `near` and `far` positive).
pub fn dolly_distances(near: f32, far: f32, steps: usize) -> Vec<f32> {
    let steps = steps.max(2);
    let (near, far) = (near.max(1e-3), far.max(1e-3));
    let ratio = (far / near).ln();
    (0..steps)
        .map(|k| near * (ratio * k as f32 / (steps - 1) as f32).exp())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgba;

    fn flat(width: u32, height: u32, pixel: [u8; 4]) -> RgbaImage {
        RgbaImage::from_pixel(width, height, Rgba(pixel))
    }

    #[test]
    fn downsample_averages_blocks_in_linear_light() {
        // Half black, half white columns: linear mean 0.5 → sRGB 188.
        let image = RgbaImage::from_fn(4, 4, |x, _| {
            if x % 2 == 0 {
                Rgba([0, 0, 0, 0])
            } else {
                Rgba([255, 255, 255, 255])
            }
        });
        let small = downsample(&image, 2);
        assert_eq!(small.dimensions(), (2, 2));
        for p in small.pixels() {
            assert_eq!(p.0, [188, 188, 188, 128]);
        }
        assert_eq!(downsample(&image, 1), image);
    }

    #[test]
    fn errors_of_known_pictures() {
        let a = flat(4, 4, [100, 100, 100, 255]);
        let mut b = flat(4, 4, [100, 100, 100, 255]);
        let rect = PixelRect::full(4, 4);
        assert_eq!(coverage_error(&a, &b, &rect).unwrap(), 0.0);
        assert_eq!(color_error(&a, &b, &rect).unwrap(), 0.0);
        // One pixel of 16 fully uncovered and 60 levels darker in one channel.
        b.put_pixel(0, 0, Rgba([40, 100, 100, 0]));
        assert!((coverage_error(&a, &b, &rect).unwrap() - 1.0 / 16.0).abs() < 1e-12);
        assert!((color_error(&a, &b, &rect).unwrap() - 60.0 / 48.0).abs() < 1e-12);
        // The crown's colour: only where the reference covers; a background
        // picture (coverage 0) has no crown.
        assert!((crown_color_error(&a, &b, &rect).unwrap() - 60.0 / 48.0).abs() < 1e-12);
        let mut outline = a.clone();
        for x in 0..4 {
            for y in 2..4 {
                outline.put_pixel(x, y, Rgba([200, 200, 200, 0]));
            }
        }
        assert!((crown_color_error(&outline, &b, &rect).unwrap() - 60.0 / 24.0).abs() < 1e-12);
        assert_eq!(crown_color_error(&flat(4, 4, [0; 4]), &b, &rect).unwrap(), 0.0);
        // A rectangle without that pixel sees no error.
        let inner = PixelRect {
            x0: 1,
            y0: 1,
            x1: 4,
            y1: 4,
        };
        assert_eq!(coverage_error(&a, &b, &inner).unwrap(), 0.0);
        assert_eq!(
            coverage_error(&a, &flat(3, 3, [0; 4]), &rect),
            Err(MeasureError::SizeMismatch((4, 4), (3, 3)))
        );
        let empty = PixelRect {
            x0: 2,
            y0: 2,
            x1: 2,
            y1: 3,
        };
        assert_eq!(color_error(&a, &b, &empty), Err(MeasureError::EmptyRect));
        assert_eq!(crown_color_error(&a, &b, &empty), Err(MeasureError::EmptyRect));
        let outside = PixelRect {
            x0: 0,
            y0: 0,
            x1: 5,
            y1: 4,
        };
        assert_eq!(color_error(&a, &b, &outside), Err(MeasureError::RectOutside));
        assert!((mean_coverage(&b, &rect) - 15.0 / 16.0).abs() < 1e-12);
    }

    /// A pixel of a tree of linear colour `own` covering `alpha` of it over
    /// `background` (sRGB 0–1), as the renderer writes it.
    fn composited(own: [f32; 3], alpha: f32, background: [f32; 3]) -> Rgba<u8> {
        let b = background.map(|c| srgb_to_linear((c * 255.0).round() as u8));
        Rgba([
            linear_to_srgb(alpha * own[0] + (1.0 - alpha) * b[0]),
            linear_to_srgb(alpha * own[1] + (1.0 - alpha) * b[1]),
            linear_to_srgb(alpha * own[2] + (1.0 - alpha) * b[2]),
            (alpha * 255.0).round() as u8,
        ])
    }

    #[test]
    fn background_is_read_from_uncovered_pixels() {
        let image = RgbaImage::from_fn(4, 1, |x, _| match x {
            0 => Rgba([10, 20, 30, 255]),
            1 => Rgba([200, 100, 50, 0]),
            2 => Rgba([100, 50, 0, 0]),
            _ => Rgba([0, 0, 0, 128]),
        });
        let background = background_color(&image).unwrap();
        let expected = [150.0 / 255.0, 75.0 / 255.0, 25.0 / 255.0];
        assert!(
            background.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-6),
            "{background:?}"
        );
        assert_eq!(background_color(&flat(2, 2, [9, 9, 9, 1])), None);
    }

    #[test]
    fn crown_shade_takes_coverage_out() {
        let background = [0.92, 0.93, 0.95];
        let rect = PixelRect::full(4, 1);
        let needle = [0.03, 0.09, 0.04];
        let reference = RgbaImage::from_fn(4, 1, |x, _| {
            composited(needle, [1.0, 0.8, 0.5, 0.05][x as usize], background)
        });
        // The same needles, covering a third less: the crown colour error is
        // large, the shade error is 8-bit rounding (a level of the composite,
        // scaled by the coverage ratio, moves the unmixed dark needle most).
        let thinner = RgbaImage::from_fn(4, 1, |x, _| {
            composited(needle, [0.7, 0.55, 0.35, 0.0][x as usize], background)
        });
        let crown = crown_color_error(&reference, &thinner, &rect).unwrap();
        let shade = crown_shade_error(&reference, &thinner, &rect, background).unwrap();
        assert!(crown > 30.0, "{crown}");
        assert!(shade.error < 2.0, "{shade:?}");
        assert!((shade.compared - 1.0).abs() < 1e-12, "{shade:?}");
        // Lighter needles with the reference's coverage: the shade error is
        // the crown colour error.
        let lighter = RgbaImage::from_fn(4, 1, |x, _| {
            composited([0.06, 0.15, 0.05], [1.0, 0.8, 0.5, 0.05][x as usize], background)
        });
        let crown = crown_color_error(&reference, &lighter, &rect).unwrap();
        let shade = crown_shade_error(&reference, &lighter, &rect, background).unwrap();
        assert!(crown > 5.0, "{crown}");
        assert!((shade.error - crown).abs() <= 0.5, "{shade:?} against {crown}");
        // A test that covers under 10 % of a crown pixel is not compared there.
        let sparse = RgbaImage::from_fn(4, 1, |x, _| {
            composited(needle, [1.0, 0.05, 0.5, 0.0][x as usize], background)
        });
        let shade = crown_shade_error(&reference, &sparse, &rect, background).unwrap();
        assert!((shade.compared - 2.0 / 3.0).abs() < 1e-12, "{shade:?}");
        let blank = flat(4, 1, [235, 237, 242, 0]);
        assert_eq!(
            crown_shade_error(&reference, &blank, &rect, background).unwrap(),
            CrownShade {
                error: 0.0,
                compared: 0.0
            }
        );
        assert_eq!(
            crown_shade_error(&reference, &flat(3, 1, [0; 4]), &rect, background),
            Err(MeasureError::SizeMismatch((4, 1), (3, 1)))
        );
    }

    #[test]
    fn coverage_bias_splits_at_the_crowns_outline() {
        let rect = PixelRect::full(5, 1);
        // Crown (≥ 26), crown, fringe, fringe, background.
        let reference = RgbaImage::from_fn(5, 1, |x, _| Rgba([0, 0, 0, [200, 100, 20, 10, 0][x as usize]]));
        // Over-covers the crown by 51 and 0, under-covers the fringe by 20
        // and covers a background pixel nothing covered by 10.
        let test = RgbaImage::from_fn(5, 1, |x, _| Rgba([0, 0, 0, [251, 100, 0, 10, 10][x as usize]]));
        let bias = coverage_bias(&reference, &test, &rect).unwrap();
        assert_eq!((bias.crown_pixels, bias.fringe_pixels), (2, 3));
        assert!((bias.crown - 51.0 / (2.0 * 255.0)).abs() < 1e-12, "{bias:?}");
        assert!(
            (bias.fringe - (-20.0 + 0.0 + 10.0) / (3.0 * 255.0)).abs() < 1e-12,
            "{bias:?}"
        );
        // Against itself: no bias; the background's pixels are in neither part.
        let same = coverage_bias(&reference, &reference, &rect).unwrap();
        assert_eq!(
            same,
            CoverageBias {
                crown: 0.0,
                fringe: 0.0,
                crown_pixels: 2,
                fringe_pixels: 2
            }
        );
        let blank = flat(5, 1, [0; 4]);
        assert_eq!(coverage_bias(&blank, &blank, &rect).unwrap(), CoverageBias::default());
        assert_eq!(
            coverage_bias(&reference, &flat(3, 1, [0; 4]), &rect),
            Err(MeasureError::SizeMismatch((5, 1), (3, 1)))
        );
    }

    proptest::proptest! {
        /// The crown's and the fringe's biases, weighted by their pixels,
        /// sum to the mean signed coverage difference over the box.
        #[test]
        fn coverage_bias_parts_sum_to_the_box(
            pairs in proptest::collection::vec((0u8..=255, 0u8..=255), 1..64),
        ) {
            let width = pairs.len() as u32;
            let rect = PixelRect::full(width, 1);
            let reference = RgbaImage::from_fn(width, 1, |x, _| Rgba([0, 0, 0, pairs[x as usize].0]));
            let test = RgbaImage::from_fn(width, 1, |x, _| Rgba([0, 0, 0, pairs[x as usize].1]));
            let bias = coverage_bias(&reference, &test, &rect).unwrap();
            let signed: f64 = pairs.iter().map(|&(a, b)| (f64::from(b) - f64::from(a)) / 255.0).sum();
            let parts = bias.crown * bias.crown_pixels as f64 + bias.fringe * bias.fringe_pixels as f64;
            proptest::prop_assert!((parts - signed).abs() < 1e-9, "{:?} against {}", bias, signed);
            proptest::prop_assert!(bias.crown.abs() <= 1.0 && bias.fringe.abs() <= 1.0);
        }
    }

    proptest::proptest! {
        /// Whatever the tree's colour and the two coverages (each at least
        /// 30 %), a test that differs only in coverage has a shade error of
        /// a few 8-bit steps at most (rounding, scaled by the coverage ratio).
        #[test]
        fn crown_shade_ignores_coverage(
            own in proptest::array::uniform3(0.0f32..1.0),
            reference_alpha in 0.3f32..1.0,
            test_alpha in 0.3f32..1.0,
            background in proptest::array::uniform3(0.0f32..1.0),
        ) {
            let rect = PixelRect::full(1, 1);
            let reference = RgbaImage::from_pixel(1, 1, composited(own, reference_alpha, background));
            let test = RgbaImage::from_pixel(1, 1, composited(own, test_alpha, background));
            let shade = crown_shade_error(&reference, &test, &rect, background).unwrap();
            proptest::prop_assert!(shade.error <= 4.0, "{:?}", shade);
            proptest::prop_assert_eq!(shade.compared, 1.0);
        }
    }

    #[test]
    fn screen_rect_of_a_centred_box() {
        // A 2 m cube 10 m away, 90° field of view: it spans half of the
        // frustum's width at its near face (distance 9 m → ±9 m visible).
        let rect = screen_rect(
            Vec3::splat(-1.0),
            Vec3::splat(1.0),
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::ZERO,
            90f32.to_radians(),
            180,
            180,
        );
        // Near face at z = 1 (9 m away): ±1/9 of the half-width 90 px = ±10 px,
        // so [80, 100] widened by a pixel (plus float rounding up).
        assert_eq!((rect.x0, rect.y0), (79, 79));
        assert!(
            (101..=102).contains(&rect.x1) && (101..=102).contains(&rect.y1),
            "{rect:?}"
        );
        // A box around the eye gives the whole picture.
        let around = screen_rect(
            Vec3::splat(-20.0),
            Vec3::splat(20.0),
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::ZERO,
            1.0,
            64,
            32,
        );
        assert_eq!(around, PixelRect::full(64, 32));
    }

    #[test]
    fn popping_is_the_excess_change() {
        let reference = [1.0, 1.0, 1.0, 1.0];
        let smooth = [1.1, 0.9, 1.0, 1.2];
        let pops = [1.0, 1.0, 9.0, 1.0];
        let p = popping(&smooth, &reference);
        assert!((p.max - 0.2).abs() < 1e-9);
        let p = popping(&pops, &reference);
        assert_eq!(p.max, 8.0);
        assert_eq!(p.p99, 8.0);
        assert_eq!(p.mean, 2.0);
        assert_eq!(mean(&[1.0, f64::NAN, 3.0]), 2.0);
        assert_eq!(mean(&[]), 0.0);
        assert_eq!(popping(&[], &[]), Popping::default());
        assert_eq!(percentile_sorted(&[1.0, 2.0, 3.0, 4.0], 0.5), 2.0);
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
    }

    #[test]
    fn dolly_is_geometric_and_includes_both_ends() {
        let d = dolly_distances(10.0, 1000.0, 3);
        assert_eq!(d.len(), 3);
        assert!((d[0] - 10.0).abs() < 1e-4 && (d[1] - 100.0).abs() < 1e-2 && (d[2] - 1000.0).abs() < 1e-1);
        assert_eq!(dolly_distances(5.0, 50.0, 0).len(), 2);
    }
}
