//! What makes the far crown's pixel-to-pixel texture in `conifer eval`'s
//! reference: for each pixel of the eval's view of a record (the camera
//! on `+z` at `DISTANCE` from the crown centre, looking at it level,
//! `480 × 270`, 11.824° vertical field of view, as the README's 250 m
//! runs), what the needles nearest the camera there show, sampled on a
//! grid of 2.5 cm (each sample's needle as
//! [`CrownImpostor::nearest_pieces`] finds it): the Lambert factor of the
//! front sun at the sample's normal on the round needle
//! ([`CrownImpostor::seen_normal`], as the impostor's measures take it), and the needle's
//! colour as the reference draws it (its shoot's age colour turned toward
//! the pale underside by how much of the underside the camera sees,
//! [`ShootColor::seen_from`]). Printed: over the pixels the reference
//! covers (alpha ≥ 240) and the samples fill, the correlation of the
//! reference's grey level with each, and with their product; and, given
//! `OURS`, the same for what `OURS` lacks (reference − ours), and the
//! mean |reference − ours| in grey levels over those pixels as it is and
//! with ours scaled by each pixel's seen albedo over the pixels' mean
//! (what a far crown coloured per pixel by the needles it shows would
//! draw, the light left as it is).
//!
//! Then the same as the reference's own lighting would give it: each
//! sample's radiance as Bevy lights its standard material in the eval
//! (the sun's 9,000 lux through [`bevy_direct`], Burley diffuse and GGX
//! specular, and the ambient 600 through [`bevy_ambient`], at the
//! record's roughness and reflectance), averaged over the pixel in
//! linear light. Printed: how much of the crown's light is specular (it
//! does not take the needles' colour, so it dilutes a colour change), the
//! correlation of the reference's grey level with the log of that
//! radiance, and what a colour per pixel would change once the specular
//! is in: `ln r`, `r` the pixel's radiance over what it would be with the
//! crown's mean colour. A pixel of grey level `g` in sRGB changes by
//! about `(g + 14)/2.4 · ln r` (the sRGB curve's slope in `ln` of linear
//! light; TonyMcMapface is close to linear in the dark); the mean
//! |reference − ours| is printed with ours changed so, and with the
//! share of that change that fits best (1 where the model is the whole
//! story). And two checks on the samples themselves: how reliable a
//! pixel's seen colour is as a measure (the correlation between the mean
//! colours of two halves of its samples, a checkerboard over the grid),
//! and whether they lie where the reference's pixels do (the correlation
//! with the reference's grey level over shifts of up to 3 pixels).
//!
//! ```text
//! cargo run --release --no-default-features --example crown_pixels -- RECORD REF.png [OURS.png] [DISTANCE]
//! ```
//!
//! Orthographic at the crown's centre plane: at 250 m a crown 3 m deep
//! moves a pixel at its edge by about half a pixel.
//!
//! [`CrownImpostor::nearest_pieces`]: bevy_conifer_lod::model::impostor::CrownImpostor::nearest_pieces
//! [`CrownImpostor::seen_normal`]: bevy_conifer_lod::model::impostor::CrownImpostor::seen_normal
//! [`ShootColor::seen_from`]: bevy_conifer_lod::model::color::ShootColor::seen_from
//! [`bevy_direct`]: bevy_conifer_lod::model::shading::bevy_direct
//! [`bevy_ambient`]: bevy_conifer_lod::model::shading::bevy_ambient

use bevy_conifer_lod::model::color::shoot_colors;
use bevy_conifer_lod::model::impostor::{CrownImpostor, ImpostorOptions};
use bevy_conifer_lod::model::prism::TriangleMesh;
use bevy_conifer_lod::model::shading::{bevy_ambient, bevy_direct};
use bevy_conifer_lod::model::{Needle, read_prototype_record};
use glam::{Vec2, Vec3};

const WIDTH: usize = 480;
const HEIGHT: usize = 270;
const FOV_DEG: f32 = 11.824;
/// Samples along each side of a 10 cm texel.
const PER_TEXEL: u32 = 4;
/// The eval's sun (lux) and ambient brightness (`HeadlessRenderer::spawn_lights`).
const SUN_LUX: f32 = 9_000.0;
const AMBIENT: f32 = 600.0;
/// Alpha (0–255) from which a pixel counts as covered.
const OPAQUE: f64 = 240.0;

