//! The plugin's systems under `MinimalPlugins` (no renderer): loading
//! records, the per-tree spatial error against the paper's formula, the
//! representation as the camera backs off, settings taking effect, several
//! cameras, defined results without a usable camera, the GPU instances
//! following 100,000 trees, and no asset churn.
#![cfg(feature = "plugin")]

use bevy::asset::{AssetPlugin, LoadState};
use bevy::camera::{CameraProjection, Viewport};
use bevy::ecs::system::RunSystemOnce;
use bevy::prelude::*;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, PixelError, ViewParams, bake, write_record};
use bevy_conifer_lod::plugin::CompactInstances;
use bevy_conifer_lod::prelude::*;

const HEIGHT_PX: u32 = 720;
const FOV_DEG: f32 = 45.0;

/// An app with the plugin and just what it needs, loading from `dir`; the
/// CPU keeps every tree's [`ConiferLodState`] (as for the debug overlay's
/// stats), and mesh assets exist so that any the plugin made would show.
fn app(dir: &std::path::Path) -> App {
    app_with(
        dir,
        ConiferLodPlugin {
            preset_cache: PresetCache::Directory(dir.join("preset-cache")),
            ..default()
        },
    )
}

/// [`app`] with this plugin.
fn app_with(dir: &std::path::Path, plugin: ConiferLodPlugin) -> App {
    let mut app = App::new();
    app.add_plugins((
        MinimalPlugins,
        AssetPlugin {
            file_path: dir.to_string_lossy().into_owned(),
            ..default()
        },
        TransformPlugin,
    ))
    .init_asset::<Mesh>()
    .insert_resource(ConiferLodDebug {
        always_collect_stats: true,
        ..default()
    })
    .add_plugins(plugin);
    app
}

/// Updates `app` until `handle` has loaded or failed (`Err` with Bevy's
/// message), for up to two minutes: bakes run on a nice-19 thread, which a
/// loaded machine can starve for many seconds.
fn wait_for(app: &mut App, handle: &Handle<ConiferSpecies>) -> Result<(), String> {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while std::time::Instant::now() < deadline {
        app.update();
        match app.world().resource::<AssetServer>().load_state(handle) {
            LoadState::Loaded => return Ok(()),
            LoadState::Failed(error) => return Err(error.to_string()),
            _ => std::thread::sleep(std::time::Duration::from_millis(5)),
        }
    }
    panic!("{handle:?} neither loaded nor failed");
}

/// The loaded species of `handle`.
fn loaded_species(app: &App, handle: &Handle<ConiferSpecies>) -> ConiferSpecies {
    app.world()
        .resource::<Assets<ConiferSpecies>>()
        .get(handle)
        .expect("the species has loaded")
        .clone()
}

/// Loads `preset` through [`ConiferPresets`] in `app`.
fn load_preset(app: &mut App, preset: &str) -> Handle<ConiferSpecies> {
    let preset = preset.to_owned();
    app.world_mut()
        .run_system_once(move |mut presets: ConiferPresets| presets.load_named(&preset))
        .unwrap()
}

fn write_tree(dir: &std::path::Path, name: &str) -> Vec3 {
    let tree = generate(
        Species::NorwaySpruce,
        &GenerateOptions {
            seed: 1,
            target_needles: Some(4000),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    );
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    write_record(&record, &dir.join(name)).unwrap();
    record.crown_center()
}

fn camera(distance: f32) -> impl Bundle {
    (
        Camera3d::default(),
        Camera {
            viewport: Some(Viewport {
                physical_size: UVec2::new(HEIGHT_PX * 4 / 3, HEIGHT_PX),
                ..default()
            }),
            ..default()
        },
        Projection::Perspective(PerspectiveProjection {
            fov: FOV_DEG.to_radians(),
            ..default()
        }),
        Transform::from_xyz(0.0, 0.0, distance),
    )
}

/// Loads `name` and spawns one tree with its crown centre at the origin (so
/// the camera distance is exact).
fn spawn_tree(app: &mut App, name: &str, crown: Vec3) -> (Entity, Handle<ConiferSpecies>) {
    let handle: Handle<ConiferSpecies> = app.world().resource::<AssetServer>().load(name.to_string());
    wait_for(app, &handle).unwrap();
    let tree = app
        .world_mut()
        .spawn((ConiferFoliage(handle.clone()), Transform::from_translation(-crown)))
        .id();
    app.update();
    (tree, handle)
}

fn state(app: &App, tree: Entity) -> ConiferLodState {
    *app.world().get::<ConiferLodState>(tree).unwrap()
}

fn paper_error(distance: f32, pixel_error: f32) -> f32 {
    ViewParams {
        vertical_fov: FOV_DEG.to_radians(),
        viewport_height_px: HEIGHT_PX as f32,
        pixel_error: PixelError(pixel_error),
    }
    .spatial_error(distance)
}

#[test]
fn error_matches_the_formula_and_representation_follows_distance() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    let cam = app.world_mut().spawn(camera(5.0)).id();
    let (tree, handle) = spawn_tree(&mut app, "spruce.conifer", crown);

    let species = loaded_species(&app, &handle);
    assert!(
        app.world().get::<Children>(tree).is_none(),
        "nothing is spawned for a tree"
    );
    assert!(
        species.max_wood_error > species.max_line_error,
        "the trunk is thicker than a needle"
    );

    let mut saw = (false, false, false);
    for distance in [0.5f32, 0.9, 1.0, 1.1, 2.0, 5.0, 20.0, 80.0, 300.0] {
        app.world_mut().get_mut::<Transform>(cam).unwrap().translation.z = distance;
        app.update();
        let s = state(&app, tree);
        let expected = paper_error(distance, 1.0);
        assert!(
            (s.min_spatial_error - expected).abs() <= expected * 1e-4,
            "{distance} m: {} vs {expected}",
            s.min_spatial_error
        );
        assert_eq!(s.views, 1);
        assert_eq!(s.prisms_visible, expected < species.max_line_error, "{distance} m");
        assert_eq!(s.lines_visible, expected >= species.min_line_error, "{distance} m");
        saw.0 |= s.prisms_visible && !s.lines_visible;
        saw.1 |= s.prisms_visible && s.lines_visible;
        saw.2 |= !s.prisms_visible && s.lines_visible;
        // Trunk and branches: prisms while the thickest segment is above the error.
        assert_eq!(s.wood_prisms_visible, expected < species.max_wood_error, "{distance} m");
    }
    assert_eq!(
        saw,
        (true, true, true),
        "prisms only, both, then lines only as the camera backs off"
    );
}

