//! A rendered forest, headless: the plugin against the raw needle meshes and
//! against meshoptimizer LODs under Bevy's `VisibilityRange` (the `bevy-lod`
//! method of `conifer eval`), same trees, camera and picture.

use crate::eval::scene::{EvalError, RawTree, bevy_lod_chain, enter_distances, raw_materials, visibility_range};
use crate::model::{LodRecord, PixelError, ViewParams};
use crate::plugin::headless::HeadlessRenderer;
use crate::plugin::{ConiferFoliage, ConiferSpecies, triangle_mesh};
use bevy::prelude::*;
use std::time::Instant;

/// How the forest's trees are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum ForestMethod {
    /// The plugin (in calm: the headless renderer's).
    Ours,
    /// The plugin in a light breeze ([`crate::plugin::ConiferWind::default`]),
    /// its clock running with the frames.
    OursInWind,
    /// Every needle an `Lmax`-sided prism, no LOD.
    Raw,
    /// meshoptimizer LODs switched by `VisibilityRange` with crossfades.
    BevyLod,
}

/// Spacing of the forest's grid, metres.
pub const TREE_SPACING: f32 = 7.0;

/// Where tree `i` of a `side × side` grid stands (a deterministic jitter of
/// a third of the spacing), and its yaw.
fn place(i: usize, side: usize) -> Transform {
    let hash = |k: u64| {
        let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
        x ^= x >> 29;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 32;
        (x % 10_000) as f32 / 10_000.0
    };
    let (gx, gz) = ((i % side) as f32, (i / side) as f32);
    let jitter = TREE_SPACING / 3.0;
    Transform::from_xyz(
        gx * TREE_SPACING + (hash(2 * i as u64) - 0.5) * jitter,
        0.0,
        gz * TREE_SPACING + (hash(2 * i as u64 + 1) - 0.5) * jitter,
    )
    .with_rotation(Quat::from_rotation_y(hash(7 * i as u64 + 3) * std::f32::consts::TAU))
}

/// Median frame time (ms) of `frames` frames of a forest of `instances`
/// trees (the `records` cycled) drawn by `method`, `width × height`, seen
/// from above one corner of the grid, with Bevy's 4× MSAA or without; with
/// `picture`, a screenshot of it is saved there afterwards.
pub fn forest_frame_ms(
    records: &[LodRecord],
    method: ForestMethod,
    instances: usize,
    (width, height): (u32, u32),
    frames: usize,
    msaa: bool,
    picture: Option<&std::path::Path>,
) -> Result<f64, EvalError> {
    if width == 0 || height == 0 {
        return Err(EvalError::EmptyPicture(width, height));
    }
    if records.is_empty() || records.iter().any(|r| r.needle_count() == 0) {
        return Err(EvalError::NoNeedles);
    }
    let fov = 45f32.to_radians();
    let params = ViewParams {
        vertical_fov: fov,
        viewport_height_px: height as f32,
        pixel_error: PixelError(1.0),
    };
    let mut renderer = HeadlessRenderer::new(".");
    let target = renderer.render_target(width, height);
    let side = (instances as f32).sqrt().ceil().max(1.0) as usize;
    let extent = side as f32 * TREE_SPACING;
    let world = renderer.world_mut();
    HeadlessRenderer::spawn_lights(world);
    // Per species: what each tree spawns.
    type Parts = Vec<(
        Handle<Mesh>,
        Handle<StandardMaterial>,
        Option<bevy::camera::visibility::VisibilityRange>,
    )>;
    if method == ForestMethod::OursInWind {
        world.insert_resource(crate::plugin::ConiferWind::default());
    }
    let mut species_parts: Vec<Parts> = Vec::new();
    let mut species_handles: Vec<Handle<ConiferSpecies>> = Vec::new();
    for record in records {
        match method {
            ForestMethod::Ours | ForestMethod::OursInWind => {
                let species = ConiferSpecies::from_record(record.clone())?;
                species_handles.push(world.resource_mut::<Assets<ConiferSpecies>>().add(species));
            }
            ForestMethod::Raw | ForestMethod::BevyLod => {
                let raw = RawTree::new(record);
                let (needle_material, wood_material) = raw_materials(world, record);
                let mut parts: Parts = Vec::new();
                let mut add = |world: &mut World,
                               mesh: &crate::model::prism::TriangleMesh,
                               material: &Handle<StandardMaterial>,
                               range| {
                    let handle = world.resource_mut::<Assets<Mesh>>().add(triangle_mesh(mesh));
                    parts.push((handle, material.clone(), range));
                };
                if method == ForestMethod::Raw {
                    add(world, &raw.needles, &needle_material, None);
                    add(world, &raw.wood, &wood_material, None);
                } else {
                    let chain = bevy_lod_chain(&raw);
                    let enters = enter_distances(&chain, params.error_per_distance());
                    for (k, level) in chain.iter().enumerate() {
                        let range = visibility_range(&enters, k, |d| d);
                        add(world, &level.needles.mesh, &needle_material, Some(range.clone()));
                        add(world, &level.wood.mesh, &wood_material, Some(range));
                    }
                }
                species_parts.push(parts);
            }
        }
    }
    for i in 0..instances {
        let transform = place(i, side);
        match method {
            ForestMethod::Ours | ForestMethod::OursInWind => {
                world.spawn((
                    ConiferFoliage(species_handles[i % species_handles.len()].clone()),
                    transform,
                ));
            }
            ForestMethod::Raw | ForestMethod::BevyLod => {
                for (mesh, material, range) in &species_parts[i % species_parts.len()] {
                    let mut entity = world.spawn((Mesh3d(mesh.clone()), MeshMaterial3d(material.clone()), transform));
                    if let Some(range) = range {
                        entity.insert(range.clone());
                    }
                }
            }
        }
    }
    let eye = Vec3::new(-0.15 * extent, 0.3 * extent + 12.0, -0.15 * extent);
    let look = Vec3::new(0.5 * extent, 0.0, 0.5 * extent);
    renderer.world_mut().spawn((
        HeadlessRenderer::camera_bundle(&target, Transform::from_translation(eye).looking_at(look, Vec3::Y), fov),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::srgb(0.72, 0.8, 0.9)),
            ..default()
        },
        if msaa { Msaa::Sample4 } else { Msaa::Off },
    ));
    // Upload, specialize and settle.
    for _ in 0..HeadlessRenderer::SETTLE_FRAMES {
        renderer.update()?;
    }
    let mut times = Vec::new();
    for _ in 0..frames.max(1) {
        let started = Instant::now();
        renderer.update()?;
        times.push(started.elapsed().as_secs_f64() * 1e3);
    }
    if let Some(path) = picture {
        let image = renderer.capture(&target, 10)?;
        image
            .save(path)
            .map_err(|e| EvalError::Picture(path.display().to_string(), e.to_string()))?;
    }
    Ok(crate::eval::measure::median(&times))
}
