//! Species from presets in a running app: how long the longest frame gets
//! while several presets bake in the background, against the same app with
//! nothing baking, and how fast the next start reads them from the cache.

use crate::cli::heap::live_bytes;
use crate::generate::{Preset, Species};
use crate::plugin::PresetCache;
use crate::prelude::*;
use bevy::asset::AssetPlugin;
use bevy::ecs::system::RunSystemOnce;
use bevy::prelude::*;
use serde::Serialize;
use std::path::Path;
use std::time::{Duration, Instant};

/// What loading presets costs the frame.
#[derive(Clone, Debug, Serialize)]
pub struct PresetFigures {
    /// The presets loaded at once (their text form).
    pub presets: Vec<String>,
    /// Trees standing in the app (they start drawing as their species
    /// arrives).
    pub trees: usize,
    /// The first frame, which takes in the trees spawned with the load
    /// call (their instances, not the bake), ms.
    pub spawn_frame_ms: f64,
    /// Frames run after it while the presets baked, until every species
    /// had arrived.
    pub baking_frames: usize,
    /// Longest of those frames, ms: what a bake costs the main thread.
    pub baking_frame_ms_max: f64,
    /// 99th percentile of those frames, ms.
    pub baking_frame_ms_p99: f64,
    /// Median of those frames, ms.
    pub baking_frame_ms_median: f64,
    /// Longest of as many frames of the same app once everything has
    /// loaded, ms: the frame's own noise.
    pub idle_frame_ms_max: f64,
    /// 99th percentile of those idle frames, ms.
    pub idle_frame_ms_p99: f64,
    /// Median of those idle frames, ms.
    pub idle_frame_ms_median: f64,
    /// Baking frames longer than the idle median by more than 2 ms: frames
    /// a bake may have blocked (this machine's own hiccups included).
    pub baking_frames_over_2ms: usize,
    /// Idle frames longer than the idle median by more than 2 ms (as many
    /// frames as baked): the hiccups with nothing baking.
    pub idle_frames_over_2ms: usize,
    /// Wall time from the load call until every species had arrived, s.
    pub bake_seconds: f64,
    /// The same presets in a new app reading the cache the first wrote:
    /// from the load call until every species had arrived, ms.
    pub cached_load_ms: f64,
    /// Needles of the presets' trees, summed.
    pub needles: usize,
    /// Heap the second app (the cached load) holds once every species has
    /// arrived, bytes: its species, their trees and the app itself
    /// (`None` outside the `conifer` tool, whose allocator counts it).
    pub cached_app_heap_bytes: Option<u64>,
    /// Heap the flattened records of those species take once asked for
    /// ([`ConiferSpecies::record`], which the overlay and `conifer eval`
    /// use; drawing never does), bytes.
    pub flattened_heap_bytes: Option<u64>,
}

/// The six presets timed: the six species (mature), each aiming at
/// `needles` needles (`None`: the species' own count).
pub fn timed_presets(needles: Option<usize>) -> Vec<Preset> {
    Species::ALL
        .iter()
        .map(|&s| Preset::new(s))
        .map(|p| Preset {
            target_needles: needles,
            ..p
        })
        .collect()
}

fn app(cache: &Path) -> App {
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, AssetPlugin::default(), TransformPlugin))
        .add_plugins(ConiferLodPlugin {
            preset_cache: PresetCache::Directory(cache.to_path_buf()),
            ..default()
        });
    app.world_mut()
        .spawn((Camera3d::default(), Transform::from_xyz(0.0, 10.0, 200.0)));
    app
}