#[test]
fn settings_and_overrides_take_effect_next_frame() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    app.world_mut().spawn(camera(30.0));
    let (tree, _) = spawn_tree(&mut app, "spruce.conifer", crown);
    let before = state(&app, tree).min_spatial_error;
    app.world_mut().resource_mut::<ConiferLodSettings>().pixel_error = 2.0;
    app.update();
    let after = state(&app, tree).min_spatial_error;
    assert!((after / before - 2.0).abs() < 1e-5, "{before} → {after}");
    app.world_mut().entity_mut(tree).insert(ConiferLodOverride {
        pixel_error: Some(0.5),
        ..default()
    });
    app.update();
    assert!((state(&app, tree).min_spatial_error / before - 0.5).abs() < 1e-5);
    app.world_mut().resource_mut::<ConiferLodSettings>().enabled = false;
    app.update();
    let s = state(&app, tree);
    assert_eq!(s.min_spatial_error, 0.0);
    assert!(
        s.prisms_visible && !s.lines_visible,
        "LOD off draws every needle as a prism"
    );
}

#[test]
fn overrides_visibility_and_render_layers_reach_the_gpu_instance() {
    use bevy::camera::visibility::RenderLayers;
    use bevy_conifer_lod::plugin::{
        FLAG_PIXEL_ERROR_OVERRIDE, FLAG_TRANSITION_OVERRIDE, FLAG_VISIBLE, OPACITY_OVERRIDE_SHIFT,
    };
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    app.world_mut().spawn(camera(30.0));
    let (ours, handle) = spawn_tree(&mut app, "spruce.conifer", crown);
    let paper = app
        .world_mut()
        .spawn((
            ConiferFoliage(handle),
            ConiferLodOverride {
                line_opacity: Some(LineOpacity::Paper),
                pixel_error: Some(0.5),
                // A NaN override is ignored: the tree takes the global δ.
                transition: Some(f32::NAN),
                far_impostor: None,
            },
            RenderLayers::from_layers(&[0, 3]),
        ))
        .id();
    // No renderer here: what Bevy's visibility propagation would set.
    for tree in [ours, paper] {
        app.world_mut().entity_mut(tree).insert(InheritedVisibility::VISIBLE);
    }
    app.update();
    let instance = |app: &App, tree: Entity| *app.world().resource::<CompactInstances>().get(tree).unwrap().1;
    let (a, b) = (instance(&app, ours), instance(&app, paper));
    assert_eq!(a.flags, FLAG_VISIBLE, "no override");
    assert_eq!(a.layers, 1, "the default layer");
    assert_eq!(
        b.flags,
        FLAG_VISIBLE | FLAG_PIXEL_ERROR_OVERRIDE | (1 << OPACITY_OVERRIDE_SHIFT)
    );
    assert_eq!(b.flags & FLAG_TRANSITION_OVERRIDE, 0);
    assert_eq!((b.pixel_error, b.layers), (0.5, 0b1001));
    // Removing the override and the layers, and hiding the tree, reach it
    // next frame.
    app.world_mut()
        .entity_mut(paper)
        .remove::<(ConiferLodOverride, RenderLayers)>()
        .insert(InheritedVisibility::HIDDEN);
    app.update();
    let b = instance(&app, paper);
    assert_eq!((b.flags, b.layers), (0, 1));
}

#[test]
fn each_camera_counts_and_bad_cameras_are_quiet() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    let (tree, _) = spawn_tree(&mut app, "spruce.conifer", crown);
    // No camera: a defined state, nothing drawn.
    let s = state(&app, tree);
    assert_eq!((s.views, s.prisms_visible, s.lines_visible), (0, false, false));
    assert!(s.min_spatial_error.is_infinite());
    // A camera with a zero-size viewport and one without a target are skipped.
    app.world_mut().spawn((
        Camera3d::default(),
        Camera {
            viewport: Some(Viewport {
                physical_size: UVec2::ZERO,
                ..default()
            }),
            ..default()
        },
        Transform::from_xyz(0.0, 0.0, 3.0),
    ));
    app.world_mut()
        .spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 3.0)));
    app.update();
    assert_eq!(state(&app, tree).views, 0);
    // Two real cameras: the nearest sets the smallest error, the farthest the largest.
    app.world_mut().spawn(camera(0.5));
    app.world_mut().spawn(camera(400.0));
    app.update();
    let s = state(&app, tree);
    assert_eq!(s.views, 2);
    assert!((s.min_spatial_error - paper_error(0.5, 1.0)).abs() < 1e-6);
    assert!((s.max_spatial_error - paper_error(400.0, 1.0)).abs() < 1e-4);
    assert!(s.prisms_visible && s.lines_visible);
    // A camera inside the tree: error 0, finest detail, no panic.
    app.world_mut().spawn(camera(0.0));
    app.update();
    assert_eq!(state(&app, tree).min_spatial_error, 0.0);
}