/// What the samples of one pixel add up to (over those with a normal,
/// past `shown`).
#[derive(Clone, Copy, Default)]
struct PixelSums {
    /// Samples that show a needle.
    shown: f64,
    /// Of them, those with a normal (not past a needle's cap).
    lit: f64,
    lambert: f64,
    albedo: f64,
    albedo_lambert: f64,
    /// Light that takes the needle's colour (sun's diffuse and ambient
    /// diffuse, per unit albedo).
    diffuse_light: f64,
    /// The same times the sample's albedo.
    diffuse: f64,
    /// Light that does not (specular of the sun and the ambient).
    specular: f64,
    /// Lit samples and their albedo, split into the two colours of a
    /// checkerboard over the sample grid.
    halves: [(f64, f64); 2],
}

/// A number read off a pixel's row.
type Measure = dyn Fn(&PixelRow) -> f64;

/// One pixel the reference covers and the samples fill.
struct PixelRow {
    reference: f64,
    /// Reference − ours (grey levels).
    lacks: f64,
    lambert: f64,
    albedo: f64,
    albedo_lambert: f64,
    ours: f64,
    /// ln of the pixel's radiance (linear, per unit exposure).
    log_radiance: f64,
    /// The pixel's radiance with the crown's mean colour on every sample.
    flat_radiance: f64,
    /// ln r: the pixel's radiance over `flat_radiance`.
    color_change: f64,
    /// The mean albedo of each half of the pixel's samples.
    halves: [f64; 2],
}

