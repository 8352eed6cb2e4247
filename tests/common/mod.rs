//! Helpers shared by the render tests: the background they clear to, which
//! pixels a tree covers, how far two pictures differ, and a camera pointed
//! at a crown.
#![allow(dead_code)] // each test file uses its own subset

use bevy::prelude::*;

/// Held by a render test for as long as it renders, so that the tests of
/// one file take turns. With two apps rendering at once in one process on
/// lavapipe, about one run in five of `render_shadows` brought back one
/// test's pictures blank white (its sun scene as if lit by the other test's
/// 2,000,000 lm lamp); CI failed on it.
pub fn gpu_turn() -> std::sync::MutexGuard<'static, ()> {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    TURN.lock().unwrap_or_else(|e| e.into_inner())
}

/// The clear colour of the render tests' cameras.
pub const BACKGROUND: [u8; 3] = [235, 237, 242];

/// Whether each pixel differs from the background by more than 6 grey levels.
pub fn covered(image: &image::RgbaImage) -> Vec<bool> {
    image
        .pixels()
        .map(|p| (0..3).any(|c| (p[c] as i32 - BACKGROUND[c] as i32).abs() > 6))
        .collect()
}

/// How many pixels differ from the background by more than 6 grey levels.
pub fn covered_count(image: &image::RgbaImage) -> usize {
    covered(image).into_iter().filter(|&c| c).count()
}

/// A pixel's grey level (0–255): the mean of its RGB channels.
pub fn grey(p: &image::Rgba<u8>) -> f32 {
    (p[0] as f32 + p[1] as f32 + p[2] as f32) / 3.0
}

/// Mean grey level of the pixels a picture covers.
pub fn covered_grey(image: &image::RgbaImage) -> f32 {
    let (sum, n) = image
        .pixels()
        .zip(covered(image))
        .filter(|(_, c)| *c)
        .fold((0.0f32, 0usize), |(sum, n), (p, _)| (sum + grey(p), n + 1));
    sum / n.max(1) as f32
}

/// Mean |Δ| of the grey levels (0–255) over the pixels either picture covers.
pub fn mean_difference(a: &image::RgbaImage, b: &image::RgbaImage) -> f32 {
    let (ca, cb) = (covered(a), covered(b));
    let (mut sum, mut n) = (0.0f32, 0usize);
    for (i, (pa, pb)) in a.pixels().zip(b.pixels()).enumerate() {
        if ca[i] || cb[i] {
            sum += (grey(pa) - grey(pb)).abs();
            n += 1;
        }
    }
    sum / n.max(1) as f32
}

/// Puts `camera` `distance` metres in front of `crown` (+z), looking at it
/// with a vertical field of view of `fov_deg`.
pub fn look_at_crown(world: &mut World, camera: Entity, crown: Vec3, distance: f32, fov_deg: f32) {
    let eye = crown + Vec3::Z * distance;
    *world.get_mut::<Transform>(camera).unwrap() = Transform::from_translation(eye).looking_at(crown, Vec3::Y);
    *world.get_mut::<Projection>(camera).unwrap() = Projection::Perspective(PerspectiveProjection {
        fov: fov_deg.to_radians(),
        ..default()
    });
}

/// A 45° camera rendering into `target`, cleared to [`BACKGROUND`].
pub fn background_camera(world: &mut World, target: &Handle<Image>) -> Entity {
    world
        .spawn((
            bevy_conifer_lod::plugin::headless::HeadlessRenderer::camera_bundle(
                target,
                Transform::IDENTITY,
                45f32.to_radians(),
            ),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::srgb_u8(BACKGROUND[0], BACKGROUND[1], BACKGROUND[2])),
                ..default()
            },
        ))
        .id()
}

/// A 60 m grey ground plane (matte) at y = 0, for shadows to fall on.
pub fn spawn_ground(world: &mut World) -> Entity {
    let mesh = world
        .resource_mut::<Assets<Mesh>>()
        .add(Plane3d::default().mesh().size(60.0, 60.0));
    let material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
        base_color: Color::srgb(0.6, 0.6, 0.6),
        perceptual_roughness: 1.0,
        reflectance: 0.0,
        ..default()
    });
    world.spawn((Mesh3d(mesh), MeshMaterial3d(material))).id()
}

/// `count` needles `length` long and `radius` thick, standing side by side
/// along +x every `spacing` metres from the origin, along +y, facing +z:
/// a flat shoot.
pub fn side_by_side_needles(
    count: usize,
    spacing: f32,
    length: f32,
    radius: f32,
) -> Vec<bevy_conifer_lod::model::Needle> {
    (0..count)
        .map(|k| bevy_conifer_lod::model::Needle {
            base: Vec3::new(k as f32 * spacing, 0.0, 0.0),
            tip: Vec3::new(k as f32 * spacing, length, 0.0),
            radius,
            normal: Vec3::Z,
            group: 0,
        })
        .collect()
}

