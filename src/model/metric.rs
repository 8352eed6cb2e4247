//! Error math of the paper: the spatial error of a view, the prism side count
//! of a needle, and the opacity of its line.
//!
//! All functions are total: non-finite or out-of-range inputs give a defined
//! result (documented on each) instead of a panic.

use serde::{Deserialize, Serialize};
use std::f32::consts::PI;

/// Fewest sides a prism may have.
pub const MIN_PRISM_SIDES: u8 = 3;

/// Most sides the bake tool accepts for `Lmax`.
pub const MAX_PRISM_SIDES: u8 = 64;

/// Relative error ρ = e / R at and above which a needle is drawn as a line
/// (the 3-sided prism is already too much detail).
pub const LINE_RELATIVE_ERROR: f32 = 2.0;

/// The user's tolerance in screen space: how many pixels a simplification may
/// move the silhouette (the paper's ε). Larger is faster and coarser.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PixelError(pub f32);

impl Default for PixelError {
    fn default() -> Self {
        Self(1.0)
    }
}

/// What the spatial error of a view depends on, besides distance.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewParams {
    /// Vertical field of view θ, radians.
    pub vertical_fov: f32,
    /// Height W of the view plane, pixels.
    pub viewport_height_px: f32,
    /// Pixel error ε.
    pub pixel_error: PixelError,
}

impl Default for ViewParams {
    /// 45° vertical field of view, 1080 pixels high, ε = 1.
    fn default() -> Self {
        Self {
            vertical_fov: 45f32.to_radians(),
            viewport_height_px: 1080.0,
            pixel_error: PixelError::default(),
        }
    }
}

impl ViewParams {
    /// Spatial error of a tree at `distance` metres; see [`spatial_error`].
    pub fn spatial_error(&self, distance: f32) -> f32 {
        spatial_error(self.pixel_error, distance, self.vertical_fov, self.viewport_height_px)
    }

    /// Metres of spatial error per metre of distance: `e = slope · D`.
    /// `e` is linear in `D`, so every error threshold is also a distance.
    pub fn error_per_distance(&self) -> f32 {
        self.spatial_error(1.0)
    }

    /// The distance at which the spatial error equals `error`
    /// (infinite when the view makes no error at any distance).
    pub fn distance_for_error(&self, error: f32) -> f32 {
        let slope = self.error_per_distance();
        if slope > 0.0 && slope.is_finite() {
            error / slope
        } else {
            f32::INFINITY
        }
    }
}

/// Spatial error threshold of a view (paper, §3.1):
///
/// `e = 2 · ε · D · tan(θ/2) / W`
///
/// with ε the pixel error, `D` the distance from the viewer to the tree, θ the
/// vertical view angle and `W` the height of the view plane in pixels: the
/// size, at distance `D`, of `ε` pixels.
///
/// Defined results: a distance at or below zero (viewer inside the tree) or
/// NaN gives 0 (finest detail); a viewport with no height (zero, negative or
/// NaN) gives `f32::INFINITY` (nothing is visible, so the coarsest is right);
/// a negative or NaN pixel error counts as 0.
pub fn spatial_error(pixel_error: PixelError, distance: f32, vertical_fov: f32, viewport_height_px: f32) -> f32 {
    if viewport_height_px.is_nan() || viewport_height_px <= 0.0 {
        return f32::INFINITY;
    }
    let distance = if distance > 0.0 { distance } else { 0.0 };
    let epsilon = if pixel_error.0 > 0.0 { pixel_error.0 } else { 0.0 };
    let half_angle_tan = (vertical_fov.clamp(0.0, PI - 1e-3) * 0.5).tan();
    let e = 2.0 * epsilon * distance * half_angle_tan / viewport_height_px;
    if e.is_nan() { 0.0 } else { e }
}

/// Relative error ρ = e / R of a needle of radius `radius` under spatial
/// error `spatial_error` (paper, §3.1). A radius of zero gives infinity.
pub fn relative_error(spatial_error: f32, radius: f32) -> f32 {
    if radius > 0.0 {
        spatial_error / radius
    } else {
        f32::INFINITY
    }
}

