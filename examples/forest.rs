//! The main job: a few thousand mature conifers of six species scattered
//! on a procedural, lit, fogged terrain, every one drawn with continuous
//! LOD (prisms near, lines, merged lines, then each tree's crown impostor
//! far away).
//!
//! ```text
//! cargo run --example forest                       # a window, fly through
//! cargo run --example forest -- --headless --frames 8 --screenshot forest.png
//! ```
//!
//! Keys: `WASD` move, `Q`/`E` down/up, `Shift` faster, right mouse button +
//! drag to look; `[`/`]` pixel error ε ÷/× 1.25; `,`/`.` transition δ −/+
//! 0.1; `F3` (or `O`) the LOD debug overlay; `L` LOD on/off (off: every
//! needle a full prism, to feel the difference); `P` the line opacity
//! rule (ours → coverage → the paper's); `-`/`=` wind strength −/+ 0.5;
//! `Esc` quits.
//!
//! The trees are the shipped mature records under `assets/trees/mature/`
//! (one tree per species, 1–2 M needles each); `--grow` grows them from
//! the presets at startup instead, three seeds per species (baked in the
//! background and cached, see `ConiferPresets`). The scatter is
//! [`bevy_conifer_lod::scatter::Scatter`] (blue noise, clearings from a
//! density noise, no trees on slopes over 32°).

use bevy::anti_alias::fxaa::Fxaa;
use bevy::anti_alias::smaa::Smaa;
use bevy::anti_alias::taa::TemporalAntiAliasing;
use bevy::asset::RenderAssetUsages;
use bevy::camera::{Hdr, RenderTarget};
use bevy::input::mouse::AccumulatedMouseMotion;
use bevy::light::{CascadeShadowConfig, CascadeShadowConfigBuilder};
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy_conifer_lod::plugin::aerial_perspective;
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use bevy_conifer_lod::scatter::{HeightMap, Scatter};
use clap::Parser;
use std::path::PathBuf;

/// The six species, their shipped mature records, and their share of the
/// forest.
const SPECIES: [(Species, &str, f32); 6] = [
    (Species::NorwaySpruce, "trees/mature/norway-spruce.conifer", 4.0),
    (Species::ScotsPine, "trees/mature/scots-pine.conifer", 3.0),
    (Species::SilverFir, "trees/mature/silver-fir.conifer", 2.0),
    (Species::DouglasFir, "trees/mature/douglas-fir.conifer", 2.0),
    (
        Species::EasternWhitePine,
        "trees/mature/eastern-white-pine.conifer",
        1.0,
    ),
    (Species::LawsonCypress, "trees/mature/lawson-cypress.conifer", 0.5),
];

/// Trees of different seeds per species (a forest of one tree per species
/// repeats itself).
const SEEDS_PER_SPECIES: u64 = 3;

/// Half the side of the terrain, metres.
const HALF_SIZE: f32 = 300.0;

