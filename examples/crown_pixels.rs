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

use bevy_conifer_lod::model::color::shoot_colors;
use bevy_conifer_lod::model::impostor::{CrownImpostor, ImpostorOptions};
use bevy_conifer_lod::model::prism::TriangleMesh;
use bevy_conifer_lod::model::{Needle, read_prototype_record};
use glam::{Vec2, Vec3};

const WIDTH: usize = 480;
const HEIGHT: usize = 270;
const FOV_DEG: f32 = 11.824;
/// Samples along each side of a 10 cm texel.
const PER_TEXEL: u32 = 4;

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
    // Per pixel: samples that show a needle, those of them with a normal
    // (not past a cap), and over those Σ Lambert, Σ albedo grey, Σ albedo
    // grey × Lambert.
    let mut sums = vec![[0.0f64; 5]; WIDTH * HEIGHT];
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
        sum[0] += 1.0;
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
        sum[1] += 1.0;
        sum[2] += lambert;
        sum[3] += grey;
        sum[4] += grey * lambert;
    }
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
    // Per pixel: reference grey, reference − ours, Lambert, albedo,
    // albedo × Lambert, ours' grey.
    let mut rows: Vec<[f64; 6]> = Vec::new();
    for (k, sum) in sums.iter().enumerate() {
        let covered = reference[k][3] >= 240.0 && ours.as_ref().is_none_or(|o| o[k][3] >= 240.0);
        if !covered || sum[0] < 0.9 * samples_per_pixel || sum[1] == 0.0 {
            continue;
        }
        let drawn = ours.as_ref().map_or(0.0, |o| grey(&o[k]));
        rows.push([
            grey(&reference[k]),
            grey(&reference[k]) - drawn,
            sum[2] / sum[1],
            sum[3] / sum[1],
            sum[4] / sum[1],
            drawn,
        ]);
    }
    let correlation = |i: usize, j: usize| {
        let n = rows.len() as f64;
        let mean = |k: usize| rows.iter().map(|r| r[k]).sum::<f64>() / n;
        let (mi, mj) = (mean(i), mean(j));
        let (mut sij, mut sii, mut sjj) = (0.0, 0.0, 0.0);
        for r in &rows {
            sij += (r[i] - mi) * (r[j] - mj);
            sii += (r[i] - mi).powi(2);
            sjj += (r[j] - mj).powi(2);
        }
        sij / (sii * sjj).sqrt().max(f64::MIN_POSITIVE)
    };
    println!(
        "{}: {} pixels (≥ {:.0} samples each), pixel {:.3} m",
        record.name,
        rows.len(),
        0.9 * samples_per_pixel,
        pixel
    );
    for (name, k) in [("Lambert", 2), ("albedo", 3), ("albedo × Lambert", 4)] {
        print!("  reference grey ~ {name}: {:+.3}", correlation(0, k));
        if ours.is_some() {
            print!("; reference − ours ~ {name}: {:+.3}", correlation(1, k));
        }
        println!();
    }
    println!("  Lambert ~ albedo: {:+.3}", correlation(2, 3));
    if ours.is_some() {
        let n = rows.len() as f64;
        let mean_albedo = rows.iter().map(|r| r[3]).sum::<f64>() / n;
        let error = |scaled: &dyn Fn(&[f64; 6]) -> f64| rows.iter().map(|r| (r[0] - scaled(r)).abs()).sum::<f64>() / n;
        // The least-squares share of the albedo's change that best
        // predicts what ours lacks.
        let (mut sxy, mut sxx) = (0.0, 0.0);
        for r in &rows {
            let x = r[5] * (r[3] / mean_albedo - 1.0);
            sxy += x * r[1];
            sxx += x * x;
        }
        let share = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        println!(
            "  mean |reference − ours| (grey): {:.2} as drawn, {:.2} scaled by the seen albedo, {:.2} by {share:.2} of its change",
            error(&|r| r[5]),
            error(&|r| r[5] * r[3] / mean_albedo),
            error(&|r| r[5] * (1.0 + share * (r[3] / mean_albedo - 1.0)))
        );
    }
    Ok(())
}