/// Error of drawing a circle of radius `radius` as an inscribed polygon of
/// `sides` sides: `R · (1 − cos(π/m))` (paper, §3.1).
pub fn prism_error(radius: f32, sides: u8) -> f32 {
    let sides = sides.max(MIN_PRISM_SIDES) as f32;
    radius * (1.0 - (PI / sides).cos())
}

/// Error of drawing a needle of radius `radius` as its centerline: `2R`
/// (paper, §3.2). The error of an original line in the merge forest.
pub fn line_error(radius: f32) -> f32 {
    2.0 * radius
}

/// How a single needle is drawn at a given relative error.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum NeedleForm {
    /// A prism with this many sides.
    Prism {
        /// Side count, in `[3, Lmax]`.
        sides: u8,
    },
    /// Its centerline, a translucent line.
    Line,
}

/// Side count of the prism for a needle at relative error `rho`
/// (paper, §3.1): `n = ⌈π / arccos(1 − ρ)⌉`, clamped to `[3, max_sides]`.
///
/// This is the fewest sides whose [`prism_error`] does not exceed `e`; every
/// `ρ ≥ 0.5` gives 3. `ρ ≤ 0` or NaN gives `max_sides`.
pub fn prism_sides(rho: f32, max_sides: u8) -> u8 {
    let max_sides = max_sides.max(MIN_PRISM_SIDES);
    if rho.is_nan() || rho <= 0.0 {
        return max_sides;
    }
    if rho >= 1.0 {
        return MIN_PRISM_SIDES;
    }
    let n = (PI / (1.0 - rho).acos()).ceil();
    if n.is_finite() {
        (n as u32).clamp(MIN_PRISM_SIDES as u32, max_sides as u32) as u8
    } else {
        max_sides
    }
}

/// The form of a needle at relative error `rho` (paper, §3): a prism of
/// [`prism_sides`] sides while `ρ < 2`, its line from `ρ ≥ 2` on.
pub fn needle_form(rho: f32, max_sides: u8) -> NeedleForm {
    if rho >= LINE_RELATIVE_ERROR {
        NeedleForm::Line
    } else {
        NeedleForm::Prism {
            sides: prism_sides(rho, max_sides),
        }
    }
}

/// Coverage of a merged line whose needles' summed side area, per unit of
/// its length, is `summed_width`, drawn one pixel (`pixel_width`) wide,
/// when the needles lie at random within that footprint: `1 − exp(−w/p)`
/// (the Poisson / Beer–Lambert coverage; `LineOpacity::Coverage`). It
/// matches the area rule `min(w/p, 1)` for sparse bundles and stays below
/// it where needles overlap. Defined results: 0 for NaN, zero or negative
/// widths, 1 for an infinite ratio.
pub fn merged_line_coverage(summed_width: f32, pixel_width: f32) -> f32 {
    let density = summed_width / pixel_width;
    if density.is_nan() || density <= 0.0 {
        return 0.0;
    }
    1.0 - (-density).exp()
}

