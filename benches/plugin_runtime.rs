//! CPU cost of the plugin per frame, no rendering: `MinimalPlugins` plus the
//! plugin, trees of 4 species scattered on a grid, a camera flying through.
//! Prints one JSON object per instance count: the plugin's whole cost per
//! frame (median frame time with and without the plugin's sets, so the
//! part entities' share of Bevy's transform and visibility work counts too)
//! and per instance, and the plugin's own systems' time
//! (`ConiferLodCpuTime`, median).
//!
//! ```text
//! cargo bench --features plugin --bench plugin_runtime [-- 100 1000 10000 100000]
//! ```

use bevy::asset::AssetPlugin;
use bevy::camera::Viewport;
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::model::{BakeOptions, bake};
use bevy_conifer_lod::plugin::ConiferLodCpuTime;
use bevy_conifer_lod::prelude::*;
use std::time::Instant;

const FRAMES: usize = 60;

fn species_assets(app: &mut App) -> Vec<Handle<ConiferSpecies>> {
    Species::ALL
        .into_iter()
        .map(|species| {
            let tree = generate(
                species,
                &GenerateOptions {
                    seed: 0,
                    target_needles: Some(5000),
                },
            );
            let record = bake(&tree, &BakeOptions::default(), &()).expect("bakes");
            let world = app.world_mut();
            let species = world.resource_scope(|world, mut meshes: Mut<Assets<Mesh>>| {
                let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
                ConiferSpecies::from_record(record, &mut meshes, &mut buffers).expect("fits the GPU layout")
            });
            world.resource_mut::<Assets<ConiferSpecies>>().add(species)
        })
        .collect()
}

/// Median frame time, and median of the plugin's own systems' time
/// ([`ConiferLodCpuTime`]), both in ms.
fn run(instances: usize, with_plugin_systems: bool) -> (f64, f64) {
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, AssetPlugin::default(), TransformPlugin))
        .init_asset::<Mesh>()
        .init_asset::<ShaderBuffer>()
        .add_plugins(ConiferLodPlugin);
    if !with_plugin_systems {
        app.configure_sets(
            PostUpdate,
            (ConiferLodSet::Prepare, ConiferLodSet::Select).run_if(|| false),
        );
    }
    let handles = species_assets(&mut app);
    let side = (instances as f32).sqrt().ceil() as usize;
    for i in 0..instances {
        let (x, z) = ((i % side) as f32 * 6.0, (i / side) as f32 * 6.0);
        app.world_mut().spawn((
            ConiferFoliage(handles[i % handles.len()].clone()),
            Transform::from_xyz(x, 0.0, z),
        ));
    }
    let camera = app
        .world_mut()
        .spawn((
            Camera3d::default(),
            Camera {
                viewport: Some(Viewport {
                    physical_size: UVec2::new(1920, 1080),
                    ..default()
                }),
                ..default()
            },
            Transform::from_xyz(0.0, 2.0, 0.0),
        ))
        .id();
    for _ in 0..3 {
        app.update();
    }
    let mut frame_ms = Vec::with_capacity(FRAMES);
    let mut systems_ms = Vec::with_capacity(FRAMES);
    for frame in 0..FRAMES {
        let t = frame as f32 / FRAMES as f32;
        app.world_mut().get_mut::<Transform>(camera).unwrap().translation =
            Vec3::new(t * side as f32 * 6.0, 2.0, t * 50.0);
        let started = Instant::now();
        app.update();
        frame_ms.push(started.elapsed().as_secs_f64() * 1e3);
        let own = app
            .world()
            .get_resource::<ConiferLodCpuTime>()
            .map_or(0.0, |t| t.last_frame.as_secs_f64());
        systems_ms.push(own * 1e3);
    }
    frame_ms.sort_by(f64::total_cmp);
    systems_ms.sort_by(f64::total_cmp);
    (frame_ms[FRAMES / 2], systems_ms[FRAMES / 2])
}

fn main() {
    let counts: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let counts = if counts.is_empty() {
        vec![100, 1_000, 10_000, 100_000]
    } else {
        counts
    };
    for instances in counts {
        let (with, systems) = run(instances, true);
        let (without, _) = run(instances, false);
        let plugin_ms = (with - without).max(0.0);
        println!(
            "{}",
            serde_json::json!({
                "instances": instances,
                "frame_ms_with_plugin": with,
                "frame_ms_without_plugin": without,
                "cpu_ms_per_frame": plugin_ms,
                "ns_per_instance": plugin_ms * 1e6 / instances as f64,
                "systems_ms_per_frame": systems,
                "systems_ns_per_instance": systems * 1e6 / instances as f64,
            })
        );
    }
}
