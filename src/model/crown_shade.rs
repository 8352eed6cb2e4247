//! A crown's shade on itself past the shadow maps' range, free of Bevy.
//!
//! Bevy's directional shadows end at the last cascade's far bound (80 m in
//! the `forest` example): past it every fragment is fully lit, so a crown
//! there loses its own shade at once. Its far side, lit through metres of
//! needles, reads as bright as its sunlit side, and from a hillside the
//! canopy past the shadows is a pale, even green. Inside the range the
//! crown's lines (or its impostor card) cast its shade into the maps.
//!
//! Past it, the plugin shades a tree's fragments with the crown itself: a
//! body of revolution about the impostor's axis whose radius at each
//! height is [`CrownImpostor::crown_radii`]'s, filled with needles that
//! dim the light. Needles clump in shoots and branches, so one extinction
//! a height will not do: a sunbeam through the crown meets gaps or full
//! clumps. The crown holds [`CROWN_SHADE_CLASSES`] media at each height,
//! each a quarter of its rays (by how dense they are;
//! [`CrownImpostor::crown_extinction`], measured on the impostor's
//! pictures), and a point's light is the mean of what each lets through
//! between it and the sun ([`CrownShade::transmittance`]): `exp(−∫ σₖ(h)
//! ds)` over the part of the ray inside the crown. Over the last
//! cascade's overlap band the shadow maps' shade and the crown's are
//! cross-faded ([`past_shadow_maps`]), so no edge shows where the maps end.
//!
//! Only the tree's own crown shades it there: a neighbour's shadow past
//! the maps' range is still missing.

use glam::{Vec2, Vec3};

use super::impostor::{CROWN_PROFILE_STEPS, CrownImpostor};

/// Steps [`CrownShade::transmittance`] takes along a ray toward the light.
pub const CROWN_SHADE_STEPS: usize = 8;

/// Media a [`CrownShade`] holds at each height, each for an even share of
/// the rays through it, from the clearest to the densest.
pub const CROWN_SHADE_CLASSES: usize = 4;

/// Coverage a texel's optical depth is taken at, at most: a fully covered
/// texel (255 of 255) lets through nothing measurable, and its needles
/// count as letting through a thousandth.
const MAX_COVERAGE: f32 = 0.999;

/// A crown as a body of revolution that dims the light through it (module
/// docs): its axis and height span (the impostor's), and its radius and
/// its media's extinctions at [`CROWN_PROFILE_STEPS`] heights, bottom to
/// top.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CrownShade {
    /// The vertical axis (tree-local `x`, `z`).
    pub axis: Vec2,
    /// Tree-local height of the profile's bottom.
    pub bottom: f32,
    /// Tree-local height of the profile's top.
    pub top: f32,
    /// The crown's radius (tree metres) at each height
    /// ([`CrownImpostor::crown_radii`]).
    pub radii: [f32; CROWN_PROFILE_STEPS],
    /// The extinction (per tree metre) of each of its
    /// [`CROWN_SHADE_CLASSES`] media at each height
    /// ([`CrownImpostor::crown_extinction`]).
    pub extinction: [[f32; CROWN_SHADE_CLASSES]; CROWN_PROFILE_STEPS],
}

impl CrownShade {
    /// The shade of the crown `impostor` pictures.
    pub fn of(impostor: &CrownImpostor) -> Self {
        let radii = impostor.crown_radii();
        Self {
            axis: impostor.axis,
            bottom: impostor.bottom,
            top: impostor.top(),
            radii,
            extinction: impostor.crown_extinction(&radii),
        }
    }

    /// How far inside the crown tree-local `point` lies (metres; negative
    /// outside): the least of its depth inside the radius at its height and
    /// its heights above the bottom and below the top.
    pub fn inside(&self, point: Vec3) -> f32 {
        let radius = CrownImpostor::crown_radius_at(&self.radii, self.bottom, self.top, point.y);
        let distance = (Vec2::new(point.x, point.z) - self.axis).length();
        (radius - distance).min(point.y - self.bottom).min(self.top - point.y)
    }