#[derive(Parser, Debug, Clone, Resource)]
#[command(about = "A conifer forest on procedural terrain, with continuous LOD")]
struct Args {
    /// Render without a window (software Vulkan is enough) and exit.
    #[arg(long)]
    headless: bool,
    /// Extra frames to render in headless mode once the trees have loaded
    /// and settled, before the screenshot.
    #[arg(long, default_value_t = 0)]
    frames: u32,
    /// Where headless mode writes its picture.
    #[arg(long, default_value = "target/forest.png")]
    screenshot: PathBuf,
    /// Picture size in headless mode, window size otherwise, WIDTHxHEIGHT.
    #[arg(long, default_value = "960x540")]
    size: String,
    /// Minimum spacing between trees, metres (fewer trees when larger; a
    /// mature stand is 4–8 m).
    #[arg(long, default_value_t = 6.0)]
    spacing: f32,
    /// Scatter seed.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Pixel error ε.
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f32,
    /// No shadow maps (faster on a software renderer).
    #[arg(long)]
    no_shadows: bool,
    /// How far the sun's shadow maps reach, metres: three cascades to 80 m
    /// (20, 40, 80; to this distance when it is shorter), and past 80 m a
    /// fourth to this distance, where every tree but the nearest casts its
    /// crown impostor.
    #[arg(long, default_value_t = 600.0, value_parser = parse_shadow_distance)]
    shadow_distance: f32,
    /// The shadow maps' spatial error as a multiple of their texel's
    /// (`ConiferLodSettings::shadow_error_scale`; 1 or more).
    #[arg(long, default_value_t = 1.0, value_parser = parse_shadow_error_scale)]
    shadow_error_scale: f32,
    /// The shadow maps draw lines as quads of their bundle's width
    /// (`ConiferLodSettings::shadow_line_quads`), for coarse shadow cuts.
    #[arg(long)]
    shadow_line_quads: bool,
    /// Start with the debug overlay on.
    #[arg(long)]
    overlay: bool,
    /// Start with LOD off (all prisms).
    #[arg(long)]
    lod_off: bool,
    /// Grow the trees from the presets (three seeds per species) instead
    /// of loading the shipped mature records.
    #[arg(long)]
    grow: bool,
    /// Needles per grown tree (default: each species' own count).
    #[arg(long)]
    needles: Option<usize>,
    /// Camera: `overview` (from a hillside above the valley), `ground`
    /// (eye level between the trunks), `tree` (one tree close up) or
    /// `x,y,z:x,y,z` (eye and target).
    #[arg(long, default_value = "overview")]
    view: String,
    /// Wind strength (0 calm, 1 a light breeze, 3 strong). Default: a
    /// light breeze in a window, calm headless (repeatable pictures).
    #[arg(long)]
    wind: Option<f32>,
    /// Anti-aliasing: Bevy's default 4× MSAA, none, or Bevy's FXAA, SMAA
    /// or TAA (the last three with MSAA off, as Bevy requires).
    #[arg(long, value_enum, default_value_t = AntiAliasing::Msaa)]
    aa: AntiAliasing,
    /// Render into Bevy's 8-bit main texture instead of the 16-bit float
    /// one (`Hdr`, the default here): every blend of a translucent line is
    /// then rounded to 8 bits, and the default `--line-raster auto` draws
    /// hardware lines.
    #[arg(long)]
    ldr: bool,
    /// Headless: move the camera by `x,y,z` metres before each extra frame
    /// (`--frames`), looking the same way (a pan: what TAA's history sees).
    #[arg(long, value_parser = parse_vec3)]
    camera_step: Option<Vec3>,
    /// How lines are lit (`ConiferLodSettings::line_lighting`).
    #[arg(long, value_enum, default_value_t = Lighting::Cylinder)]
    line_lighting: Lighting,
    /// How lines are rasterized (`ConiferLodSettings::line_raster`).
    #[arg(long, value_enum, default_value_t = Raster::Auto)]
    line_raster: Raster,
    /// The order in which cameras blend the lines of the trees' expanded
    /// placements (`ConiferLodSettings::line_order`).
    #[arg(long, value_enum, default_value_t = Order::BackToFront)]
    line_order: Order,
    /// Headless: time each render pass on the GPU (Bevy's
    /// `RenderDiagnosticsPlugin`, where the GPU has timestamp queries) and
    /// print the mean of the extra frames (`--frames`) as `gpu_ms`.
    #[arg(long)]
    gpu_timings: bool,
    /// Most placements one view expands into their prototypes' detail
    /// (`ConiferLodSettings::max_expanded_placements`); trees past it, the
    /// farthest first, are drawn as their impostors or level-2 lines.
    #[arg(long)]
    max_expanded: Option<u32>,
    /// The camera elevations over a crown, `START,END` degrees, across
    /// which a far tree's impostor gives way to its lines
    /// (`ConiferLodSettings::impostor_steep_degrees`; default 30,45).
    #[arg(long, value_parser = bevy_conifer_lod::model::impostor::parse_degree_band)]
    impostor_steep: Option<[f32; 2]>,
    /// Haze: the distance in metres at which it leaves a dark object 5 % of
    /// its contrast against the horizon (Koschmieder's visibility; light
    /// haze is 5–10 km, fog under 1 km); 0 turns it off.
    #[arg(long, default_value_t = 8000.0, value_parser = parse_visibility)]
    visibility: f32,
    /// Light the crowns' insides by the full ambient light, as Bevy gives
    /// it (`ConiferLodSettings::sky_occlusion` off; on by default here).
    #[arg(long)]
    no_sky_occlusion: bool,
}