/// Pearson's correlation of the pairs' two members (0 where either does
/// not vary).
fn pearson(pairs: &[(f64, f64)]) -> f64 {
    let n = pairs.len() as f64;
    let (sa, sb) = pairs.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
    let (ma, mb) = (sa / n, sb / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for &(a, b) in pairs {
        let (da, db) = (a - ma, b - mb);
        sab += da * db;
        saa += da * da;
        sbb += db * db;
    }
    sab / (saa * sbb).sqrt().max(f64::MIN_POSITIVE)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(record_path), Some(reference_path)) = (args.first(), args.get(1)) else {
        return Err("usage: crown_pixels RECORD REF.png [OURS.png] [DISTANCE]".into());
    };
    let ours_path = args.get(2).filter(|a| a.ends_with(".png"));
    let distance: f32 = args.iter().skip(2).find_map(|a| a.parse().ok()).unwrap_or(250.0);
    let record = read_prototype_record(std::path::Path::new(record_path))?;
    let needles: Vec<Needle> = record.placed_needles();
    let valid: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
    let colors = shoot_colors(&record);
    // A one-view frame over the tree: view 0 looks from +z.
    let frame = CrownImpostor::bake(
        &needles,
        &record.wood,
        &TriangleMesh::default(),
        ImpostorOptions {
            views: 1,
            ..ImpostorOptions::default()
        },
    )
    .ok_or("no impostor frame")?;
    let nearest = frame.nearest_pieces(0, &record.wood, &valid, [PER_TEXEL; 2]);
    let right = frame.view_right(0);
    let center = record.crown_center();
    let eye = center + Vec3::Z * distance;
    let sun = Vec3::new(4.0, 8.0, 6.0).normalize();
    let pixel = 2.0 * distance * (0.5 * FOV_DEG.to_radians()).tan() / HEIGHT as f32;
    let top = frame.top();
    // Per pixel: what its samples add up to.
    let view = Vec3::Z;
    let (roughness, reflectance) = (record.material.roughness, record.material.reflectance);
    let mut sums = vec![PixelSums::default(); WIDTH * HEIGHT];
    for (index, piece) in nearest.needle_samples_at() {
        let needle = valid[piece];
        let (column, row) = (index % nearest.width as usize, index / nearest.width as usize);
        let across = (column as f32 + 0.5) * nearest.step.x - frame.half_width;
        let height = top - (row as f32 + 0.5) * nearest.step.y;
        let point = frame.axis_point() + right * across + Vec3::Y * height;
        let x = WIDTH as f32 / 2.0 + (point.x - center.x) / pixel;
        let y = HEIGHT as f32 / 2.0 - (point.y - center.y) / pixel;
        if !(0.0..WIDTH as f32).contains(&x) || !(0.0..HEIGHT as f32).contains(&y) {
            continue;
        }
        let sum = &mut sums[y as usize * WIDTH + x as usize];
        sum.shown += 1.0;
        // The sample's normal on the round needle, as the impostor's
        // measures light it (none where the round end reaches past the cap).
        let Some(normal) = frame.seen_normal(0, needle, Vec2::new(across, height)) else {
            continue;
        };
        let lambert = f64::from(normal.dot(sun).max(0.0));
        let albedo = colors
            .get(needle.group as usize)
            .map_or(Vec3::splat(0.05), |c| c.seen_from(&record.material, eye));
        let grey = f64::from(albedo.element_sum() / 3.0);
        let (sun_diffuse, sun_specular) = bevy_direct(normal, view, sun, roughness, reflectance);
        let (ambient_diffuse, ambient_specular) = bevy_ambient(normal.dot(view), roughness, reflectance);
        let diffuse_light = f64::from(SUN_LUX * sun_diffuse + AMBIENT * ambient_diffuse);
        sum.lit += 1.0;
        sum.lambert += lambert;
        sum.albedo += grey;
        sum.albedo_lambert += grey * lambert;
        sum.diffuse_light += diffuse_light;
        sum.diffuse += grey * diffuse_light;
        sum.specular += f64::from(SUN_LUX * sun_specular + AMBIENT * ambient_specular);
        let half = &mut sum.halves[(column + row) % 2];
        half.0 += 1.0;
        half.1 += grey;
    }
    // The crown's mean seen colour, over every lit sample.
    let (albedo_sum, lit_count) = sums.iter().fold((0.0, 0.0), |(a, n), s| (a + s.albedo, n + s.lit));
    let crown_albedo = albedo_sum / lit_count.max(1.0);
    let samples_per_pixel = f64::from((pixel / nearest.step.x) * (pixel / nearest.step.y));
    let load = |path: &str| -> Result<Vec<[f64; 4]>, Box<dyn std::error::Error>> {
        let image = image::open(path)?.to_rgba8();
        if (image.width() as usize, image.height() as usize) != (WIDTH, HEIGHT) {
            return Err(format!("{path}: not {WIDTH} × {HEIGHT}").into());
        }
        Ok(image.pixels().map(|p| p.0.map(f64::from)).collect())
    };
    let reference = load(reference_path)?;
    let ours = ours_path.map(|p| load(p)).transpose()?;
    let grey = |p: &[f64; 4]| (p[0] + p[1] + p[2]) / 3.0;
    // Whether the samples' picture lies where the reference's does: the
    // correlation of the reference's grey level with the samples' mean
    // albedo over whole-pixel shifts of the reference.
    let shifted = |dx: i64, dy: i64| {
        let mut pairs = Vec::new();
        for (k, sum) in sums.iter().enumerate() {
            let (x, y) = ((k % WIDTH) as i64 + dx, (k / WIDTH) as i64 + dy);
            if sum.shown < 0.9 * samples_per_pixel
                || sum.lit == 0.0
                || !(0..WIDTH as i64).contains(&x)
                || !(0..HEIGHT as i64).contains(&y)
            {
                continue;
            }
            let pixel = &reference[y as usize * WIDTH + x as usize];
            if pixel[3] >= OPAQUE {
                pairs.push((grey(pixel), sum.albedo / sum.lit));
            }
        }
        pearson(&pairs)
    };
    let best = (-3..=3)
        .flat_map(|dx| (-3..=3).map(move |dy| (dx, dy)))
        .map(|(dx, dy)| (dx, dy, shifted(dx, dy)))
        .fold((0, 0, f64::NEG_INFINITY), |b, c| if c.2 > b.2 { c } else { b });
    let alignment = format!(
        "  alignment: reference grey ~ albedo {:+.3} as placed, best {:+.3} with the reference shifted by ({}, {}) pixels",
        shifted(0, 0),
        best.2,
        best.0,
        best.1
    );
    let mut rows: Vec<PixelRow> = Vec::new();
    let (mut specular_sum, mut light_sum) = (0.0, 0.0);
    for (k, sum) in sums.iter().enumerate() {
        let covered = reference[k][3] >= OPAQUE && ours.as_ref().is_none_or(|o| o[k][3] >= OPAQUE);
        if !covered || sum.shown < 0.9 * samples_per_pixel || sum.halves.iter().any(|h| h.0 == 0.0) {
            continue;
        }
        let drawn = ours.as_ref().map_or(0.0, |o| grey(&o[k]));
        let radiance = (sum.diffuse + sum.specular) / sum.lit;
        let flat_radiance = (crown_albedo * sum.diffuse_light + sum.specular) / sum.lit;
        specular_sum += sum.specular;
        light_sum += sum.diffuse + sum.specular;
        rows.push(PixelRow {
            reference: grey(&reference[k]),
            lacks: grey(&reference[k]) - drawn,
            lambert: sum.lambert / sum.lit,
            albedo: sum.albedo / sum.lit,
            albedo_lambert: sum.albedo_lambert / sum.lit,
            ours: drawn,
            log_radiance: radiance.max(f64::MIN_POSITIVE).ln(),
            flat_radiance,
            color_change: (radiance / flat_radiance.max(f64::MIN_POSITIVE)).ln(),
            halves: sum.halves.map(|(count, albedo)| albedo / count),
        });
    }
    let n = rows.len() as f64;
    let correlation = |a: &dyn Fn(&PixelRow) -> f64, b: &dyn Fn(&PixelRow) -> f64| {
        pearson(&rows.iter().map(|r| (a(r), b(r))).collect::<Vec<_>>())
    };
    println!(
        "{}: {} pixels (≥ {:.0} samples each), pixel {:.3} m",
        record.name,
        rows.len(),
        0.9 * samples_per_pixel,
        pixel
    );
    println!("{alignment}");
    let measures: [(&str, &Measure); 3] = [
        ("Lambert", &|r| r.lambert),
        ("albedo", &|r| r.albedo),
        ("albedo × Lambert", &|r| r.albedo_lambert),
    ];
    for (name, measure) in measures {
        print!(
            "  reference grey ~ {name}: {:+.3}",
            correlation(&|r| r.reference, measure)
        );
        if ours.is_some() {
            print!(
                "; reference − ours ~ {name}: {:+.3}",
                correlation(&|r| r.lacks, measure)
            );
        }
        println!();
    }
    println!("  Lambert ~ albedo: {:+.3}", correlation(&|r| r.lambert, &|r| r.albedo));
    // How much of a pixel's seen colour is the crown's and how much the
    // draw of its samples: the correlation between the colours of two
    // halves of each pixel's samples, and (Spearman–Brown) what it is for
    // all of them. A predictor this noisy fits at about that share.
    let split_half = correlation(&|r| r.halves[0], &|r| r.halves[1]);
    println!(
        "  seen colour, split-half reliability: {split_half:+.3} (all samples: {:+.3})",
        2.0 * split_half / (1.0 + split_half)
    );
    println!(
        "  Bevy's lighting: specular {:.1} % of the crown's light; reference grey ~ ln radiance: {:+.3}, ~ ln radiance in the crown's colour: {:+.3}",
        100.0 * specular_sum / light_sum.max(f64::MIN_POSITIVE),
        correlation(&|r| r.reference, &|r| r.log_radiance),
        correlation(&|r| r.reference, &|r| r.flat_radiance.max(f64::MIN_POSITIVE).ln()),
    );
    if ours.is_some() {
        let error =
            |changed: &dyn Fn(&PixelRow) -> f64| rows.iter().map(|r| (r.reference - changed(r)).abs()).sum::<f64>() / n;
        // The least-squares share of `by`'s change (in grey levels) that
        // best predicts what ours lacks.
        let share_of = |by: &dyn Fn(&PixelRow) -> f64| {
            let (mut sxy, mut sxx) = (0.0, 0.0);
            for r in &rows {
                sxy += by(r) * r.lacks;
                sxx += by(r) * by(r);
            }
            if sxx > 0.0 { sxy / sxx } else { 0.0 }
        };
        let albedo_change = |r: &PixelRow| r.ours * (r.albedo / crown_albedo - 1.0);
        let share = share_of(&albedo_change);
        println!(
            "  mean |reference − ours| (grey): {:.2} as drawn, {:.2} scaled by the seen albedo, {:.2} by {share:.2} of its change",
            error(&|r| r.ours),
            error(&|r| r.ours + albedo_change(r)),
            error(&|r| r.ours + share * albedo_change(r))
        );
        // The colour's change through Bevy's lighting, in sRGB grey levels.
        let lit_change = |r: &PixelRow| (r.ours + 14.0) / 2.4 * r.color_change;
        let lit_share = share_of(&lit_change);
        println!(
            "  reference − ours ~ ln r: {:+.3}; mean |reference − ours| with the colour's change lit as Bevy lights it: {:.2}, {:.2} by {lit_share:.2} of it",
            correlation(&|r| r.lacks, &|r| r.color_change),
            error(&|r| r.ours + lit_change(r)),
            error(&|r| r.ours + lit_share * lit_change(r)),
        );
    }
    Ok(())
}