    /// Its media's extinctions (per tree metre) at tree-local `height`:
    /// linear between the profile's steps, as its radius
    /// ([`CrownImpostor::crown_radius_at`]).
    pub fn extinction_at(&self, height: f32) -> [f32; CROWN_SHADE_CLASSES] {
        std::array::from_fn(|class| {
            let profile = self.extinction.map(|media| media[class]);
            CrownImpostor::crown_radius_at(&profile, self.bottom, self.top, height)
        })
    }

    /// The widest of its radii (tree metres, 0 for an empty profile): the
    /// upright cylinder about the axis that holds the crown. The GPU reads
    /// it from the species' uniform, computed once at upload.
    pub fn widest_radius(&self) -> f32 {
        self.radii.iter().fold(0.0f32, |widest, &r| widest.max(r))
    }

    /// Where the ray from `point` along the unit `toward` crosses the
    /// crown's bounds, the upright cylinder of its widest radius about the
    /// axis between its bottom and top: its distances (tree metres) in and
    /// out, the way in no nearer than `point` itself; `None` where the ray
    /// ahead of `point` never meets them.
    pub fn crossing(&self, point: Vec3, toward: Vec3) -> Option<(f32, f32)> {
        let widest = self.widest_radius();
        let offset = Vec2::new(point.x, point.z) - self.axis;
        let across = Vec2::new(toward.x, toward.z);
        let a = across.length_squared();
        let (side_in, side_out) = if a > 1e-12 {
            let b = offset.dot(across);
            let c = offset.length_squared() - widest * widest;
            let disc = b * b - a * c;
            if disc < 0.0 {
                return None;
            }
            ((-b - disc.sqrt()) / a, (-b + disc.sqrt()) / a)
        } else if offset.length() <= widest {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            return None;
        };
        let (end_in, end_out) = if toward.y.abs() > 1e-6 {
            let (to_bottom, to_top) = ((self.bottom - point.y) / toward.y, (self.top - point.y) / toward.y);
            (to_bottom.min(to_top), to_bottom.max(to_top))
        } else if point.y >= self.bottom && point.y <= self.top {
            (f32::NEG_INFINITY, f32::INFINITY)
        } else {
            return None;
        };
        let (enter, exit) = (side_in.max(end_in).max(0.0), side_out.min(end_out));
        (exit > enter && exit.is_finite()).then_some((enter, exit))
    }

    /// What the crown lets through from tree-local `point` toward a light
    /// along `to_light` (any length): the mean over its media of
    /// `exp(−τₖ)`, `τₖ` the optical depth `Σ σₖ(h)·ℓ` over
    /// [`CROWN_SHADE_STEPS`] even steps of the ray's
    /// [`CrownShade::crossing`], `ℓ` the length of each step inside the
    /// crown ([`CrownShade::inside`] linear along the step, so a point
    /// moving through the crown changes its light smoothly, not by whole
    /// steps) and `σₖ` medium `k`'s extinction at the step's middle. 1 for
    /// a light or point that is not finite, a zero light direction or an
    /// empty profile. CPU reference of the fragment's
    /// `crown_transmittance`.
    pub fn transmittance(&self, point: Vec3, to_light: Vec3) -> f32 {
        let (depths, _) = self.optical_depths(point, to_light, CROWN_SHADE_STEPS);
        depths.iter().map(|d| (-d).exp()).sum::<f32>() / CROWN_SHADE_CLASSES as f32
    }

    /// The optical depths of its media that [`CrownShade::transmittance`]
    /// takes from `point` toward `to_light` in `steps` even steps, and the
    /// steps' length (0 where the ray misses the crown's bounds or the
    /// input is not finite).
    fn optical_depths(&self, point: Vec3, to_light: Vec3, steps: usize) -> ([f32; CROWN_SHADE_CLASSES], f32) {
        let mut depths = [0.0; CROWN_SHADE_CLASSES];
        let length = to_light.length();
        if !(length > 0.0 && length.is_finite() && point.is_finite() && self.top > self.bottom && steps > 0) {
            return (depths, 0.0);
        }
        let toward = to_light / length;
        let Some((enter, exit)) = self.crossing(point, toward) else {
            return (depths, 0.0);
        };
        let step = (exit - enter) / steps as f32;
        let mut before = self.inside(point + toward * enter);
        for k in 1..=steps {
            let after = self.inside(point + toward * (enter + step * k as f32));
            let middle = point + toward * (enter + step * (k as f32 - 0.5));
            let inside = inside_share(before, after) * step;
            for (depth, sigma) in depths.iter_mut().zip(self.extinction_at(middle.y)) {
                *depth += sigma.max(0.0) * inside;
            }
            before = after;
        }
        (depths, step)
    }
}