/// Loads `presets` in `app` and spawns `trees` trees of them on a grid;
/// runs frames until all have arrived and returns each frame's ms.
fn load_all(app: &mut App, presets: &[Preset], trees: usize) -> (Vec<f64>, Vec<Handle<ConiferSpecies>>) {
    let presets = presets.to_vec();
    let handles = app
        .world_mut()
        .run_system_once(move |mut loader: ConiferPresets| presets.iter().map(|&p| loader.load(p)).collect::<Vec<_>>())
        .expect("a system with no conflicting access");
    for i in 0..trees {
        let position = Vec3::new((i % 32) as f32 * 8.0, 0.0, (i / 32) as f32 * 8.0);
        app.world_mut().spawn((
            ConiferFoliage(handles[i % handles.len()].clone()),
            Transform::from_translation(position),
        ));
    }
    let mut frames = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(600);
    loop {
        let start = Instant::now();
        app.update();
        frames.push(start.elapsed().as_secs_f64() * 1e3);
        let server = app.world().resource::<AssetServer>();
        if handles
            .iter()
            .all(|h| server.is_loaded(h) || server.load_state(h).is_failed())
            || Instant::now() > deadline
        {
            break;
        }
    }
    (frames, handles)
}

/// Longest, 99th percentile and median of `frames`.
fn spread(frames: &[f64]) -> (f64, f64, f64) {
    let mut sorted = frames.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |q: f64| {
        sorted
            .get(((sorted.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    (at(1.0), at(0.99), at(0.5))
}

/// Bakes [`timed_presets`] of `needles` needles in an app with `trees`
/// trees, cache in `cache` (emptied first), and reads them back in a second
/// app.
pub fn preset_figures(needles: Option<usize>, trees: usize, cache: &Path) -> PresetFigures {
    let _ = std::fs::remove_dir_all(cache);
    let presets = timed_presets(needles);

    let mut first = app(cache);
    first.update();
    let start = Instant::now();
    let (frames, handles) = load_all(&mut first, &presets, trees);
    let (spawn_frame_ms, baking) = frames
        .split_first()
        .map_or((0.0, &[][..]), |(first, rest)| (*first, rest));
    let bake_seconds = start.elapsed().as_secs_f64();
    let species = first.world().resource::<Assets<ConiferSpecies>>();
    let needles_loaded = handles
        .iter()
        .filter_map(|h| species.get(h))
        .map(|s| s.needle_count as usize)
        .sum();
    let idle: Vec<f64> = (0..baking.len().max(10))
        .map(|_| {
            let start = Instant::now();
            first.update();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();

    drop(first);
    let heap_before = live_bytes();
    let mut second = app(cache);
    second.update();
    let start = Instant::now();
    let (_, cached) = load_all(&mut second, &presets, trees);
    let cached_load_ms = start.elapsed().as_secs_f64() * 1e3;
    let heap_loaded = live_bytes();
    let species = second.world().resource::<Assets<ConiferSpecies>>();
    for handle in &cached {
        if let Some(species) = species.get(handle) {
            species.record();
        }
    }
    let heap_flattened = live_bytes();
    let difference = |a: Option<u64>, b: Option<u64>| Some(b?.saturating_sub(a?));

    let (baking_frame_ms_max, baking_frame_ms_p99, baking_frame_ms_median) = spread(baking);
    let (idle_frame_ms_max, idle_frame_ms_p99, idle_frame_ms_median) = spread(&idle);
    let over_2ms = |frames: &[f64]| frames.iter().filter(|&&ms| ms > idle_frame_ms_median + 2.0).count();
    PresetFigures {
        presets: presets.iter().map(ToString::to_string).collect(),
        trees,
        spawn_frame_ms,
        baking_frames: baking.len(),
        baking_frame_ms_max,
        baking_frame_ms_p99,
        baking_frame_ms_median,
        idle_frame_ms_max,
        idle_frame_ms_p99,
        idle_frame_ms_median,
        baking_frames_over_2ms: over_2ms(baking),
        idle_frames_over_2ms: over_2ms(&idle),
        bake_seconds,
        cached_load_ms,
        needles: needles_loaded,
        cached_app_heap_bytes: difference(heap_before, heap_loaded),
        flattened_heap_bytes: difference(heap_loaded, heap_flattened),
    }
}
