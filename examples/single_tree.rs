//! One tree, an orbit camera, and the LOD overlay: the place to watch
//! needles go from round prisms to lines to merged lines as the camera
//! backs off.
//!
//! ```text
//! cargo run --example single_tree [-- --species norway-spruce]
//! cargo run --example single_tree -- --headless --distance 0.6 --screenshot close.png
//! ```
//!
//! Keys: `W`/`S` (or the mouse wheel) closer/farther, `A`/`D` orbit, `R`/`F`
//! up/down along the trunk; and the keys of `conifer_lod_keys`: `[`/`]`
//! pixel error ε ÷/× 1.25, `,`/`.` δ, `F3` (or `O`) the overlay (colours by
//! representation, distance rings, stats), `L` LOD on/off, `P` the opacity
//! rule, `-`/`=` wind strength −/+ 0.5. The tree is baked at startup from a
//! procedural preset (about a second), so any preset and needle count can
//! be tried.

use bevy::input::mouse::AccumulatedMouseScroll;
use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, bake};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use clap::Parser;
use std::path::PathBuf;

#[derive(Parser, Debug, Clone, Resource)]
#[command(about = "One conifer with continuous LOD and the debug overlay")]
struct Args {
    /// Preset: scots-pine, norway-spruce, eastern-white-pine, lawson-cypress.
    #[arg(long, default_value = "scots-pine")]
    species: Species,
    /// Needles (about).
    #[arg(long)]
    needles: Option<usize>,
    /// Camera distance from the crown centre, metres.
    #[arg(long, default_value_t = 12.0)]
    distance: f32,
    /// Camera height above the crown centre, metres.
    #[arg(long, default_value_t = 0.0)]
    height: f32,
    /// Vertical field of view, degrees (small: a telephoto close-up).
    #[arg(long, default_value_t = 45.0)]
    fov_deg: f32,
    /// Pixel error ε.
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f32,
    /// Overlay off at start (it is on by default here).
    #[arg(long)]
    no_overlay: bool,
    /// Render into Bevy's 8-bit main texture instead of the 16-bit float
    /// one (`Hdr`, the default here): every blend of a translucent line is
    /// then rounded to 8 bits, and lines are drawn as hardware lines
    /// (`LineRaster::Auto`).
    #[arg(long)]
    ldr: bool,
    /// Render one picture without a window and exit.
    #[arg(long)]
    headless: bool,
    /// Picture of headless mode.
    #[arg(long, default_value = "target/single_tree.png")]
    screenshot: PathBuf,
    /// Picture size, pixels (square).
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Wind strength (0 calm, 1 a light breeze, 3 strong). Default: a
    /// light breeze in a window, calm headless.
    #[arg(long)]
    wind: Option<f32>,
}

/// The orbit: distance, angle and height around the crown centre.
#[derive(Resource, Clone, Copy)]
struct Orbit {
    center: Vec3,
    distance: f32,
    angle: f32,
    height: f32,
}