/// Distances from the axis at which a [`SkyVisibility`] holds the crown's
/// sky: the axis, a third and two thirds of the crown's radius at the
/// height, and its edge.
pub const SKY_VISIBILITY_RINGS: usize = 4;

/// Elevations (evenly spaced, midpoints) and azimuths of the rays
/// [`CrownShade::sky_visibility`] looks at the sky along.
const SKY_ELEVATIONS: usize = 6;
const SKY_AZIMUTHS: usize = 16;

impl CrownShade {
    /// The share of the sky (the upper hemisphere, by solid angle) that
    /// tree-local `point` sees through the crown: the mean of
    /// [`CrownShade::transmittance`] over 96 rays, at 6 evenly spaced
    /// elevations and 16 azimuths, each weighted by its
    /// ring's solid angle (`cos` of its elevation). 1 outside the crown's
    /// reach and for a point that is not finite.
    pub fn sky_visibility(&self, point: Vec3) -> f32 {
        let (mut seen, mut total) = (0.0f32, 0.0f32);
        for e in 0..SKY_ELEVATIONS {
            let elevation = (e as f32 + 0.5) / SKY_ELEVATIONS as f32 * std::f32::consts::FRAC_PI_2;
            let (sin, cos) = elevation.sin_cos();
            for a in 0..SKY_AZIMUTHS {
                let azimuth = (a as f32 + 0.5) / SKY_AZIMUTHS as f32 * std::f32::consts::TAU;
                let toward = Vec3::new(cos * azimuth.cos(), sin, cos * azimuth.sin());
                seen += cos * self.transmittance(point, toward);
                total += cos;
            }
        }
        seen / total
    }

    /// Its [`CrownShade::sky_visibility`] tabled by height (the middles of
    /// the profile's [`CROWN_PROFILE_STEPS`] steps, as its radii) and
    /// distance from the axis ([`SKY_VISIBILITY_RINGS`] shares of the
    /// radius at the height), for the GPU.
    pub fn sky_visibility_table(&self) -> SkyVisibility {
        let mut rows = [[1.0; SKY_VISIBILITY_RINGS]; CROWN_PROFILE_STEPS];
        for (step, row) in rows.iter_mut().enumerate() {
            let height = self.bottom + (step as f32 + 0.5) / CROWN_PROFILE_STEPS as f32 * (self.top - self.bottom);
            let radius = self.radii[step];
            for (ring, value) in row.iter_mut().enumerate() {
                let out = radius * ring as f32 / (SKY_VISIBILITY_RINGS - 1) as f32;
                *value = self.sky_visibility(Vec3::new(self.axis.x + out, height, self.axis.y));
            }
        }
        SkyVisibility { rows }
    }
}

/// How much of the sky a point in a crown sees through its needles
/// ([`CrownShade::sky_visibility`]), by height and distance from the axis:
/// the share of the ambient light that reaches it. Bevy's ambient light
/// is the sky's: it lights a needle deep in a crown as it lights one on
/// its top, and a crown's shaded body then reads a pale grey-green where
/// a real one is nearly black. Rows bottom to top at the middles of the
/// crown profile's steps, rings from the axis out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkyVisibility {
    /// Rows bottom to top, [`SKY_VISIBILITY_RINGS`] rings a row.
    pub rows: [[f32; SKY_VISIBILITY_RINGS]; CROWN_PROFILE_STEPS],
}

