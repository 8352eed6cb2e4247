//! Real renders through the plugin, headless (Mesa's lavapipe is enough):
//! a tree close up shows opaque prisms, far away translucent lines; two
//! cameras at different distances in one frame each get their own LOD.
//! Pictures go to `target/test-output/render/`.
#![cfg(feature = "plugin")]

mod common;

use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, bake, write_record};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use std::path::PathBuf;

const SIZE: u32 = 384;

fn output_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A renderer with one small pine loaded; returns it, the tree's crown centre.
fn scene(dir: &std::path::Path) -> (HeadlessRenderer, Vec3) {
    let tree = generate(
        Species::ScotsPine,
        &GenerateOptions {
            seed: 2,
            target_needles: Some(20000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    write_record(&record, &dir.join("pine.conifer")).unwrap();
    let crown = record.crown_center();
    let mut renderer = HeadlessRenderer::new(&dir.to_string_lossy());
    let handle: Handle<ConiferSpecies> = renderer.world().resource::<AssetServer>().load("pine.conifer");
    renderer
        .world_mut()
        .spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY));
    renderer.world_mut().spawn((
        DirectionalLight {
            illuminance: 8000.0,
            ..default()
        },
        Transform::from_xyz(3.0, 6.0, 5.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    renderer.load(&[handle.untyped()], 600).unwrap();
    (renderer, crown)
}

fn camera(renderer: &mut HeadlessRenderer, crown: Vec3, distance: f32) -> (Entity, Handle<Image>) {
    let target = renderer.render_target(SIZE, SIZE);
    let transform = Transform::from_translation(crown + Vec3::new(0.0, 0.0, distance)).looking_at(crown, Vec3::Y);
    let entity = renderer
        .world_mut()
        .spawn((
            HeadlessRenderer::camera_bundle(&target, transform, 45f32.to_radians()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::NONE),
                ..default()
            },
            // Keep the output linear in coverage: no tonemapping curve on alpha or colour.
            bevy::core_pipeline::tonemapping::Tonemapping::None,
        ))
        .id();
    (entity, target)
}

/// `(opaque needle, partial)` pixel counts: opaque pixels of needle colour
/// (green over red; the bark is red over green), and translucent pixels.
fn coverage(image: &image::RgbaImage) -> (usize, usize) {
    let opaque = image.pixels().filter(|p| p[3] == 255 && p[1] >= p[0]).count();
    let partial = image.pixels().filter(|p| p[3] > 0 && p[3] < 255).count();
    (opaque, partial)
}

#[test]
fn close_prisms_far_lines_and_two_cameras() {
    let _turn = common::gpu_turn();
    let dir = tempfile::tempdir().unwrap();
    let out = output_dir();
    let (mut renderer, crown) = scene(dir.path());

    let mut results = Vec::new();
    // At 384 px and 45°, a pixel is 1.3 mm at 0.6 m (prisms: 2R ≥ 1.4 mm),
    // 8.6 mm at 4 m (original lines) and 0.13 m at 60 m (merged lines).
    for distance in [0.6f32, 4.0, 60.0] {
        let (camera, target) = camera(&mut renderer, crown, distance);
        let image = renderer.capture(&target, 20).unwrap();
        image.save(out.join(format!("pine_{distance}m.png"))).unwrap();
        renderer.world_mut().despawn(camera);
        let (opaque, partial) = coverage(&image);
        println!("{distance} m: {opaque} opaque, {partial} partial pixels");
        results.push((opaque, partial));
    }
    let (near, _, far) = (results[0], results[1], results[2]);
    assert!(near.0 > 500, "close view shows opaque needle prisms: {near:?}");
    assert!(far.0 + far.1 > 30, "far view is not empty: {far:?}");
    assert!(far.1 > 4 * far.0, "far view is mostly translucent lines: {far:?}");

    // Two cameras, one frame.
    let (_, near_target) = camera(&mut renderer, crown, 0.6);
    let (_, far_target) = camera(&mut renderer, crown, 60.0);
    let mut images = renderer.capture_all(&[near_target, far_target], 20).unwrap();
    let far_image = images.pop().unwrap();
    let near_image = images.pop().unwrap();
    near_image.save(out.join("two_cameras_near.png")).unwrap();
    far_image.save(out.join("two_cameras_far.png")).unwrap();
    let (near2, far2) = (coverage(&near_image), coverage(&far_image));
    assert!(near2.0 > 500, "{near2:?}");
    assert!(far2.1 > 4 * far2.0 && far2.1 > 30, "{far2:?}");
}

/// Pixels by dominant channel among drawn pixels: `(blue, green, warm)`,
/// warm meaning red above blue (merged lines run yellow → red).
fn hues(image: &image::RgbaImage) -> (usize, usize, usize) {
    let (mut blue, mut green, mut warm) = (0, 0, 0);
    for p in image.pixels().filter(|p| p[3] > 0) {
        let [r, g, b] = [p[0] as i32, p[1] as i32, p[2] as i32];
        if b > r + 20 && b >= g {
            blue += 1;
        } else if g > r + 20 && g > b + 20 {
            green += 1;
        } else if r > b + 40 {
            warm += 1;
        }
    }
    (blue, green, warm)
}

#[test]
fn overlay_colours_each_representation() {
    let _turn = common::gpu_turn();
    let dir = tempfile::tempdir().unwrap();
    let out = output_dir();
    let (mut renderer, crown) = scene(dir.path());
    renderer.world_mut().resource_mut::<ConiferLodSettings>().debug_colors = true;
    // The lines' colours (at 60 m the tree would be its impostor).
    renderer.world_mut().resource_mut::<ConiferLodSettings>().far_impostor = false;
    let mut found = Vec::new();
    for distance in [0.6f32, 4.0, 60.0] {
        let (camera, target) = camera(&mut renderer, crown, distance);
        let image = renderer.capture(&target, 20).unwrap();
        image.save(out.join(format!("overlay_{distance}m.png"))).unwrap();
        renderer.world_mut().despawn(camera);
        let (blue, green, warm) = hues(&image);
        println!("{distance} m: {blue} blue (prisms), {green} green (lines), {warm} warm (merged lines, wood)");
        found.push((blue, green, warm));
    }
    let [close, middle, far] = [found[0], found[1], found[2]];
    assert!(
        close.0 > 500 && close.0 > 2 * (close.1 + close.2),
        "prisms blue: {close:?}"
    );
    assert!(
        middle.1 > 500 && middle.1 > 2 * (middle.0 + middle.2),
        "original lines green: {middle:?}"
    );
    assert!(far.2 > 20 && far.2 > 2 * (far.0 + far.1), "merged lines warm: {far:?}");
}

/// A shader that does not compile fails the headless frame, naming its
/// pipeline: Bevy logs it and draws on without the pipeline, and the
/// pictures measured from such frames would be missing what it draws.
#[test]
fn a_pipeline_that_fails_to_compile_fails_the_frame() {
    use bevy::render::render_resource::{CachedComputePipelineId, ComputePipelineDescriptor, PipelineCache};
    use bevy::render::{ExtractSchedule, MainWorld, RenderApp};
    use bevy::shader::Shader;
    use bevy_conifer_lod::plugin::headless::HeadlessError;

    #[derive(Resource, Clone)]
    struct Broken(Handle<Shader>);
    #[derive(Resource, Default)]
    struct Queued(Option<CachedComputePipelineId>);

    fn queue_broken(main_world: Res<MainWorld>, cache: Res<PipelineCache>, mut queued: ResMut<Queued>) {
        if queued.0.is_none()
            && let Some(broken) = main_world.get_resource::<Broken>()
        {
            queued.0 = Some(cache.queue_compute_pipeline(ComputePipelineDescriptor {
                label: Some("deliberately broken".into()),
                shader: broken.0.clone(),
                entry_point: Some("main".into()),
                ..default()
            }));
        }
    }

    let _turn = common::gpu_turn();
    let mut renderer = HeadlessRenderer::with_setup(".", |app| {
        let shader = app.world_mut().resource_mut::<Assets<Shader>>().add(Shader::from_wgsl(
            "@compute @workgroup_size(1) fn main() { let x: u32 = ; }",
            "broken.wgsl",
        ));
        app.insert_resource(Broken(shader));
        app.sub_app_mut(RenderApp)
            .init_resource::<Queued>()
            .add_systems(ExtractSchedule, queue_broken);
    });
    let mut failure = None;
    for _ in 0..10 {
        if let Err(error) = renderer.update() {
            failure = Some(error);
            break;
        }
    }
    match failure {
        Some(HeadlessError::Pipeline(label, message)) => {
            assert_eq!(label, "deliberately broken");
            assert!(!message.is_empty());
        }
        other => panic!("expected the broken pipeline to fail the frame, got {other:?}"),
    }
}