#[test]
fn orthographic_error_does_not_depend_on_distance() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    let mut ortho = OrthographicProjection::default_3d();
    ortho.scaling_mode = bevy::camera::ScalingMode::Fixed {
        width: 8.0,
        height: 6.0,
    };
    ortho.update(960.0, HEIGHT_PX as f32);
    let cam = app
        .world_mut()
        .spawn((
            Camera3d::default(),
            Camera {
                viewport: Some(Viewport {
                    physical_size: UVec2::new(960, HEIGHT_PX),
                    ..default()
                }),
                ..default()
            },
            Projection::Orthographic(ortho),
            Transform::from_xyz(0.0, 0.0, 10.0),
        ))
        .id();
    let (tree, _) = spawn_tree(&mut app, "spruce.conifer", crown);
    let near = state(&app, tree).min_spatial_error;
    // One pixel of a 6 m tall view over 720 pixels.
    assert!((near - 6.0 / HEIGHT_PX as f32).abs() < 1e-6, "{near}");
    app.world_mut().get_mut::<Transform>(cam).unwrap().translation.z = 100.0;
    app.update();
    assert_eq!(state(&app, tree).min_spatial_error, near);
}

#[derive(Resource, Default)]
struct MeshEvents(usize);

fn count_mesh_events(mut events: MessageReader<AssetEvent<Mesh>>, mut count: ResMut<MeshEvents>) {
    count.0 += events.read().count();
}

#[test]
fn no_asset_churn_and_nothing_left_behind() {
    // 1,000 trees of the six species, a camera flying through them.
    let dir = tempfile::tempdir().unwrap();
    let mut app = app(dir.path());
    app.init_resource::<MeshEvents>().add_systems(Last, count_mesh_events);
    let cam = app.world_mut().spawn(camera(3.0)).id();
    let mut handles = Vec::new();
    for species in Species::ALL {
        let tree = generate(
            species,
            &GenerateOptions {
                seed: 5,
                target_needles: Some(3000),
                age: bevy_conifer_lod::generate::Age::Young,
            },
        );
        let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
        let name = format!("{species}.conifer");
        write_record(&record, &dir.path().join(&name)).unwrap();
        handles.push(spawn_tree(&mut app, &name, Vec3::ZERO).1);
    }
    for i in 0..1000 - handles.len() {
        let (x, z) = ((i % 40) as f32 * 4.0, (i / 40) as f32 * -4.0);
        let foliage = ConiferFoliage(handles[i % handles.len()].clone());
        app.world_mut().spawn((foliage, Transform::from_xyz(x, 0.0, z)));
    }
    app.update();
    app.update();
    let warm = app.world().resource::<MeshEvents>().0;
    assert_eq!(warm, 0, "the plugin makes no mesh");
    assert_eq!(app.world().resource::<CompactInstances>().len(), 1000);
    assert_eq!(
        app.world_mut().query::<&Children>().iter(app.world()).count(),
        0,
        "nothing is spawned per tree"
    );
    // The camera flies through the stand for 120 frames, changing the
    // representation of most trees: no mesh is created or modified.
    let snapshot = |app: &mut App| -> Vec<(bool, bool)> {
        let mut states: Vec<(Entity, bool, bool)> = app
            .world_mut()
            .query::<(Entity, &ConiferLodState)>()
            .iter(app.world())
            .map(|(e, s)| (e, s.prisms_visible, s.lines_visible))
            .collect();
        states.sort_by_key(|s| s.0);
        states.into_iter().map(|(_, p, l)| (p, l)).collect()
    };
    let mut previous = snapshot(&mut app);
    let mut changes = 0;
    for frame in 0..120 {
        app.world_mut().get_mut::<Transform>(cam).unwrap().translation =
            Vec3::new(frame as f32 * 1.3, 1.5, 3.0 - frame as f32 * 0.9);
        app.update();
        let now = snapshot(&mut app);
        changes += now.iter().zip(&previous).filter(|(a, b)| a != b).count();
        previous = now;
    }
    assert_eq!(
        app.world().resource::<MeshEvents>().0,
        warm,
        "mesh asset events after warm-up"
    );
    println!("{changes} representation changes along the flight");
    let cpu = app
        .world()
        .resource::<bevy_conifer_lod::plugin::ConiferLodCpuTime>()
        .last_frame;
    assert!(cpu > std::time::Duration::ZERO, "the plugin times its systems");
    println!("plugin systems, last frame: {cpu:?} for 1,000 trees");
    assert!(changes > 0, "the flight must change some tree's representation");

    // Churn: despawn everything, respawn, despawn again, drop the handles.
    let all: Vec<Entity> = app
        .world_mut()
        .query_filtered::<Entity, With<ConiferFoliage>>()
        .iter(app.world())
        .collect();
    for tree in all {
        app.world_mut().despawn(tree);
    }
    app.update();
    for i in 0..50 {
        app.world_mut().spawn((
            ConiferFoliage(handles[i % handles.len()].clone()),
            Transform::from_xyz(i as f32, 0.0, 0.0),
        ));
    }
    app.update();
    let all: Vec<Entity> = app
        .world_mut()
        .query_filtered::<Entity, With<ConiferFoliage>>()
        .iter(app.world())
        .collect();
    for tree in all {
        app.world_mut().despawn(tree);
    }
    drop(handles);
    for _ in 0..3 {
        app.update();
    }
    assert!(
        app.world().resource::<CompactInstances>().is_empty(),
        "no instance left"
    );
    assert_eq!(
        app.world().resource::<Assets<ConiferSpecies>>().len(),
        0,
        "species unloaded"
    );
    assert_eq!(app.world().resource::<Assets<Mesh>>().len(), 0);
}

