//! The [`ConiferWind`] resource: wind over every tree
//! ([`crate::model::wind`] is the field it drives).

use crate::model::wind::Wind;
use bevy::prelude::*;

/// Wind over every tree. The render path displaces every vertex (prisms,
/// lines, merged lines, wood, shadows, the impostor's trunk lean) by one
/// field of where it sits in its tree ([`crate::model::wind`]), so LOD
/// changes never jump; each tree sways at its own phase, from where it
/// stands. Culling and error spheres grow by the largest displacement the
/// settings allow ([`crate::model::wind::wind_reach`]).
///
/// The plugin starts with a light breeze ([`ConiferWind::default`]); set
/// `strength` to 0 for calm (nothing moves, nothing is computed).
#[derive(Resource, Clone, Copy, Debug, PartialEq, Reflect)]
#[reflect(Resource, Default, Debug, Clone)]
pub struct ConiferWind {
    /// Where the wind blows to (world x, z); normalised where used.
    pub direction: Vec2,
    /// 0: calm; 1: a light breeze (a 20 m tree's top leans about 16 cm and sways ±10 cm);
    /// 3: a strong wind.
    pub strength: f32,
    /// How much gusts vary the strength, 0–1.
    pub gustiness: f32,
    /// How much shoots flutter, 0–1.
    pub turbulence: f32,
    /// The wind's clock, seconds; `None` follows `Time` (virtual time: a
    /// paused game's trees stand still). Set it for reproducible pictures.
    pub time: Option<f64>,
}

impl ConiferWind {
    /// No wind.
    pub const CALM: ConiferWind = ConiferWind::from_model(Wind::CALM);

    /// The resource for the model's `wind`, on `Time`'s clock.
    pub const fn from_model(wind: Wind) -> ConiferWind {
        ConiferWind {
            direction: wind.direction,
            strength: wind.strength,
            gustiness: wind.gustiness,
            turbulence: wind.turbulence,
            time: None,
        }
    }

    /// The model's wind.
    pub fn model(&self) -> Wind {
        Wind {
            direction: self.direction,
            strength: self.strength,
            gustiness: self.gustiness,
            turbulence: self.turbulence,
        }
    }

    /// The wind's clock now: [`ConiferWind::time`], or `elapsed` (seconds of
    /// `Time`).
    pub fn seconds(&self, elapsed: f64) -> f64 {
        self.time.unwrap_or(elapsed)
    }
}

impl Default for ConiferWind {
    /// A light breeze ([`Wind::LIGHT_BREEZE`]).
    fn default() -> Self {
        ConiferWind::from_model(Wind::LIGHT_BREEZE)
    }
}
