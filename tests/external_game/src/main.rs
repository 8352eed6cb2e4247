//! A forest of preset conifers, rendered headless by a plain Bevy app, as a
//! game would write it: no `.conifer` files, no helpers from the crate's
//! own tests. Exits with an error if the picture shows no trees.
//!
//! ```text
//! cargo run -- [PICTURE.png]
//! ```

use bevy::app::ScheduleRunnerPlugin;
use bevy::asset::RenderAssetUsages;
use bevy::camera::RenderTarget;
use bevy::prelude::*;
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat, TextureUsages};
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::window::ExitCondition;
use bevy::winit::WinitPlugin;
use bevy_conifer_lod::prelude::*;
use bevy_conifer_lod::scatter::Scatter;
use std::time::Duration;

const SIZE: UVec2 = UVec2::new(320, 180);
const SKY: Color = Color::srgb(0.62, 0.72, 0.82);
/// Frames to wait for the species to bake and reach the GPU.
const MAX_FRAMES: u32 = 3_000;

#[derive(Resource)]
struct Forest {
    species: Vec<Handle<ConiferSpecies>>,
    target: Handle<Image>,
    frames: u32,
    settled: u32,
    picture: String,
}

/// The latest screenshot's verdict, written by its observer.
#[derive(Resource, Default)]
struct Verdict(Option<Result<f64, String>>);

fn main() -> AppExit {
    let picture = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "external_game.png".to_owned());
    App::new()
        .add_plugins((
            DefaultPlugins
                .set(WindowPlugin {
                    primary_window: None,
                    exit_condition: ExitCondition::DontExit,
                    ..default()
                })
                .disable::<WinitPlugin>(),
            ScheduleRunnerPlugin::run_loop(Duration::ZERO),
            ConiferLodPlugin::default(),
        ))
        .insert_resource(ClearColor(SKY))
        .init_resource::<Verdict>()
        .add_systems(
            Startup,
            move |commands: Commands, presets: ConiferPresets, images: ResMut<Assets<Image>>| {
                setup(commands, presets, images, picture.clone())
            },
        )
        .add_systems(Update, take_picture)
        .run()
}

fn setup(mut commands: Commands, mut presets: ConiferPresets, mut images: ResMut<Assets<Image>>, picture: String) {
    let species = vec![
        // Young trees, scaled up: a forest of mature ones is too heavy for
        // the software renderer CI draws with.
        presets.load(Preset::new(Species::ScotsPine).with_seed(1).with_age(Age::Young)),
        presets.load(Preset::new(Species::NorwaySpruce).with_age(Age::Young)),
        presets.load_named("lawson-cypress?seed=2&age=young"),
    ];
    let trees = Scatter::new(Vec2::splat(-30.0), Vec2::splat(30.0), 4.0)
        .scale_range(2.0, 3.0)
        .species_weights(&[2.0, 2.0, 1.0])
        .seed(3)
        .place();
    spawn_forest(&mut commands, &trees, &species);

    let mut image = Image::new_uninit(
        Extent3d {
            width: SIZE.x,
            height: SIZE.y,
            depth_or_array_layers: 1,
        },
        TextureDimension::D2,
        TextureFormat::Rgba8UnormSrgb,
        RenderAssetUsages::RENDER_WORLD,
    );
    image.texture_descriptor.usage |= TextureUsages::RENDER_ATTACHMENT;
    let target = images.add(image);
    commands.spawn((
        Camera3d::default(),
        RenderTarget::from(target.clone()),
        Transform::from_xyz(0.0, 12.0, 60.0).looking_at(Vec3::new(0.0, 4.0, 0.0), Vec3::Y),
    ));
    commands.spawn((
        DirectionalLight {
            illuminance: 9_000.0,
            ..default()
        },
        Transform::from_xyz(1.0, 2.0, 1.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    commands.insert_resource(Forest {
        species,
        target,
        frames: 0,
        settled: 0,
        picture,
    });
}

/// Once every species has loaded, takes a picture every few frames (the
/// first frames go to compiling pipelines) until one shows the forest, then
/// ends the app; an error if none does within [`MAX_FRAMES`].
fn take_picture(
    mut commands: Commands,
    mut forest: ResMut<Forest>,
    mut verdict: ResMut<Verdict>,
    server: Res<AssetServer>,
    mut exit: MessageWriter<AppExit>,
) {
    forest.frames += 1;
    match verdict.0.take() {
        Some(Ok(share)) => {
            println!(
                "{{\"picture\": {:?}, \"frames\": {}, \"tree_share\": {share:.4}}}",
                forest.picture, forest.frames
            );
            exit.write(AppExit::Success);
            return;
        }
        Some(Err(why)) => info!("not yet: {why}"),
        None => {}
    }
    if forest.frames > MAX_FRAMES {
        error!("no picture of the forest in {MAX_FRAMES} frames");
        exit.write(AppExit::error());
        return;
    }
    for handle in &forest.species {
        if let bevy::asset::LoadState::Failed(error) = server.load_state(handle) {
            error!("a species failed: {error}");
            exit.write(AppExit::error());
            return;
        }
    }
    if !forest.species.iter().all(|h| server.is_loaded(h)) {
        return;
    }
    forest.settled += 1;
    if forest.settled % 8 != 4 {
        return;
    }
    let picture = forest.picture.clone();
    commands.spawn(Screenshot::image(forest.target.clone())).observe(
        move |captured: On<ScreenshotCaptured>, mut verdict: ResMut<Verdict>| {
            verdict.0 = Some(check(&captured.image, &picture));
        },
    );
}

/// Saves the picture; `Ok(share of tree pixels)` if it shows sky above and
/// trees below: pixels far darker than the sky.
fn check(image: &Image, path: &str) -> Result<f64, String> {
    let picture = image.clone().try_into_dynamic().map_err(|e| e.to_string())?.to_rgba8();
    picture.save(path).map_err(|e| format!("cannot write {path}: {e}"))?;
    let sky = SKY.to_srgba().to_u8_array();
    let brightness = |p: &[u8]| p.iter().take(3).map(|&c| u32::from(c)).sum::<u32>();
    let (mut sky_pixels, mut tree_pixels) = (0usize, 0usize);
    for pixel in picture.pixels() {
        if pixel.0.iter().zip(sky).take(3).all(|(a, b)| a.abs_diff(b) <= 6) {
            sky_pixels += 1;
        } else if brightness(&pixel.0) + 120 < brightness(&sky) {
            tree_pixels += 1;
        }
    }
    let total = (picture.width() * picture.height()) as f64;
    let (sky_share, tree_share) = (sky_pixels as f64 / total, tree_pixels as f64 / total);
    if sky_share < 0.2 || tree_share < 0.01 {
        return Err(format!(
            "{:.1} % sky, {:.1} % trees",
            sky_share * 100.0,
            tree_share * 100.0
        ));
    }
    Ok(tree_share)
}