#[test]
fn a_corrupted_record_fails_to_load_with_its_reason() {
    let dir = tempfile::tempdir().unwrap();
    write_tree(dir.path(), "spruce.conifer");
    let mut bytes = std::fs::read(dir.path().join("spruce.conifer")).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x40;
    std::fs::write(dir.path().join("broken.conifer"), &bytes).unwrap();
    let mut app = app(dir.path());
    let handle: Handle<ConiferSpecies> = app.world().resource::<AssetServer>().load("broken.conifer");
    let failure = wait_for(&mut app, &handle).expect_err("load fails");
    assert!(failure.contains("checksum"), "{failure}");
}

#[test]
fn debug_overlay_switches_colours_and_counts_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    app.add_plugins(ConiferLodDebugPlugin::default());
    // The cut's counts (the far tree would be its impostor).
    app.world_mut().resource_mut::<ConiferLodSettings>().far_impostor = false;
    app.world_mut().spawn(camera(6.0));
    let (tree, handle) = spawn_tree(&mut app, "spruce.conifer", crown);
    // A second tree far behind: two instances, two different cuts.
    let far = app
        .world_mut()
        .spawn((
            ConiferFoliage(handle.clone()),
            Transform::from_translation(-crown - Vec3::Z * 80.0),
        ))
        .id();
    app.update();
    assert!(!app.world().resource::<ConiferLodSettings>().debug_colors);
    app.world_mut().resource_mut::<ConiferLodDebug>().enabled = true;
    // No renderer here: what Bevy's visibility propagation would set.
    for entity in [tree, far] {
        app.world_mut().entity_mut(entity).insert(InheritedVisibility::VISIBLE);
    }
    app.update();
    assert!(
        app.world().resource::<ConiferLodSettings>().debug_colors,
        "overlay turns debug colours on"
    );
    let stats = *app.world().resource::<ConiferLodStats>();
    let species = loaded_species(&app, &handle);
    let mut expected = (0, 0, 0, 0);
    for entity in [tree, far] {
        let cut = species.record().cut(state(&app, entity).min_spatial_error);
        let s = species.record().cut_stats(&cut);
        expected.0 += s.prisms;
        expected.1 += s.triangles;
        expected.2 += s.lines_original;
        expected.3 += s.lines_merged;
    }
    assert_eq!((stats.instances, stats.visible_instances), (2, 2));
    assert_eq!(
        (stats.prisms, stats.triangles, stats.lines_original, stats.lines_merged),
        expected
    );
    assert_eq!(stats.lines, expected.2 + expected.3);
    assert_eq!(stats.pixel_error, 1.0);
    app.world_mut().resource_mut::<ConiferLodDebug>().enabled = false;
    app.update();
    assert!(!app.world().resource::<ConiferLodSettings>().debug_colors);
}

#[test]
fn scattered_forest_spawns_one_tree_per_placement() {
    use bevy_conifer_lod::plugin::placement_transform;
    use bevy_conifer_lod::scatter::Scatter;
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    let (_, handle) = spawn_tree(&mut app, "spruce.conifer", crown);
    let placements = Scatter::new(Vec2::ZERO, Vec2::splat(60.0), 5.0)
        .height(|p: Vec2| 0.1 * p.x)
        .scale_range(0.8, 1.2)
        .species_weights(&[1.0, 1.0])
        .seed(4)
        .place();
    // Species 1 has no handle: those placements are skipped.
    let spawned = app
        .world_mut()
        .run_system_once(move |mut commands: Commands| {
            spawn_forest(&mut commands, &placements, std::slice::from_ref(&handle))
        })
        .unwrap();
    app.update();
    let placements = Scatter::new(Vec2::ZERO, Vec2::splat(60.0), 5.0)
        .height(|p: Vec2| 0.1 * p.x)
        .scale_range(0.8, 1.2)
        .species_weights(&[1.0, 1.0])
        .seed(4)
        .place();
    let kept: Vec<_> = placements.iter().filter(|p| p.species == 0).collect();
    assert_eq!(spawned.len(), kept.len());
    assert!(!kept.is_empty() && kept.len() < placements.len());
    for (entity, placement) in spawned.iter().zip(kept) {
        let transform = *app.world().get::<Transform>(*entity).unwrap();
        assert_eq!(transform, placement_transform(placement));
        let tracked = app.world().resource::<CompactInstances>().get(*entity);
        assert!(tracked.is_some(), "drawn by the GPU instances");
    }
}

