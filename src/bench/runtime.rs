//! CPU cost of the plugin per frame, no rendering: `MinimalPlugins` plus the
//! plugin, trees of several species on a grid, a camera flying through.

use crate::model::LodRecord;
use crate::plugin::ConiferLodCpuTime;
use crate::prelude::*;
use bevy::asset::AssetPlugin;
use bevy::camera::Viewport;
use bevy::prelude::*;
use serde::Serialize;
use std::time::Instant;

/// The plugin's CPU cost at one instance count.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RuntimeFigures {
    /// Trees.
    pub instances: usize,
    /// Median frame time with the plugin's systems, ms.
    pub frame_ms_with_plugin: f64,
    /// Median frame time with the plugin's sets disabled (the trees and
    /// Bevy's own systems remain), ms.
    pub frame_ms_without_plugin: f64,
    /// The plugin's whole cost per frame: with − without, ms (at least 0).
    pub cpu_ms_per_frame: f64,
    /// `cpu_ms_per_frame` per instance, ns.
    pub ns_per_instance: f64,
    /// Median time inside the plugin's own systems (`ConiferLodCpuTime`), ms.
    pub systems_ms_per_frame: f64,
    /// `systems_ms_per_frame` per instance, ns.
    pub systems_ns_per_instance: f64,
}

fn species_assets(app: &mut App, records: &[LodRecord]) -> Vec<Handle<ConiferSpecies>> {
    records
        .iter()
        .map(|record| {
            let world = app.world_mut();
            let species = ConiferSpecies::from_record(record.clone());
            let species = species.expect("benchmark records fit the GPU layout");
            world.resource_mut::<Assets<ConiferSpecies>>().add(species)
        })
        .collect()
}

/// Median frame time and median plugin-systems time (ms) of `frames`
/// frames with `instances` trees of `records` (cycled) on a 6 m grid and a
/// 1920×1080 camera flying across it at 10 m per frame.
fn run(records: &[LodRecord], instances: usize, frames: usize, with_plugin_systems: bool) -> (f64, f64) {
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, AssetPlugin::default(), TransformPlugin))
        .add_plugins(ConiferLodPlugin::default());
    if !with_plugin_systems {
        app.configure_sets(
            PostUpdate,
            (ConiferLodSet::Select, ConiferLodSet::Instances).run_if(|| false),
        );
    }
    let handles = species_assets(&mut app, records);
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
    let frames = frames.max(1);
    let mut frame_ms = Vec::with_capacity(frames);
    let mut systems_ms = Vec::with_capacity(frames);
    for frame in 0..frames {
        let t = frame as f32 / frames as f32;
        if let Some(mut transform) = app.world_mut().get_mut::<Transform>(camera) {
            transform.translation = Vec3::new(t * side as f32 * 6.0, 2.0, t * 50.0);
        }
        let started = Instant::now();
        app.update();
        frame_ms.push(started.elapsed().as_secs_f64() * 1e3);
        let own = app
            .world()
            .get_resource::<ConiferLodCpuTime>()
            .map_or(0.0, |t| t.last_frame.as_secs_f64());
        systems_ms.push(own * 1e3);
    }
    (
        crate::eval::measure::median(&frame_ms),
        crate::eval::measure::median(&systems_ms),
    )
}

/// The plugin's CPU cost per frame at `instances` trees of `records`:
/// frames with and without its system sets, and its own systems' time.
pub fn runtime(records: &[LodRecord], instances: usize, frames: usize) -> RuntimeFigures {
    let (with, systems) = run(records, instances, frames, true);
    let (without, _) = run(records, instances, frames, false);
    let cpu = (with - without).max(0.0);
    let per = |ms: f64| ms * 1e6 / instances.max(1) as f64;
    RuntimeFigures {
        instances,
        frame_ms_with_plugin: with,
        frame_ms_without_plugin: without,
        cpu_ms_per_frame: cpu,
        ns_per_instance: per(cpu),
        systems_ms_per_frame: systems,
        systems_ns_per_instance: per(systems),
    }
}