/// Opacity of an original line at relative error `rho` (paper, §3.2 and §6):
/// `T(ρ) = 2/ρ` for `ρ ≥ 2` (the needle's width over the line's width),
/// times the transition coefficient δ in `(0, 1]` that makes lines more
/// transparent where they take over from prisms.
///
/// Defined results: `ρ < 2` gives `δ` (a line is never more than opaque);
/// `δ` is clamped to `[0, 1]`; NaN inputs give 0.
pub fn line_opacity(rho: f32, transition: f32) -> f32 {
    let transition = if transition.is_nan() {
        0.0
    } else {
        transition.clamp(0.0, 1.0)
    };
    if rho.is_nan() {
        return 0.0;
    }
    let t = if rho <= LINE_RELATIVE_ERROR {
        1.0
    } else {
        LINE_RELATIVE_ERROR / rho
    };
    t * transition
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spatial_error_is_one_pixel_at_distance() {
        // 45°, 1536 px, ε = 1, 12.22 m: the paper's first Table 1 view.
        let e = spatial_error(PixelError(1.0), 12.22, 45f32.to_radians(), 1536.0);
        let expected = 2.0 * 12.22 * (22.5f32.to_radians()).tan() / 1536.0;
        assert!((e - expected).abs() < 1e-9);
        assert!((e - 0.006_59).abs() < 1e-4, "{e}");
    }

    #[test]
    fn spatial_error_defined_cases() {
        let fov = 45f32.to_radians();
        assert_eq!(spatial_error(PixelError(1.0), 10.0, fov, 0.0), f32::INFINITY);
        assert_eq!(spatial_error(PixelError(1.0), 10.0, fov, f32::NAN), f32::INFINITY);
        assert_eq!(spatial_error(PixelError(1.0), -3.0, fov, 1080.0), 0.0);
        assert_eq!(spatial_error(PixelError(1.0), f32::NAN, fov, 1080.0), 0.0);
        assert_eq!(spatial_error(PixelError(f32::NAN), 10.0, fov, 1080.0), 0.0);
    }

    #[test]
    fn distance_for_error_inverts_spatial_error() {
        let view = ViewParams::default();
        let d = view.distance_for_error(0.01);
        assert!((view.spatial_error(d) - 0.01).abs() < 1e-7);
    }

    #[test]
    fn prism_sides_is_fewest_sides_within_error() {
        let radius = 0.001;
        for step in 1..2000 {
            let e = step as f32 * 1e-6;
            let sides = prism_sides(relative_error(e, radius), 8);
            assert!((3..=8).contains(&sides));
            if sides < 8 {
                assert!(prism_error(radius, sides) <= e * (1.0 + 1e-4), "e {e} sides {sides}");
            }
            if sides > 3 {
                assert!(prism_error(radius, sides - 1) > e * (1.0 - 1e-4), "e {e} sides {sides}");
            }
        }
        assert_eq!(prism_sides(0.5, 8), 3);
        assert_eq!(prism_sides(1.5, 8), 3);
        assert_eq!(prism_sides(0.0, 8), 8);
        assert_eq!(prism_sides(f32::NAN, 12), 12);
    }

    #[test]
    fn needle_form_switches_to_line_at_two() {
        assert_eq!(needle_form(1.999, 8), NeedleForm::Prism { sides: 3 });
        assert_eq!(needle_form(2.0, 8), NeedleForm::Line);
        assert_eq!(needle_form(f32::INFINITY, 8), NeedleForm::Line);
    }

    #[test]
    fn merged_line_coverage_stays_under_the_summed_area() {
        for density in [1e-4f32, 0.01, 0.1, 0.5, 1.0, 2.0, 10.0] {
            let coverage = merged_line_coverage(density * 0.02, 0.02);
            assert!(coverage <= density.min(1.0) + 1e-6, "{density}: {coverage}");
            assert!(coverage > 0.0 && coverage < 1.0 + 1e-6);
        }
        // Sparse bundles: the summed area; two needles each covering a
        // quarter of the footprint at random: between 1 − 0.75² and 0.5.
        assert!((merged_line_coverage(1e-3, 1.0) - 1e-3).abs() < 1e-6);
        let pair = merged_line_coverage(0.5, 1.0);
        assert!((0.39..0.4375).contains(&pair), "{pair}");
        assert_eq!(merged_line_coverage(f32::NAN, 1.0), 0.0);
        assert_eq!(merged_line_coverage(1.0, 0.0), 1.0);
        assert_eq!(merged_line_coverage(-1.0, 1.0), 0.0);
    }

    #[test]
    fn line_opacity_is_two_over_rho_times_transition() {
        assert_eq!(line_opacity(2.0, 1.0), 1.0);
        assert!((line_opacity(8.0, 1.0) - 0.25).abs() < 1e-7);
        assert!((line_opacity(8.0, 0.5) - 0.125).abs() < 1e-7);
        assert_eq!(line_opacity(1.0, 0.7), 0.7);
        assert_eq!(line_opacity(f32::NAN, 1.0), 0.0);
        assert_eq!(line_opacity(4.0, 3.0), 0.5);
    }

    #[test]
    fn errors_are_ordered_along_a_needle() {
        let r = 0.0007;
        for sides in 4..=16u8 {
            assert!(prism_error(r, sides) < prism_error(r, sides - 1));
        }
        assert!(prism_error(r, 3) < line_error(r));
    }
}
