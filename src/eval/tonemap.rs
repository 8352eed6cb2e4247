//! Bevy's TonyMcMapface tone mapping on the CPU, for the reference.
//!
//! A camera with `Hdr` blends in linear light and tone-maps each pixel
//! once: what a game shows of a pixel half covered by a needle is
//! `T(½ needle + ½ sky)`. The reference renders `supersampling²` pixels
//! for each of the picture's and box-filters them; tone-mapped one by one
//! before the filter it would give `½ T(needle) + ½ T(sky)` instead, and
//! TonyMcMapface bends enough that a quarter-covered pixel comes out up
//! to 6 of 255 darker that way (a dark needle on the eval's grey sky,
//! computed with the LUT). So where the methods' cameras tone-map, the
//! reference's writes linear light (`Hdr`, `Tonemapping::None`), is
//! box-filtered in linear light ([`super::measure::downsample`]), and is
//! tone-mapped here, with the LUT Bevy's own pass samples.
//!
//! [`ToneMap::map`] follows `sample_tony_mc_mapface_lut` in Bevy 0.19's
//! `tonemapping_shared.wgsl` (the LUT's coordinate `c / (c + 1)` per
//! channel, trilinear), with Bevy's default colour grading (no exposure,
//! no saturation change) and without deband dithering.

use bevy::core_pipeline::tonemapping::TonemappingLuts;
use bevy::image::Image;
use bevy::prelude::*;
use bevy::render::render_resource::TextureFormat;
use image::RgbaImage;

/// Texels of the TonyMcMapface LUT along each axis.
pub const TONY_MC_MAPFACE_SIZE: usize = 48;

/// The TonyMcMapface LUT, decoded: linear light in, linear display
/// colour out.
#[derive(Clone, Debug, PartialEq)]
pub struct ToneMap {
    /// `48³` texels, red fastest, then green, then blue.
    texels: Vec<[f32; 3]>,
}

impl ToneMap {
    /// The LUT Bevy loaded into `world` (`TonemappingLuts`, kept in the
    /// main world); `None` where it is missing or not the 48³
    /// `Rgb9e5Ufloat` texture (Bevy built without `tonemapping_luts` has a
    /// placeholder there).
    pub fn from_world(world: &World) -> Option<Self> {
        let luts = world.get_resource::<TonemappingLuts>()?;
        let image = world.resource::<Assets<Image>>().get(&luts.tony_mc_mapface)?;
        Self::from_image(image)
    }

    /// The LUT held by `image`: `None` unless it is a 48³ `Rgb9e5Ufloat`
    /// texture with its data.
    pub fn from_image(image: &Image) -> Option<Self> {
        let size = image.texture_descriptor.size;
        let n = TONY_MC_MAPFACE_SIZE as u32;
        if image.texture_descriptor.format != TextureFormat::Rgb9e5Ufloat
            || (size.width, size.height, size.depth_or_array_layers) != (n, n, n)
        {
            return None;
        }
        let data = image.data.as_ref()?;
        let count = TONY_MC_MAPFACE_SIZE.pow(3);
        if data.len() < 4 * count {
            return None;
        }
        let texels = data[..4 * count]
            .chunks_exact(4)
            .map(|bytes| decode_rgb9e5(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])))
            .collect();
        Some(Self { texels })
    }

    /// TonyMcMapface of the linear colour `rgb` (negative and non-finite
    /// channels taken as 0), linear display colour.
    pub fn map(&self, rgb: [f32; 3]) -> [f32; 3] {
        let last = (TONY_MC_MAPFACE_SIZE - 1) as f32;
        // The shader's `uv = c/(c+1) · 47/48 + 0.5/48` in texel units.
        let at = rgb.map(|c| {
            let c = if c.is_finite() { c.max(0.0) } else { 0.0 };
            (c / (c + 1.0) * last).clamp(0.0, last)
        });
        let base = at.map(|t| (t as usize).min(TONY_MC_MAPFACE_SIZE - 2));
        let fraction = [0, 1, 2].map(|k| at[k] - base[k] as f32);
        let mut out = [0.0f32; 3];
        for corner in 0..8 {
            let step = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let weight: f32 = (0..3)
                .map(|k| if step[k] == 1 { fraction[k] } else { 1.0 - fraction[k] })
                .product();
            let [x, y, z] = [0, 1, 2].map(|k| base[k] + step[k]);
            let texel = self.texels[(z * TONY_MC_MAPFACE_SIZE + y) * TONY_MC_MAPFACE_SIZE + x];
            for k in 0..3 {
                out[k] += weight * texel[k];
            }
        }
        out
    }

    /// Tone-maps an sRGB picture of linear light in place (alpha kept):
    /// each pixel decoded, mapped and encoded again.
    pub fn apply(&self, picture: &mut RgbaImage) {
        let decode: Vec<f32> = (0..=255u8).map(crate::preview::srgb_to_linear).collect();
        for pixel in picture.pixels_mut() {
            let mapped = self.map([0, 1, 2].map(|k| decode[pixel.0[k] as usize]));
            for (channel, value) in pixel.0.iter_mut().zip(mapped) {
                *channel = crate::preview::linear_to_srgb(value);
            }
        }
    }
}

/// One `Rgb9e5Ufloat` texel: three 9-bit mantissas sharing a 5-bit
/// exponent (bias 15), red in the low bits.
fn decode_rgb9e5(bits: u32) -> [f32; 3] {
    let exponent = (bits >> 27) as i32;
    let scale = 2f32.powi(exponent - 15 - 9);
    [0, 9, 18].map(|shift| ((bits >> shift) & 0x1ff) as f32 * scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgb9e5_texels_decode() {
        // 1.0: mantissa 256 at exponent 16 (256 · 2^(16−24)).
        let one = (16 << 27) | (256 << 18) | (256 << 9) | 256;
        assert_eq!(decode_rgb9e5(one), [1.0, 1.0, 1.0]);
        // 0.5 in red, 0 elsewhere, and the largest mantissa.
        assert_eq!(decode_rgb9e5((15 << 27) | 256), [0.5, 0.0, 0.0]);
        assert_eq!(decode_rgb9e5((15 << 27) | (511 << 9))[1], 511.0 / 512.0);
    }

    /// An identity-like LUT (each texel its own coordinate): the map is
    /// `c/(c+1)` per channel, trilinear between texels, bad input taken
    /// as black.
    #[test]
    fn the_map_reads_the_lut_at_c_over_c_plus_one() {
        let n = TONY_MC_MAPFACE_SIZE;
        let last = (n - 1) as f32;
        let texels = (0..n * n * n)
            .map(|i| [i % n, (i / n) % n, i / (n * n)].map(|k| k as f32 / last))
            .collect();
        let lut = ToneMap { texels };
        for c in [0.0f32, 0.1, 0.5, 1.0, 3.0, 100.0] {
            let out = lut.map([c, 2.0 * c, 0.5 * c]);
            for (k, value) in [c, 2.0 * c, 0.5 * c].into_iter().enumerate() {
                assert!((out[k] - value / (value + 1.0)).abs() < 1e-5, "{c}: {out:?}");
            }
        }
        assert_eq!(lut.map([f32::NAN, -1.0, f32::INFINITY]), [0.0, 0.0, 0.0]);
    }
}
