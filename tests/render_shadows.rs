//! Shadows of the foliage, rendered (Mesa's lavapipe is enough): under a
//! directional light whose shadow map draws the needles as translucent
//! lines, the tree's shadow on the ground is as dark as the shadow of every
//! needle drawn as a prism (LOD off), not the shadow of opaque lines.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, bake, write_record};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use std::path::PathBuf;

const SIZE: u32 = 256;

/// Mean linear-ish luminance (0–255) of the picture's lower `fraction` of rows.
fn mean_luminance(image: &image::RgbaImage, fraction: f32) -> f64 {
    let first_row = ((1.0 - fraction) * image.height() as f32) as u32;
    let mut sum = 0.0;
    let mut count = 0usize;
    for y in first_row..image.height() {
        for x in 0..image.width() {
            let p = image.get_pixel(x, y);
            sum += 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64;
            count += 1;
        }
    }
    sum / count.max(1) as f64
}

#[test]
fn line_shadows_are_as_dark_as_prism_shadows() {
    let dir = tempfile::tempdir().unwrap();
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    let tree = generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 4,
            target_needles: Some(20_000),
        },
    );
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    write_record(&record, &dir.path().join("pine.conifer")).unwrap();

    let mut renderer = HeadlessRenderer::new(&dir.path().to_string_lossy());
    let handle: Handle<ConiferSpecies> = renderer.world().resource::<AssetServer>().load("pine.conifer");
    let tree_entity = renderer
        .world_mut()
        .spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY))
        .id();
    let world = renderer.world_mut();
    world.insert_resource(GlobalAmbientLight {
        brightness: 150.0,
        ..default()
    });
    let ground_mesh = world
        .resource_mut::<Assets<Mesh>>()
        .add(Plane3d::default().mesh().size(30.0, 30.0));
    let ground_material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::srgb(0.8, 0.8, 0.8),
        perceptual_roughness: 1.0,
        ..default()
    });
    world.spawn((Mesh3d(ground_mesh), MeshMaterial3d(ground_material)));
    // A low sun from +x: the crown's shadow falls 1–6 m toward −x.
    world.spawn((
        DirectionalLight {
            illuminance: 10_000.0,
            shadow_maps_enabled: true,
            ..default()
        },
        Transform::from_xyz(5.0, 4.0, 0.0).looking_at(Vec3::ZERO, Vec3::Y),
        CascadeShadowConfigBuilder {
            num_cascades: 1,
            maximum_distance: 16.0,
            first_cascade_far_bound: 16.0,
            ..default()
        }
        .build(),
    ));
    renderer.load(&[handle.untyped()], 600).unwrap();

    // From 10 m above the shadow, looking down, +x up the picture: the
    // tree stands at the top edge, its shadow fills the lower part.
    let target = renderer.render_target(SIZE, SIZE);
    renderer.world_mut().spawn((
        HeadlessRenderer::camera_bundle(
            &target,
            Transform::from_xyz(-3.5, 10.0, 0.0).looking_at(Vec3::new(-3.5, 0.0, 0.0), Vec3::X),
            40f32.to_radians(),
        ),
        bevy::core_pipeline::tonemapping::Tonemapping::None,
    ));

    let mut capture = |renderer: &mut HeadlessRenderer, name: &str| {
        let image = renderer.capture(&target, 20).unwrap();
        image.save(out.join(format!("shadow_{name}.png"))).unwrap();
        mean_luminance(&image, 0.7)
    };
    let with_lod = capture(&mut renderer, "lines");
    renderer.world_mut().resource_mut::<ConiferLodSettings>().enabled = false;
    let prisms = capture(&mut renderer, "prisms");
    renderer.world_mut().resource_mut::<ConiferLodSettings>().enabled = true;
    renderer.world_mut().entity_mut(tree_entity).insert(Visibility::Hidden);
    let lit = capture(&mut renderer, "no_tree");

    let (lines_shadow, prism_shadow) = (lit - with_lod, lit - prisms);
    println!("ground {lit:.1}; darkening: prisms {prism_shadow:.2}, lines {lines_shadow:.2}");
    assert!(prism_shadow > 3.0, "the tree casts a visible shadow: {prism_shadow:.2}");
    assert!(
        (lines_shadow - prism_shadow).abs() <= 0.2 * prism_shadow,
        "the lines' shadow darkens the ground by {lines_shadow:.2}, the prisms' by {prism_shadow:.2}"
    );
}
