//! Renders every conifer preset to `target/preview/<species>.png` (whole
//! tree, side view) and `target/preview/<species>-closeup.png` (a 40 cm
//! window on a shoot at the crown's edge), both also side by side in
//! `all.png` and `all-closeups.png`, and prints each tree's figures.
//!
//! ```text
//! cargo run --release --example preview_presets [seed]
//! ```

use std::path::PathBuf;
use std::time::Instant;

use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::preview::{PreviewCamera, PreviewOptions, render_preview, tree_primitives};
use glam::Vec3;

const SIZE: u32 = 512;
const FOV: f32 = 0.6;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seed = std::env::args().nth(1).map(|s| s.parse()).transpose()?.unwrap_or(0);
    let out_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/preview");
    std::fs::create_dir_all(&out_dir)?;
    let options = PreviewOptions::default();
    let mut sheet = image::RgbaImage::new(2 * SIZE, 2 * SIZE);
    let mut closeup_sheet = image::RgbaImage::new(2 * SIZE, 2 * SIZE);
    for (index, species) in Species::ALL.into_iter().enumerate() {
        let (sheet_x, sheet_y) = ((index as u32 % 2) * SIZE, (index as u32 / 2) * SIZE);
        let started = Instant::now();
        let tree = generate(
            species,
            &GenerateOptions {
                seed,
                target_needles: None,
            },
        );
        let generation = started.elapsed();
        let Some((min, max)) = tree.needle_bounds() else {
            println!("{species}: no needles");
            continue;
        };
        let mut sizes = std::collections::BTreeMap::<u32, usize>::new();
        for needle in &tree.needles {
            *sizes.entry(needle.group).or_default() += 1;
        }
        let (smallest, largest) = sizes
            .values()
            .fold((usize::MAX, 0), |(lo, hi), &s| (lo.min(s), hi.max(s)));
        let mean_length = tree.needles.iter().map(|n| n.length()).sum::<f32>() / tree.needles.len() as f32;
        println!(
            "{species:20} needles {:6}  groups {:6} (size {smallest}..{largest}, mean {:.1})  wood {:5}  height {:.2} m  width {:.2} m  mean needle {:.1} mm  generated in {:.1} ms",
            tree.needles.len(),
            sizes.len(),
            tree.needles.len() as f32 / sizes.len() as f32,
            tree.wood.len(),
            max.y,
            (max.x - min.x).max(max.z - min.z),
            mean_length * 1000.0,
            generation.as_secs_f64() * 1000.0,
        );

        let primitives = tree_primitives(&tree);
        let lo = min.min(Vec3::ZERO);
        let camera = PreviewCamera::framing(lo, max, SIZE, SIZE, FOV);
        let started = Instant::now();
        let image = render_preview(&primitives, &camera, &options);
        println!(
            "{:20} rendered {} primitives in {:.1} ms",
            "",
            primitives.len(),
            started.elapsed().as_secs_f64() * 1000.0
        );
        image.save(out_dir.join(format!("{}.png", species.name())))?;
        image::imageops::replace(&mut sheet, &image, sheet_x.into(), sheet_y.into());

        let closeup = render_preview(&primitives, &closeup_camera(&tree.needles), &options);
        closeup.save(out_dir.join(format!("{}-closeup.png", species.name())))?;
        image::imageops::replace(&mut closeup_sheet, &closeup, sheet_x.into(), sheet_y.into());
    }
    sheet.save(out_dir.join("all.png"))?;
    closeup_sheet.save(out_dir.join("all-closeups.png"))?;
    for species in Species::ALL {
        let started = Instant::now();
        let tree = generate(
            species,
            &GenerateOptions {
                seed,
                target_needles: Some(1_000_000),
            },
        );
        println!(
            "{species:20} 1M target: {} needles, {} groups in {:.0} ms",
            tree.needles.len(),
            tree.group_count(),
            started.elapsed().as_secs_f64() * 1000.0
        );
    }
    Ok(())
}

/// A camera 40 cm high looking at the needle nearest the crown's +Z edge at
/// two thirds of the crown height, from outside the crown.
fn closeup_camera(needles: &[bevy_conifer_lod::model::Needle]) -> PreviewCamera {
    let top = needles.iter().map(|n| n.tip.y).fold(0.0_f32, f32::max);
    let band = |n: &&bevy_conifer_lod::model::Needle| (n.base.y - 0.6 * top).abs() < 0.1 * top;
    let focus = needles
        .iter()
        .filter(band)
        .max_by(|a, b| (a.base.z - a.base.x.abs()).total_cmp(&(b.base.z - b.base.x.abs())))
        .map_or(Vec3::new(0.0, 0.6 * top, 0.0), |n| n.base);
    let distance = 0.2 / (0.5 * FOV).tan();
    PreviewCamera {
        eye: focus + Vec3::new(0.0, 0.05, distance),
        target: focus - Vec3::new(0.0, 0.0, 0.05),
        vertical_fov: FOV,
        width: SIZE,
        height: SIZE,
    }
}