/// How lines are lit (`--line-lighting`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Lighting {
    /// Every line as the cylinder along its chord (the default).
    Cylinder,
    /// A merged line as its needles spread about its chord.
    Bundle,
    /// A strip turned toward the viewer.
    FacingStrip,
}

/// The order in which lines are blended (`--line-order`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Order {
    /// Each placement's lines on their own, the farthest first (the default).
    BackToFront,
    /// One instanced draw per prototype and band.
    ByPrototype,
}

/// How lines are rasterized (`--line-raster`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Raster {
    /// Area lines in a camera with `Hdr`, hardware lines without (the
    /// default).
    Auto,
    /// One-pixel hardware lines.
    Hardware,
    /// Each pixel covered by the line's strip's area in it.
    Area,
}

/// The camera's anti-aliasing (`--aa`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum AntiAliasing {
    /// 4× multisampling, Bevy's default.
    Msaa,
    /// None: one sample a pixel.
    None,
    /// Bevy's `Fxaa` (post-process, one frame).
    Fxaa,
    /// Bevy's `Smaa` (post-process, one frame; its lookup tables).
    Smaa,
    /// Bevy's `TemporalAntiAliasing` (jittered frames blended over time).
    Taa,
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse().ok())
        .collect::<Option<_>>()
        .ok_or_else(|| format!("{s}: expected x,y,z"))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("{s}: expected x,y,z")),
    }
}

/// A distance in metres, finite and at least `least`.
fn parse_metres(s: &str, least: f32) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v >= least && v.is_finite() => Ok(v),
        _ => Err(format!("{s}: expected a distance in metres, {least} or more")),
    }
}

fn parse_shadow_distance(s: &str) -> Result<f32, String> {
    parse_metres(s, 1.0)
}

/// The sun's cascades: as Bevy's builder splits them up to 80 m (20, 40,
/// 80 for three), and one more from 80 m to `distance` past that, so
/// crowns far away take their neighbours' shadows (cast by their
/// impostors, a few texels a crown) instead of only their own shade.
fn sun_cascades(distance: f32) -> CascadeShadowConfig {
    let near = CascadeShadowConfigBuilder {
        num_cascades: 3,
        maximum_distance: distance.min(80.0),
        first_cascade_far_bound: 20.0f32.min(distance / 4.0),
        ..default()
    };
    let mut config: CascadeShadowConfig = near.build();
    if distance > 80.0 {
        config.bounds.push(distance);
    }
    config
}

fn parse_shadow_error_scale(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if (1.0..=1000.0).contains(&v) => Ok(v),
        _ => Err(format!("{s}: expected a scale from 1 to 1000")),
    }
}