#[test]
fn lod_keys_change_the_settings_and_the_overlay() {
    let dir = tempfile::tempdir().unwrap();
    let mut app = app(dir.path());
    app.add_plugins(ConiferLodDebugPlugin::default())
        .init_resource::<ButtonInput<KeyCode>>()
        .add_systems(Update, conifer_lod_keys);
    let press = |app: &mut App, key: KeyCode| {
        let mut input = app.world_mut().resource_mut::<ButtonInput<KeyCode>>();
        input.press(key);
        app.update();
        let mut input = app.world_mut().resource_mut::<ButtonInput<KeyCode>>();
        input.release(key);
        input.clear();
    };
    press(&mut app, KeyCode::BracketRight);
    assert_eq!(app.world().resource::<ConiferLodSettings>().pixel_error, 1.25);
    press(&mut app, KeyCode::BracketLeft);
    press(&mut app, KeyCode::BracketLeft);
    assert!((app.world().resource::<ConiferLodSettings>().pixel_error - 0.8).abs() < 1e-6);
    press(&mut app, KeyCode::Comma);
    assert!((app.world().resource::<ConiferLodSettings>().transition - 0.9).abs() < 1e-6);
    press(&mut app, KeyCode::KeyL);
    assert!(!app.world().resource::<ConiferLodSettings>().enabled);
    // P cycles the opacity rules: ours (area), coverage, the paper's.
    press(&mut app, KeyCode::KeyP);
    assert_eq!(
        app.world().resource::<ConiferLodSettings>().line_opacity,
        LineOpacity::Coverage
    );
    press(&mut app, KeyCode::KeyP);
    assert_eq!(
        app.world().resource::<ConiferLodSettings>().line_opacity,
        LineOpacity::Paper
    );
    // The wind: a light breeze (1) to start, 1.5, then calm and no lower.
    press(&mut app, KeyCode::Equal);
    assert_eq!(app.world().resource::<ConiferWind>().strength, 1.5);
    for _ in 0..4 {
        press(&mut app, KeyCode::Minus);
    }
    assert_eq!(app.world().resource::<ConiferWind>().strength, 0.0);
    press(&mut app, KeyCode::F3);
    assert!(app.world().resource::<ConiferLodDebug>().enabled);
    app.update();
    assert!(app.world().resource::<ConiferLodSettings>().debug_colors);
}

/// A spruce seen by one camera 300 m away, and its state then (the files
/// live as long as the returned directory).
fn tree_seen_from_300_m() -> (tempfile::TempDir, App, Entity, ConiferLodState) {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    app.world_mut().spawn(camera(300.0));
    let (tree, _) = spawn_tree(&mut app, "spruce.conifer", crown);
    app.update();
    let far = state(&app, tree);
    (dir, app, tree, far)
}

#[test]
fn shadow_cascades_reach_the_lod_state() {
    use bevy::light::cascade::{Cascade, Cascades};
    let (_dir, mut app, tree, far) = tree_seen_from_300_m();
    assert!(
        !far.prisms_visible && !far.wood_prisms_visible,
        "the camera alone sees no prism at 300 m"
    );
    // A directional light whose one cascade covers the tree with 1 mm texels.
    let clip_from_world = Mat4::orthographic_rh(-5.0, 5.0, -5.0, 5.0, -50.0, 50.0);
    let cascade = Cascade {
        world_from_cascade: Mat4::IDENTITY,
        clip_from_cascade: clip_from_world,
        clip_from_world,
        texel_size: 0.001,
    };
    let mut cascades = Cascades::default();
    cascades.cascades.insert(Entity::PLACEHOLDER, vec![cascade]);
    let light = app
        .world_mut()
        .spawn((
            DirectionalLight {
                shadow_maps_enabled: true,
                ..default()
            },
            cascades,
        ))
        .id();
    app.update();
    let lit = state(&app, tree);
    assert!(lit.wood_prisms_visible, "the trunk casts its shadow as prisms");
    assert_eq!(
        lit.min_spatial_error, far.min_spatial_error,
        "the camera's error is unchanged"
    );
    // Without shadow maps the light changes nothing.
    app.world_mut()
        .get_mut::<DirectionalLight>(light)
        .unwrap()
        .shadow_maps_enabled = false;
    app.update();
    assert_eq!(state(&app, tree), far);
}

