//! How the needles a crown shows are lit, against how its impostor lights
//! them: for each record and each of `conifer eval`'s suns, the Lambert
//! factor averaged over every needle by projected area (what the impostor
//! texels' shares are fitted to), over what the views show (each sample lit
//! at the normal of the needle nearest the camera there) and as the
//! impostor's texels light it ([`CrownImpostor::view_lambert`]), averaged
//! over the impostor's views; and the impostor's light times the record's
//! view light scale at that sun ([`CrownImpostor::view_light_scale`]: what
//! the plugin draws) over what the views show.
//!
//! A second table looks at blocks of 2 × 2 texels (a pixel at 250 m in
//! `conifer eval`'s far views) that the needles cover whole: how much the
//! Lambert of what each block shows varies from block to block, how much
//! the texels' shares vary, the mean error of the shares once their bias
//! over the crown is taken out, and the mean error of the best line in
//! the block's mean seen normal · L. Used in the README's "The far crown lit by
//! the needles it shows".
//!
//! ```text
//! cargo run --release --no-default-features --example visible_light -- RECORD...
//! ```
//!
//! [`CrownImpostor::view_lambert`]: bevy_conifer_lod::model::impostor::CrownImpostor::view_lambert
//! [`CrownImpostor::view_light_scale`]: bevy_conifer_lod::model::impostor::CrownImpostor::view_light_scale

use bevy_conifer_lod::model::impostor::CrownImpostor;
use bevy_conifer_lod::model::{Needle, WoodSegment, read_prototype_record};
use glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        return Err("usage: visible_light RECORD...".into());
    }
    // `conifer eval`'s suns in the view's frame (x right, y up, z toward
    // the camera): `EvalSun::transform`, the camera on +z.
    let low = 15f32.to_radians();
    let suns = [
        ("front", Vec3::new(4.0, 8.0, 6.0).normalize()),
        ("side", Vec3::new(low.cos(), low.sin(), 0.0)),
        ("back", Vec3::new(0.0, low.sin(), -low.cos())),
    ];
    println!(
        "| record | sun | every needle | needles seen | impostor | impostor / seen | shares of the seen | their / seen | scaled impostor / seen |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut blocks_table = vec![
        "| record | sun | blocks | seen Lambert | its spread (sd) | shares' spread (sd) | shares' error, bias out | error of a line in mean normal · L |".to_string(),
        "|---|---|---:|---:|---:|---:|---:|---:|".to_string(),
    ];
    for path in paths {
        let record = read_prototype_record(std::path::Path::new(&path))?;
        let impostor = record.impostor.as_deref().ok_or("the record has no crown impostor")?;
        let needles = record.placed_needles();
        let scale = impostor.view_light_scale.unwrap_or_default();
        for (name, sun) in suns {
            let (mut sums, mut views) = ([0.0f64; 4], 0u32);
            for view in 0..impostor.views {
                if let Some(lambert) = impostor.view_lambert(view, &record.wood, &needles, sun) {
                    sums[0] += f64::from(lambert.all_needles);
                    sums[1] += f64::from(lambert.seen_needles);
                    sums[2] += f64::from(lambert.impostor);
                    sums[3] += f64::from(lambert.shares_of_seen);
                    views += 1;
                }
            }
            let [all, seen, texels, fitted] = sums.map(|s| s / f64::from(views.max(1)));
            println!(
                "| {} | {name} | {all:.4} | {seen:.4} | {texels:.4} | {:.3} | {fitted:.4} | {:.3} | {:.3} |",
                record.name,
                texels / seen,
                fitted / seen,
                texels * f64::from(scale.at(sun)) / seen
            );
            let b = blocks(impostor, &record.wood, &needles, sun);
            blocks_table.push(format!(
                "| {} | {name} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} |",
                record.name, b.count, b.seen_mean, b.seen_spread, b.shares_spread, b.shares_error, b.normal_error
            ));
        }
    }
    println!();
    for line in blocks_table {
        println!("{line}");
    }
    Ok(())
}

/// The second table's row for one record and sun.
struct Blocks {
    count: usize,
    seen_mean: f64,
    seen_spread: f64,
    shares_spread: f64,
    shares_error: f64,
    normal_error: f64,
}

/// Over every view's 2 × 2 blocks of texels whose needles cover them
/// (each texel 90 %, 56 of the block's 64 samples a needle): the Lambert
/// of what the block shows, of its texels' shares (by coverage), and its
/// mean seen normal · L.
fn blocks(impostor: &CrownImpostor, wood: &[WoodSegment], needles: &[Needle], sun: Vec3) -> Blocks {
    let valid: Vec<&Needle> = needles.iter().filter(|n| n.is_valid()).collect();
    let (columns, rows) = (impostor.columns as usize, impostor.rows as usize);
    let (mut seen, mut shares, mut normal) = (Vec::new(), Vec::new(), Vec::new());
    for view in 0..impostor.views {
        let (right, toward) = (impostor.view_right(view), impostor.view_toward(view));
        let to_light = sun.x * right + sun.y * Vec3::Y + sun.z * toward;
        let samples = impostor.seen_samples(view, wood, &valid);
        let mut texels = vec![(0.0f64, Vec3::ZERO, 0u32); columns * rows];
        for (n, &t) in samples.normals.iter().zip(&samples.texels) {
            let texel = &mut texels[t as usize];
            texel.0 += f64::from(n.dot(to_light).max(0.0));
            texel.1 += *n;
            texel.2 += 1;
        }
        for row in (0..rows.saturating_sub(1)).step_by(2) {
            for column in (0..columns.saturating_sub(1)).step_by(2) {
                let (mut lambert, mut sum, mut count, mut lit, mut covered) = (0.0, Vec3::ZERO, 0, 0.0, 0.0);
                let mut whole = true;
                for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let (r, c) = (row + dr, column + dc);
                    let t = texels[r * columns + c];
                    (lambert, sum, count) = (lambert + t.0, sum + t.1, count + t.2);
                    let Some(texel) = impostor.texel_at(view, c as u32, r as u32) else {
                        whole = false;
                        continue;
                    };
                    whole &= texel.coverage >= 0.9;
                    lit += f64::from(texel.coverage * texel.shares.lambert(Vec3::Y, right, toward, to_light));
                    covered += f64::from(texel.coverage);
                }
                if !whole || count < 56 {
                    continue;
                }
                seen.push(lambert / f64::from(count));
                shares.push(lit / covered);
                normal.push(f64::from((sum / count as f32).dot(to_light)));
            }
        }
    }
    let n = seen.len().max(1) as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    let spread = |v: &[f64]| (v.iter().map(|x| (x - mean(v)).powi(2)).sum::<f64>() / n).sqrt();
    let (seen_mean, shares_mean) = (mean(&seen), mean(&shares));
    let shares_error = seen
        .iter()
        .zip(&shares)
        .map(|(s, t)| (s - seen_mean - t + shares_mean).abs())
        .sum::<f64>()
        / n;
    // The least-squares line seen ≈ a + b · (mean normal · L).
    let normal_mean = mean(&normal);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (x, y) in normal.iter().zip(&seen) {
        sxy += (x - normal_mean) * (y - seen_mean);
        sxx += (x - normal_mean).powi(2);
    }
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let normal_error = normal
        .iter()
        .zip(&seen)
        .map(|(x, y)| (seen_mean + slope * (x - normal_mean) - y).abs())
        .sum::<f64>()
        / n;
    Blocks {
        count: seen.len(),
        seen_mean,
        seen_spread: spread(&seen),
        shares_spread: spread(&shares),
        shares_error,
        normal_error,
    }
}