fn parse_visibility(s: &str) -> Result<f32, String> {
    parse_metres(s, 0.0)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let (eye, target) = camera_view(&args.view)?;
    let (width, height) = args
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .filter(|&(w, h)| w > 0 && h > 0)
        .ok_or_else(|| format!("--size {}: expected WIDTHxHEIGHT", args.size))?;
    if !args.headless {
        let window = Window {
            title: "conifer forest".into(),
            resolution: (width, height).into(),
            ..default()
        };
        App::new()
            .add_plugins((
                DefaultPlugins.set(WindowPlugin {
                    primary_window: Some(window),
                    ..default()
                }),
                ConiferLodPlugin::default(),
                ConiferLodDebugPlugin::default(),
            ))
            .insert_resource(args)
            .insert_resource(CameraStart { eye, target })
            .add_systems(Startup, setup)
            .add_systems(Update, (fly_camera, conifer_lod_keys, quit_on_escape, announce_ready))
            .run();
        return Ok(());
    }
    let frames = args.frames;
    let aa = args.aa;
    let camera_step = args.camera_step;
    let screenshot = args.screenshot.clone();
    let gpu_timings = args.gpu_timings;
    // The checkout's assets: `cargo run` names it at run time, so a build
    // shared by two clones (one `CARGO_TARGET_DIR`) reads the right one.
    let assets = std::env::var("CARGO_MANIFEST_DIR").map_or_else(
        |_| concat!(env!("CARGO_MANIFEST_DIR"), "/assets").to_owned(),
        |dir| format!("{dir}/assets"),
    );
    let assets = assets.as_str();
    let mut renderer = HeadlessRenderer::with_setup(assets, |app| {
        if gpu_timings {
            app.add_plugins(bevy::render::diagnostic::RenderDiagnosticsPlugin);
        }
        app.add_plugins(ConiferLodDebugPlugin::default())
            .insert_resource(args)
            .insert_resource(CameraStart { eye, target })
            .add_systems(Startup, setup);
    });
    let image = renderer.render_target(width, height);
    renderer.world_mut().insert_resource(HeadlessTarget(image.clone()));
    // Startup scatters the trees and starts baking (or loading) them; then
    // wait for them and let meshes and pipelines reach the GPU.
    let begin = std::time::Instant::now();
    renderer.update()?;
    let handles: Vec<UntypedHandle> = renderer
        .world()
        .resource::<SpeciesHandles>()
        .0
        .iter()
        .map(|h| h.clone().untyped())
        .collect();
    renderer.load(&handles, 2000)?;
    let loaded_after = begin.elapsed();
    let mut frame_ms = Vec::with_capacity(frames as usize);
    // The picture is of the last extra frame, taken while the camera still
    // moves (TAA's history as a player sees it), not of a later still one.
    let mut pending = None;
    for frame in 0..frames {
        if let Some(step) = camera_step {
            let world = renderer.world_mut();
            let mut cameras = world.query_filtered::<&mut Transform, With<Camera3d>>();
            for mut transform in cameras.iter_mut(world) {
                transform.translation += step;
            }
        }
        if frame + 1 == frames {
            pending = Some(renderer.request_screenshots(std::slice::from_ref(&image)));
        }
        let start = std::time::Instant::now();
        renderer.update()?;
        frame_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    frame_ms.sort_by(f64::total_cmp);
    let median_frame_ms = frame_ms.get(frame_ms.len() / 2).copied().unwrap_or(f64::NAN);
    let picture = match pending {
        Some(pending) => renderer.wait_for(&pending, 20)?.remove(0),
        None => renderer.capture(&image, 20)?,
    };
    if let Some(dir) = screenshot.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    picture.save(&screenshot)?;
    let stats = *renderer.world().resource::<ConiferLodStats>();
    if stats.visible_instances == 0 || stats.lines + stats.triangles + stats.impostors == 0 {
        return Err(format!("no tree was drawn: {stats:?}").into());
    }
    let trees = renderer
        .world_mut()
        .query::<&ConiferFoliage>()
        .iter(renderer.world())
        .count();
    let gpu_ms = if gpu_timings {
        gpu_pass_times(renderer.world())
    } else {
        String::new()
    };
    println!(
        "{{\"screenshot\": {:?}, \"aa\": \"{:?}\", \"load_s\": {:.2}, \"total_s\": {:.2}, \"median_frame_ms\": {:.1}, \"trees\": {trees}, \"visible\": {}, \"impostors\": {}, \"fading\": {}, \"prisms\": {}, \"triangles\": {}, \"lines\": {}, \"plugin_cpu_ms\": {:.3}{gpu_ms}}}",
        screenshot.display().to_string(),
        aa,
        loaded_after.as_secs_f64(),
        begin.elapsed().as_secs_f64(),
        median_frame_ms,
        stats.visible_instances,
        stats.impostors,
        stats.fading,
        stats.prisms,
        stats.triangles,
        stats.lines,
        stats.plugin_cpu_ms
    );
    Ok(())
}

/// `, "gpu_ms": {...}`: the GPU time of each render pass Bevy's
/// `RenderDiagnosticsPlugin` timed (its `…/elapsed_gpu` diagnostics), summed
/// over the views that ran it in one frame (shadow cascades, cameras) and
/// averaged over the frames it kept, and the top-level passes' sum as
/// `"frame"`; empty where the GPU has no timestamp queries (lavapipe).
fn gpu_pass_times(world: &World) -> String {
    let store = world.resource::<bevy::diagnostic::DiagnosticsStore>();
    let mut passes: Vec<(String, f64)> = store
        .iter()
        .filter_map(|d| {
            let pass = d
                .path()
                .as_str()
                .strip_prefix("render/")?
                .strip_suffix("/elapsed_gpu")?;
            // One frame's measurements arrive together, at one instant.
            let mut frames: Vec<(std::time::Instant, f64)> = Vec::new();
            for m in d.measurements() {
                match frames.last_mut() {
                    Some((time, sum)) if *time == m.time => *sum += m.value,
                    _ => frames.push((m.time, m.value)),
                }
            }
            let mean = frames.iter().map(|(_, ms)| ms).sum::<f64>() / frames.len().max(1) as f64;
            (!frames.is_empty()).then(|| (pass.to_string(), mean))
        })
        .collect();
    if passes.is_empty() {
        return String::new();
    }
    passes.sort_by(|a, b| a.0.cmp(&b.0));
    // A span inside another (`outer/inner`) is already in the outer's time.
    let frame: f64 = passes.iter().filter(|(p, _)| !p.contains('/')).map(|(_, ms)| ms).sum();
    let fields: Vec<String> = passes.iter().map(|(p, ms)| format!("{p:?}: {ms:.3}")).collect();
    format!(", \"gpu_ms\": {{{}, \"frame\": {frame:.3}}}", fields.join(", "))
}

/// Where the camera starts.
#[derive(Resource, Clone, Copy)]
struct CameraStart {
    eye: Vec3,
    target: Vec3,
}

/// In headless mode, the image the camera renders into.
#[derive(Resource)]
struct HeadlessTarget(Handle<Image>);

/// The species records being loaded.
#[derive(Resource)]
struct SpeciesHandles(Vec<Handle<ConiferSpecies>>);

fn camera_view(view: &str) -> Result<(Vec3, Vec3), String> {
    let ground = |x: f32, z: f32| Vec3::new(x, terrain_height(Vec2::new(x, z)), z);
    match view {
        "overview" => Ok((
            ground(-30.0, 298.0) + Vec3::Y * 55.0,
            ground(20.0, 60.0) + Vec3::Y * 4.0,
        )),
        "ground" => Ok((ground(-6.0, 120.0) + Vec3::Y * 2.0, ground(10.0, 60.0) + Vec3::Y * 12.0)),
        // Replaced in `setup` by the spruce or fir nearest this point.
        "tree" => Ok((
            ground(-18.0, 150.0) + Vec3::Y * 2.0,
            ground(-2.0, 128.0) + Vec3::Y * 2.0,
        )),
        custom => {
            let parse = |s: &str| -> Option<Vec3> {
                let v: Vec<f32> = s.split(',').map(|x| x.trim().parse().ok()).collect::<Option<_>>()?;
                (v.len() == 3).then(|| Vec3::new(v[0], v[1], v[2]))
            };
            custom
                .split_once(':')
                .and_then(|(a, b)| Some((parse(a)?, parse(b)?)))
                .ok_or_else(|| format!("--view {custom}: expected overview, ground or x,y,z:x,y,z"))
        }
    }
}

// The terrain and the clearings need only a smooth, seeded noise: thirty
// lines of value noise here rather than a noise crate in every build.

/// Hash of a lattice point to `[0, 1)`.
fn lattice(x: i32, z: i32, seed: u32) -> f32 {
    let mut h =
        (x as u32).wrapping_mul(0x8da6_b343) ^ (z as u32).wrapping_mul(0xd816_3841) ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h >> 8) as f32 / 16_777_216.0
}