#[test]
fn the_shadow_error_scale_coarsens_the_shadow_views_only() {
    use bevy::light::cascade::{Cascade, Cascades};
    let (_dir, mut app, tree, far) = tree_seen_from_300_m();
    let handle = app.world().get::<ConiferFoliage>(tree).unwrap().0.clone();
    let wood_error = loaded_species(&app, &handle).max_wood_error;
    assert!(wood_error > 0.0 && !far.wood_prisms_visible);
    // One cascade over the tree whose texel is half the error below which
    // the trunk is drawn as prisms: a scale under 2 keeps the prisms in
    // the shadow, one over 2 casts the trunk as lines.
    let clip_from_world = Mat4::orthographic_rh(-5.0, 5.0, -5.0, 5.0, -50.0, 50.0);
    let cascade = Cascade {
        world_from_cascade: Mat4::IDENTITY,
        clip_from_cascade: clip_from_world,
        clip_from_world,
        texel_size: wood_error / 2.0,
    };
    let mut cascades = Cascades::default();
    cascades.cascades.insert(Entity::PLACEHOLDER, vec![cascade]);
    app.world_mut().spawn((
        DirectionalLight {
            shadow_maps_enabled: true,
            ..default()
        },
        cascades,
    ));
    // Below 1, NaN and infinity are taken as 1.
    for (scale, prisms) in [
        (1.0, true),
        (1.5, true),
        (1.9, true),
        (2.1, false),
        (2.5, false),
        (0.25, true),
        (f32::NAN, true),
        (f32::INFINITY, true),
    ] {
        app.world_mut().resource_mut::<ConiferLodSettings>().shadow_error_scale = scale;
        app.update();
        let lit = state(&app, tree);
        assert_eq!(
            lit.wood_prisms_visible, prisms,
            "shadow error scale {scale}: the trunk's shadow as prisms"
        );
        assert_eq!(
            lit.min_spatial_error, far.min_spatial_error,
            "shadow error scale {scale}: the camera's error is unchanged"
        );
    }
}

#[test]
fn point_and_spot_light_shadows_reach_the_lod_state() {
    let (_dir, mut app, tree, far) = tree_seen_from_300_m();
    assert!(!far.prisms_visible, "the camera alone sees no prism at 300 m");

    // A lamp 3 m from the crown: its cube faces (1,024 texels over 90°)
    // have 6 mm texels there, so the tree's shadow needs wood prisms the
    // far camera does not.
    let lamp = app
        .world_mut()
        .spawn((
            PointLight {
                shadow_maps_enabled: true,
                range: 20.0,
                ..default()
            },
            Transform::from_xyz(3.0, 0.0, 0.0),
        ))
        .id();
    app.update();
    let lit = state(&app, tree);
    assert!(lit.wood_prisms_visible, "the trunk casts the lamp's shadow as prisms");
    assert_eq!(
        lit.min_spatial_error, far.min_spatial_error,
        "the camera's error is unchanged"
    );

    // Out of the lamp's range, or with its shadows off, the lamp changes nothing.
    app.world_mut().get_mut::<Transform>(lamp).unwrap().translation = Vec3::new(100.0, 0.0, 0.0);
    app.update();
    assert_eq!(state(&app, tree), far, "a lamp out of range");
    app.world_mut().get_mut::<Transform>(lamp).unwrap().translation = Vec3::new(3.0, 0.0, 0.0);
    app.world_mut().get_mut::<PointLight>(lamp).unwrap().shadow_maps_enabled = false;
    app.update();
    assert_eq!(state(&app, tree), far, "a lamp without shadows");

    // A spot light does the same.
    app.world_mut().spawn((
        SpotLight {
            shadow_maps_enabled: true,
            range: 20.0,
            ..default()
        },
        Transform::from_xyz(0.0, 3.0, 0.0).looking_at(Vec3::ZERO, Vec3::X),
    ));
    app.update();
    let spot = state(&app, tree);
    assert!(
        spot.wood_prisms_visible,
        "the spot light's shadow needs the trunk's prisms"
    );
}

/// The instance tracking under churn: 100,000 trees of two
/// species spawned, moved, re-targeted and mostly despawned; every tree's
/// GPU instance follows its transform and species, nothing is left of
/// despawned trees, and no mesh asset is made or touched after warm-up.
#[test]
fn instances_follow_100k_trees_in_churn() {
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    std::fs::copy(dir.path().join("spruce.conifer"), dir.path().join("spruce2.conifer")).unwrap();
    let mut app = app(dir.path());
    app.world_mut().spawn(camera(5.0));
    let (first, a) = spawn_tree(&mut app, "spruce.conifer", crown);
    let (second, b) = spawn_tree(&mut app, "spruce2.conifer", crown);
    for tree in [first, second] {
        app.world_mut().despawn(tree);
    }
    let n = 100_000usize;
    let trees: Vec<Entity> = (0..n)
        .map(|i| {
            let handle = if i % 3 == 0 { b.clone() } else { a.clone() };
            let position = Vec3::new((i % 400) as f32 * 5.0, 0.0, (i / 400) as f32 * 5.0);
            app.world_mut()
                .spawn((ConiferFoliage(handle), Transform::from_translation(position)))
                .id()
        })
        .collect();
    app.update();
    let mesh_events = |app: &mut App| {
        let mut reader = app
            .world_mut()
            .resource_mut::<Messages<AssetEvent<Mesh>>>()
            .get_cursor();
        let messages = app.world().resource::<Messages<AssetEvent<Mesh>>>();
        reader.read(messages).count()
    };
    let _ = mesh_events(&mut app);
    let check = |app: &App, alive: &[Entity]| {
        let tracked = app.world().resource::<CompactInstances>();
        assert_eq!(tracked.len(), alive.len());
        assert_eq!(tracked.species_len(a.id()) + tracked.species_len(b.id()), alive.len());
        for &tree in alive {
            let (species, instance) = tracked.get(tree).expect("tracked");
            let foliage = app.world().get::<ConiferFoliage>(tree).unwrap();
            assert_eq!(species, foliage.0.id());
            let t = app.world().get::<GlobalTransform>(tree).unwrap().translation();
            assert_eq!(
                [instance.rows[0][3], instance.rows[1][3], instance.rows[2][3]],
                t.to_array()
            );
        }
    };
    check(&app, &trees);
    assert_eq!(
        app.world().resource::<CompactInstances>().species_len(b.id()),
        n.div_ceil(3)
    );
    // Move a thousand, re-target five hundred.
    for (k, &tree) in trees.iter().enumerate().step_by(97) {
        app.world_mut().get_mut::<Transform>(tree).unwrap().translation.y = 1.0 + k as f32;
    }
    for &tree in trees.iter().skip(1).step_by(199) {
        app.world_mut().get_mut::<ConiferFoliage>(tree).unwrap().0 = b.clone();
    }
    app.update();
    check(&app, &trees);
    // Despawn 60 %: swap-removals keep every other tree's slot right.
    let gone: Vec<Entity> = trees
        .iter()
        .copied()
        .enumerate()
        .filter(|(k, _)| k % 5 < 3)
        .map(|(_, e)| e)
        .collect();
    let alive: Vec<Entity> = trees
        .iter()
        .copied()
        .enumerate()
        .filter(|(k, _)| k % 5 >= 3)
        .map(|(_, e)| e)
        .collect();
    for tree in gone {
        app.world_mut().despawn(tree);
    }
    app.update();
    check(&app, &alive);
    // Nothing per tree: no mesh asset made or changed while trees moved,
    // changed and went.
    for _ in 0..3 {
        app.update();
    }
    assert_eq!(mesh_events(&mut app), 0);
}