/// A headless renderer drawing `species` as one tree at the origin, lit
/// by its sun, seen by a [`background_camera`] rendering into a `size ×
/// size` target: the renderer, the target and the camera.
pub fn one_tree_scene(
    species: bevy_conifer_lod::plugin::ConiferSpecies,
    size: u32,
) -> (
    bevy_conifer_lod::plugin::headless::HeadlessRenderer,
    Handle<Image>,
    Entity,
) {
    use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
    let mut renderer = HeadlessRenderer::new(".");
    let handle = renderer
        .world_mut()
        .resource_mut::<Assets<bevy_conifer_lod::plugin::ConiferSpecies>>()
        .add(species);
    HeadlessRenderer::spawn_lights(renderer.world_mut());
    renderer
        .world_mut()
        .spawn((bevy_conifer_lod::plugin::ConiferFoliage(handle), Transform::IDENTITY));
    let target = renderer.render_target(size, size);
    let camera = background_camera(renderer.world_mut(), &target);
    (renderer, target, camera)
}

/// A shoot of 12 needles 30 cm long side by side in the prototype's x–y
/// plane.
pub fn shoot() -> Vec<bevy_conifer_lod::model::Needle> {
    side_by_side_needles(12, 0.03, 0.3, 0.012)
}

/// A 10 m trunk of ten pieces (as a grown trunk has: the wind bends it at
/// their ends), piece `k` from radius `radius(k)` to `radius(k + 1)`, with
/// a shoot at each of `shoots`.
pub fn trunk_with_shoots(shoots: &[Vec3], radius: impl Fn(usize) -> f32) -> bevy_conifer_lod::plugin::ConiferSpecies {
    trunk_with_branches(shoots, radius, &[])
}

/// [`trunk_with_shoots`] with the wood segments `branches` too.
pub fn trunk_with_branches(
    shoots: &[Vec3],
    radius: impl Fn(usize) -> f32,
    branches: &[bevy_conifer_lod::model::WoodSegment],
) -> bevy_conifer_lod::plugin::ConiferSpecies {
    use bevy_conifer_lod::model::{
        BakeOptions, FoliageMaterial, Placement, PrototypeInput, WoodSegment, bake_prototypes,
    };
    let input = PrototypeInput {
        name: "wind".into(),
        prototypes: vec![shoot()],
        placements: shoots
            .iter()
            .map(|&translation| Placement {
                translation,
                ..Placement::identity(0)
            })
            .collect(),
        wood: (0..10)
            .map(|k| WoodSegment {
                start: Vec3::new(0.0, 0.97 * k as f32, 0.0),
                end: Vec3::new(0.0, 0.97 * (k + 1) as f32, 0.0),
                start_radius: radius(k),
                end_radius: radius(k + 1),
            })
            .chain(branches.iter().copied())
            .collect(),
        wood_mesh: Default::default(),
        material: FoliageMaterial::default(),
    };
    let record = bake_prototypes(&input, &BakeOptions::default(), &())
        .unwrap()
        .quantized()
        .unwrap();
    bevy_conifer_lod::plugin::ConiferSpecies::from_prototype_record(&record).unwrap()
}

/// A headless renderer with a `size`² target, lit by the headless sun alone
/// (no ambient light): what a picture shows is the sun's light. Returns the
/// renderer, its target and the sun.
pub fn sun_lit_renderer(
    size: u32,
) -> (
    bevy_conifer_lod::plugin::headless::HeadlessRenderer,
    Handle<Image>,
    Entity,
) {
    let mut renderer = bevy_conifer_lod::plugin::headless::HeadlessRenderer::new(".");
    let target = renderer.render_target(size, size);
    let world = renderer.world_mut();
    let sun = bevy_conifer_lod::plugin::headless::HeadlessRenderer::spawn_lights(world);
    world.insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    });
    (renderer, target, sun)
}

/// Linear light (clamped to `[0, 1]`) as an sRGB level in `[0, 255]`,
/// not rounded.
pub fn srgb_level(linear: f32) -> f32 {
    let c = linear.clamp(0.0, 1.0);
    let encoded = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    encoded * 255.0
}

/// An sRGB-encoded byte as linear light in `[0, 1]`.
pub fn linear(c: u8) -> f32 {
    let c = f32::from(c) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// What the compute passes wrote for `species` in the camera's view (the
/// first perspective view read back; the readback must be enabled,
/// `CompactReadback::enabled`).
pub fn camera_readback(
    world: &World,
    species: AssetId<bevy_conifer_lod::plugin::ConiferSpecies>,
) -> bevy_conifer_lod::plugin::ViewReadback {
    world
        .resource::<bevy_conifer_lod::plugin::CompactReadback>()
        .views
        .iter()
        .find(|v| v.species == species && v.perspective)
        .expect("the camera's compute results")
        .clone()
}
