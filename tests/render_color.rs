//! Colour within a tree, rendered on Mesa's lavapipe and compared with
//! the CPU reference (`model::color`): a placed shoot's needles take their
//! age's colour seen from above and their underside's from beneath, and
//! the bark its height's. The light is white and the material has no
//! specular reflectance, so a pixel's linear RGB is its albedo times one
//! grey: the chroma (R/G, B/G) of the rendered needles is the albedo's.
//! The pictures are cleared to black, so that edges blended with the
//! background keep their chroma.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

mod common;

use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy_conifer_lod::model::color::{bark_color, needle_color};
use bevy_conifer_lod::model::{
    BakeOptions, FoliageMaterial, Needle, Placement, PrototypeInput, WoodSegment, bake_prototypes,
};
use bevy_conifer_lod::prelude::*;
use bevy_conifer_lod::preview::srgb_to_linear;
use std::path::PathBuf;

const SIZE: u32 = 160;

/// Old needles green, young ones yellow, undersides blue; bark brown at
/// the foot and blue from 6 m up, turning from 4 m.
fn material() -> FoliageMaterial {
    FoliageMaterial {
        young_needle_color: [0.10, 0.10, 0.01, 1.0],
        needle_underside_color: [0.05, 0.05, 0.12, 1.0],
        upper_wood_color: [0.02, 0.05, 0.10, 1.0],
        upper_wood_heights: [4.0, 6.0],
        ..FoliageMaterial::uniform([0.02, 0.10, 0.03, 1.0], [0.10, 0.05, 0.02, 1.0], 0.6, 0.0)
    }
}

/// A flat shoot of 20 needles 30 cm long side by side in the prototype's
/// x–y plane, their upper side +z.
fn flat_shoot() -> Vec<Needle> {
    common::side_by_side_needles(20, 0.018, 0.3, 0.008)
}

/// Mean linear chroma (R/G, B/G) of the pixels of `image` that are not
/// black and pass `keep` (column, row), and how many there were.
fn chroma(image: &image::RgbaImage, keep: impl Fn(u32, u32) -> bool) -> (f32, f32, usize) {
    let (mut sum, mut n) = (Vec3::ZERO, 0usize);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let p = image.get_pixel(x, y);
            let brightest = p[0].max(p[1]).max(p[2]);
            if !(24..250).contains(&brightest) || !keep(x, y) {
                continue; // background, or clipped
            }
            sum += Vec3::new(srgb_to_linear(p[0]), srgb_to_linear(p[1]), srgb_to_linear(p[2]));
            n += 1;
        }
    }
    (sum.x / sum.y.max(1e-9), sum.z / sum.y.max(1e-9), n)
}

fn assert_chroma(what: &str, measured: (f32, f32, usize), albedo: Vec3) {
    let (red, blue, pixels) = measured;
    let (want_red, want_blue) = (albedo.x / albedo.y, albedo.z / albedo.y);
    println!("{what}: {pixels} pixels; R/G {red:.3} (albedo {want_red:.3}), B/G {blue:.3} (albedo {want_blue:.3})");
    assert!(pixels > 30, "{what}: {pixels} pixels measured");
    assert!(
        (red - want_red).abs() <= 0.1 * want_red.max(0.2) && (blue - want_blue).abs() <= 0.1 * want_blue.max(0.2),
        "{what}: rendered chroma ({red:.3}, {blue:.3}), the CPU reference's ({want_red:.3}, {want_blue:.3})"
    );
}

#[test]
fn needles_take_their_age_and_side_and_bark_its_height() {
    let _turn = common::gpu_turn();
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    // Two placements of the shoot lying level 1 m up (upper side +y), this
    // year's at x < 0 and a 5-year-old at x > 0; a 10 m trunk at x = 3.
    let level = Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    let placement = |x: f32, needle_age: u8| Placement {
        rotation: level,
        translation: Vec3::new(x, 1.0, 0.15),
        needle_age,
        ..Placement::identity(0)
    };
    let input = PrototypeInput {
        name: "colours".into(),
        prototypes: vec![flat_shoot()],
        placements: vec![placement(-0.42, 0), placement(0.06, 5)],
        wood: vec![WoodSegment {
            start: Vec3::new(3.0, 0.0, 0.0),
            end: Vec3::new(3.0, 10.0, 0.0),
            start_radius: 0.4,
            end_radius: 0.3,
        }],
        wood_mesh: Default::default(),
        material: material(),
    };
    let record = bake_prototypes(&input, &BakeOptions::default(), &())
        .unwrap()
        .quantized()
        .unwrap();
    let species = ConiferSpecies::from_prototype_record(&record).unwrap();
    let (mut renderer, target, camera) = common::one_tree_scene(species, SIZE);
    renderer.world_mut().entity_mut(camera).insert((
        Tonemapping::None,
        Camera {
            clear_color: ClearColorConfig::Custom(Color::BLACK),
            ..default()
        },
    ));
    let mut shot = |transform: Transform, fov_deg: f32, name: &str| {
        let world = renderer.world_mut();
        *world.get_mut::<Transform>(camera).unwrap() = transform;
        *world.get_mut::<Projection>(camera).unwrap() = Projection::Perspective(PerspectiveProjection {
            fov: fov_deg.to_radians(),
            ..default()
        });
        for _ in 0..3 {
            renderer.update().unwrap();
        }
        let image = renderer.capture(&target, 20).unwrap();
        image.save(out.join(format!("color_{name}.png"))).unwrap();
        (image, transform)
    };
    let m = material();
    let half = SIZE / 2;

    // From 0.8 m above the shoots and from 0.8 m beneath, +x to the right
    // of the picture (the camera's own +x is world +x).
    let centre = Vec3::new(0.0, 1.0, 0.0);
    for (name, eye, up, upper_seen) in [
        ("above", centre + Vec3::Y * 0.8, -Vec3::Z, true),
        ("beneath", centre - Vec3::Y * 0.8, Vec3::Z, false),
    ] {
        let (image, transform) = shot(Transform::from_translation(eye).looking_at(centre, up), 40.0, name);
        assert!(transform.right().dot(Vec3::X) > 0.99, "{name}: +x is to the right");
        let to_viewer = if upper_seen { Vec3::Y } else { -Vec3::Y };
        for (side, age, keep) in [("young", 0u8, true), ("old", 5, false)] {
            let measured = chroma(&image, |x, _| (x < half - 4) == keep && (x > half + 4) != keep);
            let albedo = needle_color(&m, age, Vec3::Y, to_viewer);
            assert_chroma(&format!("{name}, {side} shoot"), measured, albedo);
        }
    }

    // The trunk from the side, 14 m away: its foot brown, its top blue.
    let trunk = Vec3::new(3.0, 5.0, 0.0);
    let fov = 50.0f32;
    let (image, _) = shot(
        Transform::from_translation(trunk + Vec3::Z * 14.0).looking_at(trunk, Vec3::Y),
        fov,
        "bark",
    );
    // Rows of heights 2 m and 8 m: a metre is SIZE / (2·14·tan 25°) pixels.
    let pixels_per_metre = SIZE as f32 / (2.0 * 14.0 * (fov.to_radians() / 2.0).tan());
    let row = |height: f32| (half as f32 - (height - 5.0) * pixels_per_metre).round() as u32;
    for height in [2.0f32, 8.0] {
        let r = row(height);
        let measured = chroma(&image, |x, y| x.abs_diff(half) <= 2 && y.abs_diff(r) <= 3);
        assert_chroma(&format!("bark at {height} m"), measured, bark_color(&m, height));
    }
}