/// Inspectors (bevy-inspector-egui) and Bevy's remote protocol work through
/// reflection: the settings resource is read and written through the type
/// registry, a tree's override is inserted and its LOD state read the same
/// way, and the change takes effect like any other.
#[test]
fn settings_overrides_and_state_are_reflected() {
    use bevy::ecs::reflect::{AppTypeRegistry, ReflectComponent, ReflectResource};
    use bevy::reflect::{PartialReflect, ReflectMut, ReflectRef};
    let dir = tempfile::tempdir().unwrap();
    let crown = write_tree(dir.path(), "spruce.conifer");
    let mut app = app(dir.path());
    app.add_plugins(ConiferLodDebugPlugin::default());
    app.world_mut().spawn(camera(30.0));
    let (tree, _) = spawn_tree(&mut app, "spruce.conifer", crown);
    let before = state(&app, tree).min_spatial_error;
    let registry = app.world().resource::<AppTypeRegistry>().clone();
    let registry = registry.read();
    use std::any::TypeId;
    for (name, id) in [
        ("ConiferLodSettings", TypeId::of::<ConiferLodSettings>()),
        ("ConiferLodDebug", TypeId::of::<ConiferLodDebug>()),
        ("ConiferLodStats", TypeId::of::<ConiferLodStats>()),
        (
            "ConiferLodCpuTime",
            TypeId::of::<bevy_conifer_lod::plugin::ConiferLodCpuTime>(),
        ),
        ("ConiferFoliage", TypeId::of::<ConiferFoliage>()),
        ("ConiferLodOverride", TypeId::of::<ConiferLodOverride>()),
        ("ConiferLodState", TypeId::of::<ConiferLodState>()),
    ] {
        assert!(
            registry.get_type_data::<ReflectComponent>(id).is_some(),
            "{name} is registered"
        );
    }
    // Write ε through the resource's reflection (a resource is the
    // component of its own entity).
    let id = std::any::TypeId::of::<ConiferLodSettings>();
    assert!(registry.get_type_data::<ReflectResource>(id).is_some());
    let settings = registry
        .get_type_data::<ReflectComponent>(id)
        .expect("ConiferLodSettings reflects as its entity's component");
    let component = app.world().component_id::<ConiferLodSettings>().unwrap();
    let holder = app.world().resource_entities().get(component).unwrap();
    {
        let mut entity = app.world_mut().entity_mut(holder);
        let mut reflected = settings.reflect_mut(&mut entity).unwrap();
        let ReflectMut::Struct(fields) = reflected.reflect_mut() else {
            panic!("a struct");
        };
        fields.field_mut("pixel_error").unwrap().apply(&2.0f32);
    }
    assert_eq!(app.world().resource::<ConiferLodSettings>().pixel_error, 2.0);
    app.update();
    let after = state(&app, tree).min_spatial_error;
    assert!((after / before - 2.0).abs() < 1e-5, "{before} → {after}");
    // Insert an override through the component's reflection.
    let overrides = registry
        .get_type_data::<ReflectComponent>(std::any::TypeId::of::<ConiferLodOverride>())
        .expect("ConiferLodOverride reflects as a component");
    let value = ConiferLodOverride {
        pixel_error: Some(0.5),
        ..default()
    };
    overrides.insert(
        &mut app.world_mut().entity_mut(tree),
        value.as_partial_reflect(),
        &registry,
    );
    app.update();
    assert_eq!(app.world().get::<ConiferLodOverride>(tree), Some(&value));
    // Read the state through reflection.
    let states = registry
        .get_type_data::<ReflectComponent>(std::any::TypeId::of::<ConiferLodState>())
        .expect("ConiferLodState reflects as a component");
    let entity = app.world().entity(tree);
    let reflected = states.reflect(entity).unwrap();
    let ReflectRef::Struct(fields) = reflected.reflect_ref() else {
        panic!("a struct");
    };
    let error = fields
        .field("min_spatial_error")
        .unwrap()
        .try_downcast_ref::<f32>()
        .copied();
    assert!((error.unwrap() / before - 0.5).abs() < 1e-5, "{error:?}");
}