impl Orbit {
    fn transform(&self) -> Transform {
        let eye =
            self.center + Vec3::new(self.angle.sin(), 0.0, self.angle.cos()) * self.distance + Vec3::Y * self.height;
        Transform::from_translation(eye).looking_at(self.center + Vec3::Y * self.height, Vec3::Y)
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let record = bake(
        &generate(
            args.species,
            &GenerateOptions {
                seed: 0,
                target_needles: args.needles,
                age: bevy_conifer_lod::generate::Age::Young,
            },
        ),
        &BakeOptions::default(),
        &(),
    )?;
    let orbit = Orbit {
        center: record.crown_center(),
        distance: args.distance.max(0.05),
        angle: 0.0,
        height: args.height,
    };
    let scene_args = args.clone();
    let scene = move |app: &mut App| {
        app.add_plugins(ConiferLodDebugPlugin::default())
            .insert_resource(orbit)
            .insert_resource(TreeRecord(Some(record)))
            .insert_resource(scene_args)
            .add_systems(Startup, setup)
            .add_systems(Update, ((controls, follow_orbit).chain(), conifer_lod_keys));
    };
    if !args.headless {
        let mut app = App::new();
        app.add_plugins((DefaultPlugins, ConiferLodPlugin::default()));
        scene(&mut app);
        app.run();
        return Ok(());
    }
    // The checkout's assets: `cargo run` names it at run time, so a build
    // shared by two clones (one `CARGO_TARGET_DIR`) reads the right one.
    let assets = std::env::var("CARGO_MANIFEST_DIR").map_or_else(
        |_| concat!(env!("CARGO_MANIFEST_DIR"), "/assets").to_owned(),
        |dir| format!("{dir}/assets"),
    );
    let mut renderer = HeadlessRenderer::with_setup(&assets, scene);
    let target = renderer.render_target(args.size, args.size);
    renderer.world_mut().insert_resource(HeadlessTarget(target.clone()));
    // The species is built in Startup; a few frames bring it to the GPU.
    for _ in 0..6 {
        renderer.update()?;
    }
    let picture = renderer.capture(&target, 20)?;
    if let Some(dir) = args.screenshot.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    picture.save(&args.screenshot)?;
    let stats = *renderer.world().resource::<ConiferLodStats>();
    if stats.visible_instances == 0 || stats.lines + stats.triangles == 0 {
        return Err(format!("the tree was not drawn: {stats:?}").into());
    }
    println!(
        "{{\"screenshot\": {:?}, \"distance\": {}, \"prisms\": {}, \"triangles\": {}, \"lines_original\": {}, \"lines_merged\": {}}}",
        args.screenshot.display().to_string(),
        args.distance,
        stats.prisms,
        stats.triangles,
        stats.lines_original,
        stats.lines_merged
    );
    Ok(())
}

/// The baked record, handed to the app once.
#[derive(Resource)]
struct TreeRecord(Option<bevy_conifer_lod::model::LodRecord>);

/// In headless mode, the image the camera renders into.
#[derive(Resource)]
struct HeadlessTarget(Handle<Image>);

#[allow(clippy::too_many_arguments)] // a Bevy system
fn setup(
    mut commands: Commands,
    args: Res<Args>,
    orbit: Res<Orbit>,
    mut record: ResMut<TreeRecord>,
    target: Option<Res<HeadlessTarget>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut species: ResMut<Assets<ConiferSpecies>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut settings: ResMut<ConiferLodSettings>,
    mut wind: ResMut<ConiferWind>,
    mut debug: ResMut<ConiferLodDebug>,
) {
    settings.pixel_error = args.pixel_error;
    if let Some(strength) = args.wind {
        wind.strength = strength;
    }
    debug.enabled = !args.no_overlay;
    debug.always_collect_stats = true;
    let Some(record) = record.0.take() else { return };
    match ConiferSpecies::from_record(record) {
        Ok(tree) => {
            let handle = species.add(tree);
            commands.spawn((ConiferFoliage(handle), Transform::IDENTITY));
        }
        Err(error) => error!("the tree does not fit the GPU layout: {error}"),
    }
    commands.spawn((
        Mesh3d(meshes.add(Circle::new(30.0))),
        MeshMaterial3d(materials.add(StandardMaterial {
            base_color: Color::srgb(0.28, 0.3, 0.2),
            perceptual_roughness: 0.95,
            ..default()
        })),
        Transform::from_rotation(Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2)),
    ));
    commands.spawn((
        DirectionalLight {
            illuminance: 9_000.0,
            shadow_maps_enabled: true,
            ..default()
        },
        Transform::from_xyz(4.0, 8.0, 6.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    commands.insert_resource(GlobalAmbientLight {
        brightness: 600.0,
        ..default()
    });
    let mut camera = commands.spawn((
        Camera3d::default(),
        Camera {
            // With `Hdr` Bevy tone-maps the clear colour with the picture:
            // this linear colour comes out as the 8-bit texture's sRGB
            // (0.62, 0.72, 0.82) (Bevy's TonyMcMapface LUT, inverted on the
            // CPU).
            clear_color: ClearColorConfig::Custom(if args.ldr {
                Color::srgb(0.62, 0.72, 0.82)
            } else {
                Color::linear_rgb(0.5072, 0.801, 1.1887)
            }),
            ..default()
        },
        Projection::Perspective(PerspectiveProjection {
            fov: args.fov_deg.clamp(1.0, 170.0).to_radians(),
            near: 0.01,
            ..default()
        }),
        orbit.transform(),
    ));
    // The stats panel draws on this camera, also when it renders to an image.
    camera.insert(IsDefaultUiCamera);
    if !args.ldr {
        camera.insert(bevy::camera::Hdr);
    }
    if let Some(target) = target {
        camera.insert(bevy::camera::RenderTarget::from(target.0.clone()));
    }
}

fn controls(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    scroll: Res<AccumulatedMouseScroll>,
    mut orbit: ResMut<Orbit>,
) {
    let dt = time.delta_secs();
    let mut zoom = -scroll.delta.y * 0.1;
    if keys.pressed(KeyCode::KeyW) {
        zoom -= dt;
    }
    if keys.pressed(KeyCode::KeyS) {
        zoom += dt;
    }
    if zoom != 0.0 {
        orbit.distance = (orbit.distance * zoom.exp()).clamp(0.05, 2000.0);
    }
    if keys.pressed(KeyCode::KeyA) {
        orbit.angle -= dt;
    }
    if keys.pressed(KeyCode::KeyD) {
        orbit.angle += dt;
    }
    if keys.pressed(KeyCode::KeyR) {
        orbit.height += dt * 2.0;
    }
    if keys.pressed(KeyCode::KeyF) {
        orbit.height -= dt * 2.0;
    }
}

fn follow_orbit(orbit: Res<Orbit>, mut camera: Single<&mut Transform, With<Camera3d>>) {
    if orbit.is_changed() {
        **camera = orbit.transform();
    }
}