impl SkyVisibility {
    /// The share of the sky tree-local `point` sees through `shade`'s
    /// crown: bilinear in the table, linear in height between the steps'
    /// middles as [`CrownImpostor::crown_radius_at`] (clamped at the end
    /// steps) and in distance from the axis over the crown's radius there
    /// (clamped at its edge). 1 for a point that is not finite or a crown
    /// with no height. CPU reference of the fragment's
    /// `sky_visibility_at`.
    pub fn at(&self, shade: &CrownShade, point: Vec3) -> f32 {
        if !(point.is_finite() && shade.top > shade.bottom) {
            return 1.0;
        }
        let (k, t) = CrownImpostor::profile_step(shade.bottom, shade.top, point.y);
        let radius = CrownImpostor::crown_radius_at(&shade.radii, shade.bottom, shade.top, point.y);
        let last = (SKY_VISIBILITY_RINGS - 1) as f32;
        let distance = (Vec2::new(point.x, point.z) - shade.axis).length();
        let ring = if radius > 0.0 {
            (distance / radius * last).clamp(0.0, last)
        } else {
            last
        };
        let j = (ring as usize).min(SKY_VISIBILITY_RINGS - 2);
        let u = ring - j as f32;
        let row = |k: usize| self.rows[k][j] * (1.0 - u) + self.rows[k][j + 1] * u;
        row(k) * (1.0 - t) + row(k + 1) * t
    }

    /// A table that occludes nothing (every entry 1): the GPU's when the
    /// plugin's `ConiferLodSettings::sky_occlusion` is off or the species
    /// has no impostor.
    pub fn open() -> Self {
        Self {
            rows: [[1.0; SKY_VISIBILITY_RINGS]; CROWN_PROFILE_STEPS],
        }
    }
}

/// The share of a step inside the crown when its ends lie `before` and
/// `after` inside it (negative outside), the inside depth linear between
/// them.
fn inside_share(before: f32, after: f32) -> f32 {
    match (before > 0.0, after > 0.0) {
        (true, true) => 1.0,
        (false, false) => 0.0,
        (true, false) => before / (before - after),
        (false, true) => after / (after - before),
    }
}

/// How much of a directional light's shade past its shadow maps comes from
/// the crown ([`CrownShade::transmittance`]) at view depth `depth`
/// (metres, positive ahead of the camera): 0 before the last cascade's
/// overlap band (its last `overlap` share, Bevy's
/// `cascades_overlap_proportion`), rising linearly to 1 at its `far`
/// bound, where Bevy's shadow lookup lets every fragment be fully lit, and
/// 1 past it. A light with no cascade (`far` 0) is all crown. CPU
/// reference of the fragment's `past_shadow_maps`.
pub fn past_shadow_maps(depth: f32, far: f32, overlap: f32) -> f32 {
    if far.is_nan() || far <= 0.0 || depth >= far {
        return 1.0;
    }
    let near = (1.0 - overlap.clamp(0.0, 1.0)) * far;
    if depth.is_nan() || depth <= near {
        return 0.0;
    }
    (depth - near) / (far - near)
}

