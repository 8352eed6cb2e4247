//! Per-tree multi-draws beside Bevy's own meshes: a mature fir's trunk seen
//! from beside it, with and without a ground mesh in the opaque pass.
//!
//! Mesa's lavapipe (22.3) drew every draw of a multi-draw with the first
//! tree's instance once a `StandardMaterial` mesh was drawn in the same
//! pass: in the forest, a Douglas fir 9 m from the camera lost its trunk
//! (its stubs stayed, drawn by other trees' draws). The plugin splits the
//! multi-draws there (`split_multi_draws`).

mod common;

use bevy::prelude::*;
use bevy_conifer_lod::model::file::read_prototype_record;
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use common::{background_camera, covered_count, mean_difference};
use std::path::PathBuf;

#[test]
fn a_mesh_in_the_opaque_pass_leaves_the_trees_as_they_were() {
    let _turn = common::gpu_turn();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = root.join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    let record = read_prototype_record(&root.join("assets/trees/mature/douglas-fir.conifer")).unwrap();
    let species = ConiferSpecies::from_prototype_record(&record).unwrap();
    let mut renderer = HeadlessRenderer::new(".");
    let handle = renderer
        .world_mut()
        .resource_mut::<Assets<ConiferSpecies>>()
        .add(species);
    HeadlessRenderer::spawn_lights(renderer.world_mut());
    let target = renderer.render_target(160, 90);
    let camera = background_camera(renderer.world_mut(), &target);
    let world = renderer.world_mut();
    world.resource_mut::<ConiferLodSettings>().pixel_error = 3.0;
    // The forest's `--view tree`: its eye 9 m from a fir, looking past it
    // up another's crown; the fir's trunk crosses the picture's left side.
    let eye = Vec3::new(-27.17, 10.83, 145.46);
    *world.get_mut::<Transform>(camera).unwrap() =
        Transform::from_translation(eye).looking_at(Vec3::new(-14.62, 19.89, 151.67), Vec3::Y);
    *world.get_mut::<Projection>(camera).unwrap() = Projection::Perspective(PerspectiveProjection {
        fov: 50f32.to_radians(),
        ..default()
    });
    // Another fir first (the first tree's instance is what lavapipe
    // repeated), out of sight, then the one beside the camera.
    world.spawn((ConiferFoliage(handle.clone()), Transform::from_xyz(-120.0, 10.0, 100.0)));
    world.spawn((
        ConiferFoliage(handle.clone()),
        Transform::from_xyz(-18.04, 10.92, 143.58)
            .with_rotation(Quat::from_rotation_y(3.538))
            .with_scale(Vec3::splat(0.869)),
    ));
    // Buffers fill and pipelines compile over a few frames.
    for _ in 0..3 {
        renderer.update().unwrap();
    }
    let alone = renderer.capture(&target, 20).unwrap();
    alone.save(out.join("trunk_alone.png")).unwrap();
    // A ground mesh below the picture: nothing of it is in view.
    let world = renderer.world_mut();
    let ground = common::spawn_ground(world);
    *world.get_mut::<Transform>(ground).unwrap() = Transform::from_xyz(-20.0, 9.0, 150.0);
    for _ in 0..3 {
        renderer.update().unwrap();
    }
    let with_ground = renderer.capture(&target, 20).unwrap();
    with_ground.save(out.join("trunk_with_ground.png")).unwrap();
    let (a, g) = (covered_count(&alone), covered_count(&with_ground));
    let difference = mean_difference(&alone, &with_ground);
    println!("covered pixels: alone {a}, with a ground mesh {g}; mean grey |Δ| {difference:.3}");
    // The trunk is a large part of the picture.
    assert!(a > 160 * 90 / 20, "the fir is drawn ({a} pixels)");
    assert!(
        g * 20 > a * 19 && difference < 1.0,
        "a ground mesh out of view took the fir's parts: {a} -> {g} pixels, mean |Δ| {difference}"
    );
}