#[test]
fn presets_load_without_files_and_come_back_from_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let preset: Preset = "scots-pine?seed=4&needles=3000".parse().unwrap();
    let cached = dir
        .path()
        .join("preset-cache")
        .join(bevy_conifer_lod::plugin::cache_file_name(&preset));

    // First start: baked in the background, drawn, written to the cache.
    let mut run = app(dir.path());
    let handle = load_preset(&mut run, "scots-pine?seed=4&needles=3000");
    assert_eq!(
        load_preset(&mut run, "scots-pine?needles=3000&seed=4"),
        handle,
        "one handle per preset"
    );
    wait_for(&mut run, &handle).unwrap();
    let baked = preset.bake().unwrap().flatten().unwrap();
    let species = loaded_species(&run, &handle);
    assert_eq!(species.record().needles, baked.needles, "the preset's own tree");
    let tree = run
        .world_mut()
        .spawn((ConiferFoliage(handle), Transform::default()))
        .id();
    run.world_mut().spawn(camera(30.0));
    run.update();
    assert!(state(&run, tree).lines_visible, "the tree is drawn");
    assert!(run.world().resource::<CompactInstances>().len() == 1);
    let on_disk = bevy_conifer_lod::model::read_prototype_record(&cached).unwrap();
    assert_eq!(
        on_disk.flatten().unwrap().needles,
        baked.needles,
        "the cache holds the bake"
    );

    // Next start reads the cache: a different record put there is what loads.
    let other = Preset::new(Species::NorwaySpruce).with_needles(1_500).bake().unwrap();
    bevy_conifer_lod::model::write_prototype_record(&other, &cached).unwrap();
    let mut run = app(dir.path());
    let handle = load_preset(&mut run, &preset.to_string());
    wait_for(&mut run, &handle).unwrap();
    let species = loaded_species(&run, &handle);
    assert_eq!(
        species.record().needles,
        other.flatten().unwrap().needles,
        "read from the cache"
    );

    // A cache file that no longer decodes is baked again and rewritten.
    std::fs::write(&cached, b"CONIFLOD truncated").unwrap();
    let mut run = app(dir.path());
    let handle = load_preset(&mut run, &preset.to_string());
    wait_for(&mut run, &handle).unwrap();
    let species = loaded_species(&run, &handle);
    assert_eq!(species.record().needles, baked.needles);
    let on_disk = bevy_conifer_lod::model::read_prototype_record(&cached).unwrap();
    assert_eq!(
        on_disk.flatten().unwrap().needles,
        baked.needles,
        "the cache is whole again"
    );

    // Without a cache nothing is written.
    let mut run = app_with(
        dir.path(),
        ConiferLodPlugin {
            preset_cache: PresetCache::Off,
            ..default()
        },
    );
    std::fs::remove_file(&cached).unwrap();
    let handle = load_preset(&mut run, &preset.to_string());
    wait_for(&mut run, &handle).unwrap();
    assert!(!cached.exists());
}

#[test]
fn bad_trees_fail_with_what_to_do_and_are_not_drawn() {
    let dir = tempfile::tempdir().unwrap();
    write_tree(dir.path(), "spruce.conifer");
    let mut future = std::fs::read(dir.path().join("spruce.conifer")).unwrap();
    let version = bevy_conifer_lod::model::file::FORMAT_VERSION + 1;
    future[8..12].copy_from_slice(&version.to_le_bytes());
    std::fs::write(dir.path().join("future.conifer"), &future).unwrap();
    let mut app = app(dir.path());
    app.world_mut().spawn(camera(30.0));

    let unknown = load_preset(&mut app, "norwy-spruce");
    let missing: Handle<ConiferSpecies> = app.world().resource::<AssetServer>().load("trees/missing.conifer");
    let newer: Handle<ConiferSpecies> = app.world().resource::<AssetServer>().load("future.conifer");
    let needles = load_preset(&mut app, "scots-pine?needles=0");
    let trees: Vec<Entity> = [&unknown, &missing, &newer, &needles]
        .into_iter()
        .map(|handle| {
            app.world_mut()
                .spawn((ConiferFoliage(handle.clone()), Transform::default()))
                .id()
        })
        .collect();

    let error = wait_for(&mut app, &unknown).unwrap_err();
    assert!(
        error.contains("norwy-spruce") && error.contains("norway-spruce") && error.contains("conifer bake"),
        "{error}"
    );
    let error = wait_for(&mut app, &missing).unwrap_err();
    assert!(error.contains("missing.conifer"), "{error}");
    let error = wait_for(&mut app, &newer).unwrap_err();
    assert!(
        error.contains("future.conifer") && error.contains("newer") && error.contains("update bevy_conifer_lod"),
        "{error}"
    );
    let error = wait_for(&mut app, &needles).unwrap_err();
    assert!(
        error.contains("scots-pine?needles=0") && error.contains("N > 0"),
        "{error}"
    );

    // The systems run on; no species arrives, so none of these trees has
    // anything to draw, and none is counted in a view.
    for _ in 0..3 {
        app.update();
    }
    let species = app.world().resource::<Assets<ConiferSpecies>>();
    assert!(
        [&unknown, &missing, &newer, &needles]
            .iter()
            .all(|h| !species.contains(*h))
    );
    for tree in trees {
        assert_eq!(state(&app, tree).views, 0);
    }
}