/// Smooth value noise in `[0, 1)`, period 1 per lattice cell.
fn value_noise(p: Vec2, seed: u32) -> f32 {
    let (i, f) = (p.floor(), p - p.floor());
    let (x, z) = (i.x as i32, i.y as i32);
    let s = f * f * (Vec2::splat(3.0) - 2.0 * f);
    let a = lattice(x, z, seed) + (lattice(x + 1, z, seed) - lattice(x, z, seed)) * s.x;
    let b = lattice(x, z + 1, seed) + (lattice(x + 1, z + 1, seed) - lattice(x, z + 1, seed)) * s.x;
    a + (b - a) * s.y
}

/// Fractal sum of `octaves` octaves of value noise, in about `[0, 1)`.
fn fbm(p: Vec2, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amplitude, mut frequency, mut total) = (0.0, 1.0, 1.0, 0.0);
    for octave in 0..octaves {
        sum += amplitude * value_noise(p * frequency, seed + octave);
        total += amplitude;
        amplitude *= 0.5;
        frequency *= 2.03;
    }
    sum / total
}

/// The terrain: rolling hills around a shallow valley along z.
fn terrain_height(p: Vec2) -> f32 {
    let hills = fbm(p / 140.0, 5, 11) * 60.0 - 30.0;
    let valley = (p.x / 120.0).powi(2).min(1.0) * 18.0;
    hills + valley
}

