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
use bevy_conifer_lod::model::impostor::ImpostorOptions;
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

/// One tree of `species` before a camera that clears to black and does
/// not tone-map: a pixel's linear colour is its albedo times the light.
fn black_scene(
    species: ConiferSpecies,
) -> (
    bevy_conifer_lod::plugin::headless::HeadlessRenderer,
    Handle<Image>,
    Entity,
) {
    let (mut renderer, target, camera) = common::one_tree_scene(species, SIZE);
    renderer.world_mut().entity_mut(camera).insert((
        Tonemapping::None,
        Camera {
            clear_color: ClearColorConfig::Custom(Color::BLACK),
            ..default()
        },
    ));
    (renderer, target, camera)
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
    let (mut renderer, target, camera) = black_scene(species);
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

/// Where a trunk stands among the needles decides how much of it shows.
/// A wall of needles 0.3 m in front of a trunk, seen 25 m away from either
/// side, where both are lines: drawn under every needle line
/// (`WoodLineOrder::UnderFoliage`), the trunk keeps the share `t` of its
/// own picture that the wall's lines let through; layered (the default),
/// `g + (1 − g)·t`, `g` the CPU reference's share in sight
/// (`WoodVisibility::at` of the species' impostor, at the trunk's height
/// and nearness from that camera), which is high where the trunk stands
/// in front of the wall and low behind it. Shares are read in linear red
/// (the bark's, ten times the needles'): the trunk's columns less the
/// wall's beside them, over the trunk's own above the wall.
#[test]
fn wood_lines_show_in_front_of_the_needles_and_not_behind() {
    let _turn = common::gpu_turn();
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    let wall = common::side_by_side_needles(34, 0.018, 1.0, 0.008);
    // Green needles with hardly any red (every age and side), red bark.
    let uniform = FoliageMaterial::uniform([0.01, 0.25, 0.08, 1.0], [0.4, 0.2, 0.08, 1.0], 0.6, 0.0);
    let input = PrototypeInput {
        name: "wood among needles".into(),
        prototypes: vec![wall],
        placements: vec![Placement {
            translation: Vec3::new(-0.3, 0.0, 0.3),
            ..Placement::identity(0)
        }],
        wood: vec![WoodSegment {
            start: Vec3::ZERO,
            end: Vec3::new(0.0, 1.2, 0.0),
            start_radius: 0.015,
            end_radius: 0.015,
        }],
        wood_mesh: Default::default(),
        material: uniform,
    };
    let record = bake_prototypes(&input, &BakeOptions::default(), &())
        .unwrap()
        .quantized()
        .unwrap();
    // Texels of 2 cm: the trunk's few samples outweigh the fit's prior.
    let species = ConiferSpecies::from_prototype_record(&record)
        .unwrap()
        .with_impostor(ImpostorOptions { views: 8, texel: 0.02 });
    let impostor = species.impostor.clone().expect("the layers take the impostor's table");
    let radii = impostor.crown_radii();
    let axis = Vec3::new(impostor.axis.x, 0.0, impostor.axis.y);
    // The trunk's share in sight seen from `side` (+1: the camera on +z,
    // the wall in front of the trunk; −1 on −z, the trunk in front).
    let in_sight = |side: f32| {
        let nearness = (Vec3::ZERO - axis).dot(Vec3::Z * side) + 0.015;
        impostor
            .wood_visibility
            .at(&radii, impostor.bottom, impostor.top(), 0.5, nearness)
    };
    let (mut renderer, target, camera) = black_scene(species);
    let mut shot = |side: f32, order: WoodLineOrder, name: &str, setup: &dyn Fn(&mut World)| {
        let world = renderer.world_mut();
        // Lines: with 2 cm texels the tree would be its impostor here.
        world.resource_mut::<ConiferLodSettings>().far_impostor = false;
        world.resource_mut::<ConiferLodSettings>().wood_line_order = order;
        setup(world);
        let centre = Vec3::new(0.0, 0.5, 0.0);
        *world.get_mut::<Transform>(camera).unwrap() =
            Transform::from_translation(centre + Vec3::Z * 25.0 * side).looking_at(centre, Vec3::Y);
        *world.get_mut::<Projection>(camera).unwrap() = Projection::Perspective(PerspectiveProjection {
            fov: 15f32.to_radians(),
            ..default()
        });
        for _ in 0..3 {
            renderer.update().unwrap();
        }
        let image = renderer.capture(&target, 20).unwrap();
        image.save(out.join(format!("wood_layers_{name}.png"))).unwrap();
        image
    };
    // A metre is 160 / (2·25·tan 7.5°) = 24.3 pixels: the wall's rows are
    // 68–92, the trunk above it 63–68; the trunk's two columns are 79 and
    // 80, the wall's beside them 75–77 and 82–84.
    let red = |image: &image::RgbaImage, columns: &[u32], rows: std::ops::Range<u32>| {
        let n = rows.len() as f32;
        rows.map(|y| {
            columns
                .iter()
                .map(|&x| srgb_to_linear(image.get_pixel(x, y)[0]))
                .sum::<f32>()
        })
        .sum::<f32>()
            / n
    };
    let share = |image: &image::RgbaImage| {
        let trunk = red(image, &[79, 80], 72..89);
        // Six columns of the wall: two columns' worth is a third.
        let beside = red(image, &[75, 76, 77, 82, 83, 84], 72..89) / 3.0;
        let alone = red(image, &[79, 80], 64..67);
        (trunk - beside) / alone.max(1e-6)
    };
    let mut gap = [0.0f32; 2];
    for (k, (side, name)) in [(-1.0f32, "in_front"), (1.0, "behind")].into_iter().enumerate() {
        let layered = share(&shot(side, WoodLineOrder::Layered, &format!("{name}_layered"), &|_| {}));
        let under = share(&shot(
            side,
            WoodLineOrder::UnderFoliage,
            &format!("{name}_under"),
            &|_| {},
        ));
        let g = in_sight(side);
        let want = under + g * (1.0 - under);
        println!(
            "trunk {name}: share {layered:.3} layered, {under:.3} under the needles; in sight {g:.3}: want {want:.3}"
        );
        assert!(
            (layered - want).abs() < 0.1,
            "{name}: the trunk's share {layered:.3} layered, the CPU reference's {want:.3} (under {under:.3}, g {g:.3})"
        );
        gap[k] = layered - under;
    }
    // In front of the wall the layers show the trunk; behind it, hardly.
    assert!(in_sight(-1.0) > in_sight(1.0) + 0.3);
    assert!(gap[0] > 0.2 && gap[1] < gap[0] - 0.15, "layered less under: {gap:?}");
    // Lines drawn by their area take the calibration's wood scale, read by
    // the line's pixel size and opacity (CPU reference:
    // `LineCalibration::wood_scale_at`): the trunk's line alone above the
    // wall, 3 cm wide in pixels of 25 m · 2·tan 7.5° / 160 = 4.1 cm
    // (opacity 0.73, between the table's nodes at 1/4 and 1), keeps the
    // table's share of its light.
    let rows = [2.0f32, 1.0, 0.5, 0.25];
    let mut alone = [0.0f32; 2];
    for (k, wood_scales) in [[[1.0f32; 4]; 8], [rows; 8]].into_iter().enumerate() {
        let calibrate = move |world: &mut World| {
            world.resource_mut::<ConiferLodSettings>().line_raster = LineRaster::Area;
            for (_, species) in world.resource_mut::<Assets<ConiferSpecies>>().iter_mut() {
                let calibration = species.line_calibration.as_mut().expect("baked with a calibration");
                calibration.wood_scales = wood_scales;
            }
        };
        let image = shot(
            -1.0,
            WoodLineOrder::UnderFoliage,
            &format!("wood_scale_{k}"),
            &calibrate,
        );
        alone[k] = red(&image, &[79, 80], 64..67);
    }
    let pixel = 25.0 * 2.0 * 7.5f32.to_radians().tan() / 160.0;
    let table = bevy_conifer_lod::model::calibration::LineCalibration {
        wood_scales: [rows; 8],
        ..record.line_calibration.expect("baked with a calibration")
    };
    let want = table.wood_scale_at(pixel, 0.03 / pixel);
    let ratio = alone[1] / alone[0].max(1e-6);
    println!("trunk alone, area lines: red {alone:?}, with the table {ratio:.3} of it, the CPU reference {want:.3}");
    assert!(
        alone[0] > 0.05 && (ratio - want).abs() < 0.05,
        "{alone:?}: {ratio} against {want}"
    );
}
