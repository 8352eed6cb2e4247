//! Baking in code, for games that bake their trees at build time (a
//! `build.rs` or a tool) and load the records at run time: generate a tree
//! (or import one from glTF with `bevy_conifer_lod::import`), bake it,
//! write the record next to the game's assets, then load it through Bevy's
//! `AssetServer` like any asset and render it (headless, no window).
//!
//! ```text
//! cargo run --example bake_and_load [-- path/to/tree.glb]
//! ```
//! Writes `target/bake_and_load/tree.conifer` and `target/bake_and_load/tree.png`.

use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::import::{ImportOptions, import_gltf};
use bevy_conifer_lod::model::{BakeOptions, bake, write_record};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/bake_and_load");
    std::fs::create_dir_all(&out)?;

    // 1. The input: a glTF given on the command line, or a procedural spruce.
    let tree = match std::env::args().nth(1) {
        Some(path) => import_gltf(std::path::Path::new(&path), &ImportOptions::default())?.0,
        None => generate(
            Species::NorwaySpruce,
            &GenerateOptions {
                seed: 3,
                target_needles: Some(30_000),
                age: bevy_conifer_lod::generate::Age::Young,
            },
        ),
    };
    // 2. Bake (merge hierarchy and errors), 3. write the record atomically.
    let record = bake(&tree, &BakeOptions::default(), &())?;
    let file = out.join("tree.conifer");
    write_record(&record, &file)?;
    println!(
        "baked {} needles into {} ({} bytes)",
        record.needle_count(),
        file.display(),
        std::fs::metadata(&file)?.len()
    );

    // 4. Load it as a Bevy asset and draw it.
    let mut renderer = HeadlessRenderer::new(&out.to_string_lossy());
    let handle: Handle<ConiferSpecies> = renderer.world().resource::<AssetServer>().load("tree.conifer");
    let crown = record.crown_center();
    renderer
        .world_mut()
        .spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY));
    let target = renderer.render_target(384, 384);
    let eye = crown + Vec3::new(0.0, 0.5, 9.0);
    renderer.world_mut().spawn((
        HeadlessRenderer::camera_bundle(
            &target,
            Transform::from_translation(eye).looking_at(crown, Vec3::Y),
            0.8,
        ),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::srgb(0.92, 0.93, 0.95)),
            ..default()
        },
    ));
    renderer.world_mut().spawn((
        DirectionalLight {
            illuminance: 9_000.0,
            ..default()
        },
        Transform::from_xyz(4.0, 8.0, 6.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    renderer.load(&[handle.untyped()], 1000)?;
    let picture = renderer.capture(&target, 20)?;
    picture.save(out.join("tree.png"))?;
    // The background is a flat colour: the tree is whatever differs from it.
    let background = *picture.get_pixel(0, 0);
    let tree_pixels = picture.pixels().filter(|p| **p != background).count();
    println!(
        "rendered {} ({tree_pixels} tree pixels)",
        out.join("tree.png").display()
    );
    if tree_pixels < 500 {
        return Err(format!("the tree did not render: {tree_pixels} pixels differ from the background").into());
    }
    Ok(())
}