/// Tree density: clearings where a low-frequency noise dips.
fn tree_density(p: Vec2) -> f32 {
    ((fbm(p / 90.0, 3, 29) - 0.35) * 4.0).clamp(0.0, 1.0)
}

fn terrain_mesh(map: &HeightMap) -> Mesh {
    let (columns, rows) = (map.columns, map.rows);
    let mut positions = Vec::with_capacity(columns * rows);
    let mut normals = Vec::with_capacity(columns * rows);
    let mut colors = Vec::with_capacity(columns * rows);
    let step = (map.max - map.min) / Vec2::new((columns - 1) as f32, (rows - 1) as f32);
    for j in 0..rows {
        for i in 0..columns {
            let h = map.get(i, j);
            let dx = (map.get(i + 1, j) - map.get(i.saturating_sub(1), j)) / (2.0 * step.x);
            let dz = (map.get(i, j + 1) - map.get(i, j.saturating_sub(1))) / (2.0 * step.y);
            let normal = Vec3::new(-dx, 1.0, -dz).normalize();
            let p = map.min + step * Vec2::new(i as f32, j as f32);
            positions.push([p.x, h, p.y]);
            normals.push(normal.to_array());
            // Grass on the flats, earth and rock on the slopes.
            let steep = (1.0 - normal.y).clamp(0.0, 0.3) / 0.3;
            let grass = Vec3::new(0.085, 0.12, 0.045);
            let rock = Vec3::new(0.2, 0.18, 0.15);
            let c = grass.lerp(rock, steep) * (0.85 + 0.3 * value_noise(p / 7.0, 3));
            colors.push([c.x, c.y, c.z, 1.0]);
        }
    }
    let mut indices = Vec::with_capacity((columns - 1) * (rows - 1) * 6);
    for j in 0..rows - 1 {
        for i in 0..columns - 1 {
            let a = (j * columns + i) as u32;
            let (b, c, d) = (a + 1, a + columns as u32, a + columns as u32 + 1);
            indices.extend_from_slice(&[a, c, b, b, c, d]);
        }
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
        .with_inserted_attribute(Mesh::ATTRIBUTE_COLOR, colors)
        .with_inserted_indices(Indices::U32(indices))
}

#[allow(clippy::too_many_arguments)] // a Bevy system
fn setup(
    mut commands: Commands,
    args: Res<Args>,
    start: Res<CameraStart>,
    target: Option<Res<HeadlessTarget>>,
    asset_server: Res<AssetServer>,
    mut presets: ConiferPresets,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut settings: ResMut<ConiferLodSettings>,
    mut wind: ResMut<ConiferWind>,
    mut debug: ResMut<ConiferLodDebug>,
) {
    settings.pixel_error = args.pixel_error;
    settings.enabled = !args.lod_off;
    settings.sky_occlusion = !args.no_sky_occlusion;
    settings.shadow_error_scale = args.shadow_error_scale;
    settings.shadow_line_quads = args.shadow_line_quads;
    settings.line_lighting = match args.line_lighting {
        Lighting::Bundle => LineLighting::Bundle,
        Lighting::Cylinder => LineLighting::Cylinder,
        Lighting::FacingStrip => LineLighting::FacingStrip,
    };
    settings.line_order = match args.line_order {
        Order::BackToFront => LineOrder::BackToFront,
        Order::ByPrototype => LineOrder::ByPrototype,
    };
    settings.line_raster = match args.line_raster {
        Raster::Auto => LineRaster::Auto,
        Raster::Area => LineRaster::Area,
        Raster::Hardware => LineRaster::Hardware,
    };
    if let Some(strength) = args.wind {
        wind.strength = strength;
    }
    if let Some(budget) = args.max_expanded {
        settings.max_expanded_placements = budget;
    }
    if let Some(band) = args.impostor_steep {
        settings.impostor_steep_degrees = band;
    }
    debug.enabled = args.overlay;
    debug.always_collect_stats = args.headless;

    let map = HeightMap::from_fn(
        241,
        241,
        Vec2::splat(-HALF_SIZE),
        Vec2::splat(HALF_SIZE),
        terrain_height,
    );
    commands.spawn((
        Mesh3d(meshes.add(terrain_mesh(&map))),
        MeshMaterial3d(materials.add(StandardMaterial {
            perceptual_roughness: 0.95,
            ..default()
        })),
    ));

    let (species, weights): (Vec<Handle<ConiferSpecies>>, Vec<f32>) = if !args.grow {
        SPECIES
            .iter()
            .map(|&(_, path, weight)| (asset_server.load(path), weight))
            .unzip()
    } else {
        SPECIES
            .iter()
            .flat_map(|&(species, _, weight)| (0..SEEDS_PER_SPECIES).map(move |seed| (species, seed, weight)))
            .map(|(species, seed, weight)| {
                let preset = Preset::new(species).with_seed(seed).with_age(Age::Mature);
                let handle = presets.load(match args.needles {
                    Some(needles) => preset.with_needles(needles),
                    None => preset,
                });
                (handle, weight / SEEDS_PER_SPECIES as f32)
            })
            .unzip()
    };
    let placements = Scatter::new(
        Vec2::splat(-HALF_SIZE + 5.0),
        Vec2::splat(HALF_SIZE - 5.0),
        args.spacing,
    )
    .density(tree_density)
    .height(map)
    .max_slope_deg(32.0)
    // Mature trees at their own size, ±15 %.
    .scale_range(0.85, 1.15)
    .species_weights(&weights)
    .seed(args.seed)
    .place();
    spawn_forest(&mut commands, &placements, &species);
    // `--view tree`: 14 m from the nearest spruce or fir, at eye height,
    // looking up its crown.
    let (mut eye, mut look_at) = (start.eye, start.target);
    if args.view == "tree" {
        let per_species = if args.grow { SEEDS_PER_SPECIES as usize } else { 1 };
        let conical = [Species::NorwaySpruce, Species::SilverFir, Species::DouglasFir];
        let nearest = placements
            .iter()
            .filter(|p| conical.contains(&SPECIES[p.species / per_species].0))
            .min_by(|a, b| {
                a.position
                    .distance(start.eye)
                    .total_cmp(&b.position.distance(start.eye))
            });
        if let Some(tree) = nearest {
            let away =
                Vec3::new(start.eye.x - tree.position.x, 0.0, start.eye.z - tree.position.z).normalize_or(Vec3::Z);
            let foot = tree.position + away * 14.0;
            eye = Vec3::new(foot.x, terrain_height(Vec2::new(foot.x, foot.z)) + 1.7, foot.z);
            look_at = tree.position + Vec3::Y * 9.0;
        }
    }
    info!("{} trees", placements.len());
    commands.insert_resource(SpeciesHandles(species));

    commands.spawn((
        DirectionalLight {
            illuminance: 7_000.0,
            shadow_maps_enabled: !args.no_shadows,
            ..default()
        },
        Transform::from_xyz(-0.5, 1.0, 0.35).looking_at(Vec3::ZERO, Vec3::Y),
        // Within 80 m every needle line casts its coverage, and trees the
        // camera sees as impostors keep their lines in the cascades, so a
        // mature forest's shadows cost most of its frame; the fourth
        // cascade's budget goes to the trees nearest the camera too, and
        // the rest cast their impostors.
        sun_cascades(args.shadow_distance),
    ));
    commands.insert_resource(GlobalAmbientLight {
        color: Color::srgb(0.75, 0.85, 1.0),
        brightness: 350.0,
        ..default()
    });
    let haze = Color::srgb(0.55, 0.66, 0.8);
    // With `Hdr` Bevy tone-maps the clear colour with the picture
    // (TonyMcMapface): this linear colour comes out as the 8-bit texture's
    // untouched sRGB haze, found by inverting Bevy's TonyMcMapface LUT on
    // the CPU (to within 0.3 of 255 per channel). The haze's colour is the
    // sky's, so a far stand fades into the sky behind it.
    let sky = if args.ldr {
        haze
    } else {
        Color::linear_rgb(0.3512, 0.5861, 1.0147)
    };
    let mut camera = commands.spawn((
        Camera3d::default(),
        Camera {
            clear_color: ClearColorConfig::Custom(sky),
            ..default()
        },
        Projection::Perspective(PerspectiveProjection {
            fov: 50f32.to_radians(),
            far: 2000.0,
            ..default()
        }),
        Transform::from_translation(eye).looking_at(look_at, Vec3::Y),
    ));
    // Aerial perspective toward the sky's own colour (`aerial_perspective`'s
    // docs: Bevy's `from_visibility_colors` turned the far rows navy).
    if let Some(fog) = aerial_perspective(args.visibility, sky) {
        camera.insert(fog);
    }
    // The stats panel draws on this camera, also when it renders to an image.
    camera.insert(IsDefaultUiCamera);
    if !args.ldr {
        camera.insert(Hdr);
    }
    match args.aa {
        AntiAliasing::Msaa => {}
        AntiAliasing::None => {
            camera.insert(Msaa::Off);
        }
        AntiAliasing::Fxaa => {
            camera.insert((Msaa::Off, Fxaa::default()));
        }
        AntiAliasing::Smaa => {
            camera.insert((Msaa::Off, Smaa::default()));
        }
        AntiAliasing::Taa => {
            camera.insert((Msaa::Off, TemporalAntiAliasing::default()));
        }
    }
    if let Some(target) = target {
        camera.insert(RenderTarget::from(target.0.clone()));
    }
}

/// `Esc` ends the app, as closing the window does.
fn quit_on_escape(keys: Res<ButtonInput<KeyCode>>, mut exit: MessageWriter<AppExit>) {
    if keys.just_pressed(KeyCode::Escape) {
        exit.write(AppExit::Success);
    }
}

/// Logs once that every species has arrived (the window test waits for
/// this line before it sends keys).
fn announce_ready(
    server: Res<AssetServer>,
    species: Option<Res<SpeciesHandles>>,
    mut announced: Local<bool>,
    trees: Query<(), With<ConiferFoliage>>,
) {
    let Some(species) = species else { return };
    if !*announced && species.0.iter().all(|handle| server.is_loaded(handle)) {
        *announced = true;
        info!(
            "forest ready: {} trees of {} species",
            trees.iter().len(),
            species.0.len()
        );
    }
}

fn fly_camera(
    time: Res<Time>,
    keys: Res<ButtonInput<KeyCode>>,
    buttons: Res<ButtonInput<MouseButton>>,
    motion: Res<AccumulatedMouseMotion>,
    mut camera: Single<&mut Transform, With<Camera3d>>,
) {
    let speed = if keys.pressed(KeyCode::ShiftLeft) { 60.0 } else { 12.0 } * time.delta_secs();
    let (forward, right) = (camera.forward().as_vec3(), camera.right().as_vec3());
    let mut step = Vec3::ZERO;
    for (key, direction) in [
        (KeyCode::KeyW, forward),
        (KeyCode::KeyS, -forward),
        (KeyCode::KeyD, right),
        (KeyCode::KeyA, -right),
        (KeyCode::KeyE, Vec3::Y),
        (KeyCode::KeyQ, -Vec3::Y),
    ] {
        if keys.pressed(key) {
            step += direction;
        }
    }
    camera.translation += step.normalize_or_zero() * speed;
    if buttons.pressed(MouseButton::Right) && motion.delta != Vec2::ZERO {
        let (yaw, pitch, _) = camera.rotation.to_euler(EulerRot::YXZ);
        let yaw = yaw - motion.delta.x * 0.003;
        let pitch = (pitch - motion.delta.y * 0.003).clamp(-1.5, 1.5);
        camera.rotation = Quat::from_euler(EulerRot::YXZ, yaw, pitch, 0.0);
    }
}
