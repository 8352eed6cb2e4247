//! Aerial perspective for a forest: Bevy's [`DistanceFog`] set so that far
//! crowns fade toward the sky behind them.
//!
//! Bevy's atmospheric fog takes two coefficients per channel, one for the
//! light an object loses and one for the haze it gains, and its
//! `FogFalloff::from_visibility_colors` raises the inscattering colour to
//! the power `e` before using it: with the sky's own blue as that colour
//! (sRGB 0.55, 0.66, 0.8) the haze puts back 0.03, 0.08 and 0.25 of what a
//! grey extinction takes out, so a dark stand a few hundred metres off
//! comes out darker than a near one and navy. [`aerial_perspective`] gives
//! both coefficients the same value, which is what a real haze does: light
//! from `d` metres keeps `T = exp(−β·d)` of itself and gains `1 − T` of
//! the horizon's colour.

use bevy::pbr::{DistanceFog, FogFalloff};
use bevy::prelude::*;

/// Contrast at which an object is no longer seen against the horizon
/// (Bevy's revised Koschmieder threshold).
const CONTRAST_THRESHOLD: f32 = 0.05;

/// Wavelengths of red, green and blue, nanometres.
const WAVELENGTH_NM: [f32; 3] = [650.0, 550.0, 450.0];

/// Ångström exponent of haze (aerosols scatter about `λ^−1.3`; the clear
/// sky's air `λ^−4`, which would take the red out of a stand in a few
/// hundred metres).
const HAZE_EXPONENT: f32 = 1.3;

/// The haze's extinction per metre in red, green and blue, for a
/// visibility of `visibility` metres (Koschmieder: `−ln 0.05 / V` in
/// green, the other channels by haze's `λ^−1.3`); `None` for a
/// visibility that is not positive and finite.
pub fn haze_extinction(visibility: f32) -> Option<Vec3> {
    if !(visibility.is_finite() && visibility > 0.0) {
        return None;
    }
    let green = -CONTRAST_THRESHOLD.ln() / visibility;
    Some(Vec3::from_array(
        WAVELENGTH_NM.map(|nm| green * (nm / WAVELENGTH_NM[1]).powf(-HAZE_EXPONENT)),
    ))
}

/// A [`DistanceFog`] for a camera looking over a forest: a haze that
/// leaves a black object 5 % of its contrast against `horizon` at
/// `visibility` metres in green (light haze is 5–10 km, fog under 1 km),
/// blue a little sooner and red later, and fades everything toward
/// `horizon` — the sky's colour as the camera renders it (with `Hdr`,
/// the linear colour it clears to), so a far stand never turns darker or
/// bluer than the sky behind it. `None` for a visibility that is not
/// positive and finite (no haze).
pub fn aerial_perspective(visibility: f32, horizon: Color) -> Option<DistanceFog> {
    let extinction = haze_extinction(visibility)?;
    Some(DistanceFog {
        color: horizon,
        falloff: FogFalloff::Atmospheric {
            extinction,
            inscattering: extinction,
        },
        ..default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bevy's atmospheric fog (`bevy_pbr`'s `atmospheric_fog`, one channel):
    /// what an object of `colour` seen `distance` metres away through
    /// `fog` comes out as.
    fn fogged(fog: &DistanceFog, colour: Vec3, distance: f32) -> Vec3 {
        let FogFalloff::Atmospheric {
            extinction,
            inscattering,
        } = fog.falloff
        else {
            panic!("not atmospheric")
        };
        let horizon = fog.color.to_linear().to_vec3();
        let lost = Vec3::ONE - (-extinction * distance).exp();
        let gained = Vec3::ONE - (-inscattering * distance).exp();
        colour * (Vec3::ONE - lost) + horizon * gained
    }

    #[test]
    fn a_far_stand_fades_toward_the_sky_and_never_past_it() {
        let sky = Color::linear_rgb(0.3512, 0.5861, 1.0147);
        let fog = aerial_perspective(8000.0, sky).unwrap();
        let sky = sky.to_linear().to_vec3();
        let crown = Vec3::new(0.03, 0.06, 0.04);
        // At the visibility a black object keeps 5 % of its contrast in green.
        let black = fogged(&fog, Vec3::ZERO, 8000.0);
        assert!(((sky.y - black.y) / sky.y - 0.05).abs() < 1e-4, "{black}");
        // Blue fades first, red last.
        let contrast = (sky - black) / sky;
        assert!(contrast.z < contrast.y && contrast.y < contrast.x, "{contrast}");
        // Every channel moves toward the sky with distance, never past it.
        let mut previous = crown;
        for distance in [50.0, 200.0, 600.0, 2000.0, 20_000.0] {
            let seen = fogged(&fog, crown, distance);
            for channel in 0..3 {
                assert!(
                    seen[channel] >= previous[channel] && seen[channel] <= sky[channel],
                    "{distance} m: {seen}"
                );
            }
            previous = seen;
        }
        assert!((fogged(&fog, crown, 1e6) - sky).abs().max_element() < 1e-4);
        // The sky itself is unchanged at any distance.
        assert!((fogged(&fog, sky, 600.0) - sky).abs().max_element() < 1e-5);
    }

    #[test]
    fn no_visibility_is_no_haze() {
        for visibility in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(aerial_perspective(visibility, Color::WHITE).is_none(), "{visibility}");
        }
    }
}