impl CrownImpostor {
    /// The extinction (per tree metre) of the crown's
    /// [`CROWN_SHADE_CLASSES`] media at [`CROWN_PROFILE_STEPS`] heights (as
    /// [`CrownImpostor::crown_radii`]), measured on the pictures: a texel
    /// whose ray crosses the crown's chord `2√(r² − x²)` at its offset `x`
    /// from the axis (`r` the crown's `radii` at the height) lets through
    /// `1 − coverage` of it, an optical depth of `−ln(1 − coverage)`
    /// (coverage at most 0.999) over the chord. A height's texels in every
    /// view, ordered by their optical depth per metre, fall into the
    /// classes in even counts, clearest first; each class's extinction is
    /// its texels' summed optical depth over their summed chords. One
    /// medium a height does not hold the crown's light: with the mean
    /// optical depth it let a sunbeam through at the full clumps' rate
    /// everywhere (a mature spruce's far side past the shadow maps at 57 %
    /// of the light its lines' shadows leave it), and with the medium that
    /// lets as much through the chords as the texels do, short paths near
    /// the sunlit side kept too much (its sunlit half 23–31 % too bright).
    /// Texels outside the radius are left out; a height with no chord has
    /// none.
    pub fn crown_extinction(
        &self,
        radii: &[f32; CROWN_PROFILE_STEPS],
    ) -> [[f32; CROWN_SHADE_CLASSES]; CROWN_PROFILE_STEPS] {
        let mut extinction = [[0.0; CROWN_SHADE_CLASSES]; CROWN_PROFILE_STEPS];
        if self.rows == 0 || self.columns == 0 || self.views == 0 {
            return extinction;
        }
        // (optical depth per metre, optical depth, chord) of each texel.
        let mut rays: Vec<(f64, f64, f64)> = Vec::new();
        for (step, (media, &radius)) in extinction.iter_mut().zip(radii).enumerate() {
            // Rows as `crown_radii` shares them: step 0 is the bottom.
            let first = self.rows - ((step as u32 + 1) * self.rows).div_ceil(CROWN_PROFILE_STEPS as u32);
            let last = self.rows - (step as u32 * self.rows) / CROWN_PROFILE_STEPS as u32;
            rays.clear();
            for column in 0..self.columns {
                let along = (column as f32 + 0.5) * self.texel - self.half_width;
                let half_chord = (radius * radius - along * along).max(0.0).sqrt();
                if half_chord.is_nan() || half_chord <= 0.0 {
                    continue;
                }
                let chord = f64::from(2.0 * half_chord);
                for view in 0..self.views {
                    for row in first..last {
                        let coverage = self.texel_at(view, column, row).map_or(0.0, |t| t.coverage);
                        let depth = -f64::from((1.0 - coverage.min(MAX_COVERAGE)).ln());
                        rays.push((depth / chord, depth, chord));
                    }
                }
            }
            rays.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (class, sigma) in media.iter_mut().enumerate() {
                let share =
                    &rays[class * rays.len() / CROWN_SHADE_CLASSES..(class + 1) * rays.len() / CROWN_SHADE_CLASSES];
                let (depth, chords) = share.iter().fold((0.0, 0.0), |(d, c), ray| (d + ray.1, c + ray.2));
                if chords > 0.0 {
                    *sigma = (depth / chords) as f32;
                }
            }
        }
        extinction
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::impostor::WoodVisibility;
    use proptest::prelude::*;

    /// A cylinder crown of radius 2 m from 1 to 9 m with a uniform
    /// extinction.
    fn cylinder(sigma: f32) -> CrownShade {
        CrownShade {
            axis: Vec2::new(0.5, -0.5),
            bottom: 1.0,
            top: 9.0,
            radii: [2.0; CROWN_PROFILE_STEPS],
            extinction: [[sigma; CROWN_SHADE_CLASSES]; CROWN_PROFILE_STEPS],
        }
    }

    /// A uniform cylinder's sky: all of it above the top and through a
    /// crown with no extinction, less toward the axis and toward the
    /// bottom, and the table gives back each point it was taken at and
    /// lies between its nodes elsewhere.
    #[test]
    fn the_sky_dims_toward_a_crowns_axis_and_bottom() {
        let shade = cylinder(0.5);
        let at = |out: f32, height: f32| Vec3::new(0.5 + out, height, -0.5);
        assert_eq!(shade.sky_visibility(at(0.0, 9.5)), 1.0);
        assert_eq!(cylinder(0.0).sky_visibility(at(0.0, 5.0)), 1.0);
        let (edge, middle, axis) = (
            shade.sky_visibility(at(2.0, 5.0)),
            shade.sky_visibility(at(1.0, 5.0)),
            shade.sky_visibility(at(0.0, 5.0)),
        );
        assert!(edge > middle && middle > axis && axis > 0.0, "{edge} {middle} {axis}");
        // At the edge the outward half of the sky is open, the rest dimmed.
        assert!(edge > 0.5 && edge < 0.75, "{edge}");
        assert!(shade.sky_visibility(at(0.0, 8.5)) > shade.sky_visibility(at(0.0, 2.0)));
        let table = shade.sky_visibility_table();
        for step in [0, 7, 31] {
            let height = 1.0 + (step as f32 + 0.5) / CROWN_PROFILE_STEPS as f32 * 8.0;
            for ring in 0..SKY_VISIBILITY_RINGS {
                let point = at(2.0 * ring as f32 / 3.0, height);
                assert!((table.at(&shade, point) - shade.sky_visibility(point)).abs() < 1e-5);
            }
        }
        let between = table.at(&shade, at(0.5, 5.0));
        assert!(between < middle && between > axis, "{between}");
        // Past the edge the edge's; not finite, all of it.
        assert!((table.at(&shade, at(3.0, 5.0)) - table.at(&shade, at(2.0, 5.0))).abs() < 1e-6);
        assert_eq!(table.at(&shade, Vec3::new(f32::NAN, 5.0, 0.0)), 1.0);
        assert_eq!(SkyVisibility::open().at(&shade, at(0.0, 5.0)), 1.0);
    }

    proptest! {
        /// The sky a point sees is a share, and inside a uniform crown's
        /// height a point nearer its axis never sees more of it (below
        /// the crown the axis may: its rays leave through the bottom).
        #[test]
        fn the_sky_seen_is_a_share_that_falls_toward_the_axis(
            sigma in 0.0f32..3.0,
            height in 1.0f32..9.0,
            out in 0.0f32..3.0,
            inward in 0.0f32..1.0,
        ) {
            let shade = cylinder(sigma);
            let outer = shade.sky_visibility(Vec3::new(0.5 + out, height, -0.5));
            let inner = shade.sky_visibility(Vec3::new(0.5 + out * inward, height, -0.5));
            prop_assert!((0.0..=1.0).contains(&outer));
            prop_assert!((0.0..=1.0).contains(&shade.sky_visibility(Vec3::new(out, height - 2.0, out))));
            prop_assert!(inner <= outer + 1e-5, "{inner} {outer}");
        }
    }

    /// Through a uniform cylinder the light is `exp(−σ·ℓ)` for the exact
    /// length `ℓ` of the ray inside it: across it from the axis, up to its
    /// top, and through its whole width from outside.
    #[test]
    fn a_uniform_cylinder_lets_through_its_exact_chord() {
        let shade = cylinder(0.4);
        let axis = Vec3::new(0.5, 5.0, -0.5);
        let close = |got: f32, length: f32| (got - (-0.4 * length).exp()).abs() < 1e-4;
        assert!(close(shade.transmittance(axis, Vec3::X), 2.0));
        assert!(close(shade.transmittance(axis, Vec3::Y * 3.0), 4.0));
        assert!(close(shade.transmittance(axis - Vec3::X * 5.0, Vec3::X), 4.0));
        // Off the axis, a chord of 2√(4 − 1).
        let off = axis + Vec3::Z;
        let chord = 3.0f32.sqrt();
        assert!(close(shade.transmittance(off, -Vec3::X), chord));
        // Slanting up across the top: 45° from the axis at 8 m reaches the
        // top after √2 m.
        let slant = Vec3::new(1.0, 1.0, 0.0);
        assert!(close(shade.transmittance(axis + Vec3::Y * 3.0, slant), 2f32.sqrt()));
        // Away from the crown, nothing is in the way.
        assert_eq!(shade.transmittance(axis + Vec3::X * 5.0, Vec3::X), 1.0);
        assert_eq!(shade.transmittance(axis + Vec3::Y * 10.0, Vec3::Y), 1.0);
    }

    /// A cone's radius shrinks upward, and a light from the side crosses
    /// less of it higher up; a point just inside its surface facing the
    /// light is nearly fully lit, and the light falls off toward the far
    /// side.
    #[test]
    fn a_cone_shades_its_far_side_and_not_its_lit_side() {
        let mut shade = cylinder(0.5);
        for (k, r) in shade.radii.iter_mut().enumerate() {
            *r = 3.0 * (1.0 - (k as f32 + 0.5) / CROWN_PROFILE_STEPS as f32);
        }
        let axis = Vec3::new(0.5, 0.0, -0.5);
        let sun = Vec3::new(1.0, 0.5, 0.0);
        let at = |x: f32, y: f32| shade.transmittance(axis + Vec3::new(x, y, 0.0), sun);
        let low = shade.inside(axis + Vec3::Y * 3.0);
        assert!(low > 1.0, "{low}");
        let radius_at_3 = CrownImpostor::crown_radius_at(&shade.radii, 1.0, 9.0, 3.0);
        assert!(at(radius_at_3 - 0.01, 3.0) > 0.98);
        assert!(at(-radius_at_3 + 0.1, 3.0) < at(0.0, 3.0));
        assert!(at(0.0, 3.0) < at(0.0, 7.0));
    }

    /// Bad input gets a defined light: a zero, infinite or NaN direction
    /// or point lets everything through, as does an empty profile.
    #[test]
    fn bad_input_lets_the_light_through() {
        let shade = cylinder(1.0);
        let p = Vec3::new(0.5, 5.0, -0.5);
        assert_eq!(shade.transmittance(p, Vec3::ZERO), 1.0);
        assert_eq!(shade.transmittance(p, Vec3::new(f32::NAN, 1.0, 0.0)), 1.0);
        assert_eq!(shade.transmittance(p, Vec3::splat(f32::INFINITY)), 1.0);
        assert_eq!(shade.transmittance(Vec3::splat(f32::NAN), Vec3::Y), 1.0);
        let empty = CrownShade { top: 1.0, ..shade };
        assert_eq!(empty.transmittance(p, Vec3::Y), 1.0);
    }

    /// The shadow maps hand over to the crown across the last cascade's
    /// overlap band, continuously.
    #[test]
    fn the_maps_hand_over_to_the_crown_across_the_overlap_band() {
        assert_eq!(past_shadow_maps(10.0, 80.0, 0.2), 0.0);
        assert_eq!(past_shadow_maps(64.0, 80.0, 0.2), 0.0);
        assert!((past_shadow_maps(72.0, 80.0, 0.2) - 0.5).abs() < 1e-6);
        assert_eq!(past_shadow_maps(80.0, 80.0, 0.2), 1.0);
        assert_eq!(past_shadow_maps(500.0, 80.0, 0.2), 1.0);
        assert_eq!(past_shadow_maps(79.0, 80.0, 0.0), 0.0);
        assert_eq!(past_shadow_maps(5.0, 0.0, 0.2), 1.0);
        assert_eq!(past_shadow_maps(f32::NAN, 80.0, 0.2), 0.0);
    }

    /// `views` pictures of `columns` × 64 texels of side `texel` about an
    /// axis at the origin, from height 0, each texel's coverage
    /// `coverage(row, column)` (255ths; no wood).
    fn pictures(views: u32, columns: u32, texel: f32, coverage: impl Fn(u32, u32) -> u8) -> CrownImpostor {
        let rows = 64;
        CrownImpostor {
            views,
            columns,
            rows,
            axis: Vec2::ZERO,
            half_width: columns as f32 * texel / 2.0,
            bottom: 0.0,
            texel,
            texels: (0..views * rows * columns)
                .map(|i| [coverage((i / columns) % rows, i % columns), 0, 0, 0])
                .collect(),
            wood_visibility: WoodVisibility::default(),
            crown_density: Default::default(),
            seen_needles: None,
            view_light_scale: None,
        }
    }

    /// Pictures of a uniform medium filling a cylinder give back its
    /// extinction: each texel's coverage is `1 − exp(−σ·chord)` at its
    /// offset, rounded to 255ths as the bake stores it.
    #[test]
    fn the_pictures_of_a_uniform_crown_give_back_its_extinction() {
        let (columns, texel, radius, sigma) = (40u32, 0.1f32, 1.8f32, 0.7f32);
        let half_width = columns as f32 * texel / 2.0;
        let impostor = pictures(3, columns, texel, |_, column| {
            let along = (column as f32 + 0.5) * texel - half_width;
            let chord = 2.0 * (radius * radius - along * along).max(0.0).sqrt();
            ((1.0 - (-sigma * chord).exp()) * 255.0).round() as u8
        });
        let shade = CrownShade::of(&impostor);
        let axis = Vec3::new(0.0, 3.2, 0.0);
        for (step, (media, &r)) in shade.extinction.iter().zip(&shade.radii).enumerate() {
            // The profile's radius holds 95 % of the coverage: a little
            // inside the cylinder, so its chords are shorter, most at its
            // edge, and the densest class (the edge's rays) is denser.
            assert!(r < radius && r > radius - 2.0 * texel, "step {step}: radius {r}");
            assert!(media.is_sorted(), "step {step}: {media:?}");
            assert!(
                media[0] > 0.95 * sigma && media[3] < 1.3 * sigma,
                "step {step}: extinctions {media:?} for {sigma}"
            );
        }
        // What matters is the light through it: across the crown from its
        // axis and through its whole width, within 12 % of the medium's
        // optical depth (the shorter radius's chords, measured: 9 % over
        // from the axis).
        for (from, toward, length) in [(axis, Vec3::X, radius), (axis - Vec3::Z * 5.0, Vec3::Z, 2.0 * radius)] {
            let depth = -shade.transmittance(from, toward).ln();
            assert!(
                (depth / (sigma * length) - 1.0).abs() < 0.12,
                "optical depth {depth} for {}",
                sigma * length
            );
        }
    }

    /// A clumped crown, half its texels full and half empty, lets through
    /// on the same chords what its gaps let through: about half, where one
    /// medium of the mean optical depth over its chords would let through
    /// a few per cent.
    #[test]
    fn a_clumped_crown_lets_through_what_its_gaps_do() {
        let (columns, texel) = (40u32, 0.1f32);
        let half_width = columns as f32 * texel / 2.0;
        let impostor = pictures(
            2,
            columns,
            texel,
            |row, column| if (row + column) % 2 == 0 { 255 } else { 0 },
        );
        let shade = CrownShade::of(&impostor);
        for (step, (media, &r)) in shade.extinction.iter().zip(&shade.radii).enumerate() {
            assert_eq!(media[..2], [0.0; 2], "step {step}: the gaps' media are clear");
            let chords: Vec<f32> = (0..columns)
                .map(|c| (c as f32 + 0.5) * texel - half_width)
                .filter(|x| x.abs() < r)
                .map(|x| 2.0 * (r * r - x * x).sqrt())
                .collect();
            let through = chords
                .iter()
                .map(|c| media.iter().map(|sigma| (-sigma * c).exp()).sum::<f32>() / CROWN_SHADE_CLASSES as f32)
                .sum::<f32>()
                / chords.len() as f32;
            assert!((through - 0.5).abs() < 0.03, "step {step}: {through} through");
        }
        // Through the crown's middle at mid-height: half.
        let through = shade.transmittance(Vec3::new(0.0, 3.2, -5.0), Vec3::Z);
        assert!((through - 0.5).abs() < 0.01, "{through}");
    }

    proptest! {
        /// Eight steps hold the light: through a cone of uniform
        /// extinction, from any point toward any sun, the optical depth
        /// eight steps find is within two of its steps' worth (a step
        /// where the ray crosses the crown's surface, going in and coming
        /// out) of the one 4,096 steps find, and the light stays in
        /// [0, 1].
        #[test]
        fn eight_steps_stay_within_two_steps_of_the_fine_integral(
            x in -4.0f32..4.0, y in -1.0f32..11.0, z in -4.0f32..4.0,
            azimuth in 0.0f32..std::f32::consts::TAU, elevation in -1.4f32..1.4,
            sigma in 0.0f32..3.0,
        ) {
            let mut shade = cylinder(sigma);
            for (k, r) in shade.radii.iter_mut().enumerate() {
                *r = 0.2 + 2.5 * (1.0 - (k as f32 + 0.5) / CROWN_PROFILE_STEPS as f32);
            }
            let sun = Vec3::new(elevation.cos() * azimuth.cos(), elevation.sin(), elevation.cos() * azimuth.sin());
            let p = Vec3::new(x, y, z);
            let light = shade.transmittance(p, sun);
            prop_assert!((0.0..=1.0).contains(&light));
            let (depths, step) = shade.optical_depths(p, sun, CROWN_SHADE_STEPS);
            prop_assert!((light - (-depths[0]).exp()).abs() < 1e-6);
            let (fine, _) = shade.optical_depths(p, sun, 4096);
            prop_assert!((depths[0] - fine[0]).abs() <= 2.0 * sigma * step + 1e-3, "{depths:?} against {fine:?}, steps of {step}");
        }
    }
}
