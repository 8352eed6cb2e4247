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
                age: bevy_conifer_lod::generate::Age::Young,
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

        let closeup = render_preview(
            &primitives,
            &closeup_camera(tree.needles.iter().map(|n| n.base), max.y),
            &options,
        );
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
                age: bevy_conifer_lod::generate::Age::Young,
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

/// A camera 40 cm high looking from +Z at the outermost shoot on the
/// crown's +X side at 60 % of the tree's height, so the shoot stands
/// against the sky.
fn closeup_camera(needle_bases: impl Iterator<Item = Vec3>, top: f32) -> PreviewCamera {
    let focus = needle_bases
        .filter(|base| (base.y - 0.6 * top).abs() < 0.08 * top)
        .max_by(|a, b| a.x.total_cmp(&b.x))
        .unwrap_or(Vec3::new(0.0, 0.6 * top, 0.0));
    // Centre the window a little inside the tip so the shoot fills it.
    let target = focus - Vec3::new(0.12, 0.0, 0.0);
    let distance = 0.2 / (0.5 * FOV).tan();
    PreviewCamera {
        eye: target + Vec3::new(0.0, 0.0, distance),
        target,
        vertical_fov: FOV,
        width: SIZE,
        height: SIZE,
    }
}
