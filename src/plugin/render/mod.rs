//! The render path: one set of compact storage buffers per species, one instance buffer per
//! species, and per view a compute pass that culls every tree and writes
//! the indirect draws of the prefixes its cut needs. Nothing is spawned per
//! tree; the CPU only copies the instances that changed.
//!
//! * Main world: [`CompactInstances`] tracks every [`ConiferFoliage`] tree
//!   (transform, override, visibility, layers) per species, touching only
//!   trees that changed.
//! * Extract: instances of species whose trees changed, the species' compact
//!   arrays ([`CompactSpecies`], built when the record loaded) and settings.
//! * Prepare: the species' buffers (re-created only when the record
//!   changes), the instance buffer (grown by powers of two, else written in
//!   place), and per view the compute inputs and outputs.
//! * Queue: per view and species, one opaque item per opaque part and one
//!   transparent item per line part, each drawn by one multi-draw-indirect
//!   with one draw per tree.
//! * Render graph: the culling compute pass (`conifer_cull.wgsl`), before
//!   the cameras draw.
//!
//! * Shadows: every shadow view (directional cascades, point-light faces,
//!   spot lights) is culled like a camera, at its texel's error, and drawn
//!   depth-only; lines keep each fragment with their opacity (a hashed
//!   alpha test), so they cast the shadow of the coverage they draw; with
//!   `shadow_line_quads` they are quads of their bundle's width, each
//!   texel of the strip kept with the line's opacity.

pub mod gpu;
mod readback;

pub use readback::{CompactReadback, ViewReadback};

use self::gpu::{
    CullView, DRAW_ARGS_BYTES, FLAG_IMPOSTOR_ON, FLAG_IMPOSTOR_OVERRIDE, FLAG_PIXEL_ERROR_OVERRIDE,
    FLAG_TRANSITION_OVERRIDE, FLAG_VISIBLE, GpuInstance, GpuPlacement, GpuPrototype, INSTANCE_LOD_BYTES,
    OPACITY_OVERRIDE_SHIFT, ORDERED_SPLIT_BYTES, PART_KINDS, PLACED_COUNTER_ARRAYS, PLACED_COUNTER_HEADER,
    PLACED_DEPTH_COUNTERS, PLACED_ENTRY_BYTES, PLACED_PART_KINDS, PartKind, SpeciesParams, TREE_PART_KINDS,
    VIEW_CAMERA, VIEW_DEPTH_ORDERED, VIEW_LINE_QUADS,
};
use super::{
    ConiferFoliage, ConiferLodOverride, ConiferLodSettings, ConiferSpecies, ConiferWind, ErrorScope, LineLighting,
    LineOpacity, LineOrder, LineRaster, WoodLineOrder,
};
use crate::model::compact::CompactSpecies;
use crate::model::compact::PLACED_BANDS;
use crate::model::crown_shade::{CrownShade, SkyVisibility};
use crate::model::impostor::CrownImpostor;
use crate::model::prism::WOOD_LINE_FADE;
use crate::model::shading::SphereLight;
use bevy::asset::{embedded_asset, embedded_path};
use bevy::camera::visibility::RenderLayers;
use bevy::core_pipeline::core_3d::{
    Opaque3d, Opaque3dBatchSetKey, Opaque3dBinKey, Transparent3d, TransparentSortingInfo3d,
};
use bevy::core_pipeline::prepass::{
    DepthPrepass, MOTION_VECTOR_PREPASS_FORMAT, MotionVectorPrepass, NORMAL_PREPASS_FORMAT, NormalPrepass,
    PreviousViewUniformOffset, ViewPrepassTextures,
};
use bevy::core_pipeline::schedule::camera_driver;
use bevy::core_pipeline::{Core3d, Core3dSystems};
use bevy::ecs::entity::EntityHashMap;
use bevy::ecs::query::ROQueryItem;
use bevy::ecs::system::SystemParamItem;
use bevy::ecs::system::lifetimeless::{Read, SRes};
use bevy::mesh::{MeshVertexBufferLayoutRef, MeshVertexBufferLayouts, PrimitiveTopology};
use bevy::pbr::{
    LightEntity, MeshPipeline, MeshPipelineKey, MeshPipelineSystems, PrepassPipeline, PrepassViewBindGroup,
    SetMeshViewBindGroup, SetMeshViewBindingArrayBindGroup, SetPrepassViewBindGroup, SetPrepassViewEmptyBindGroup,
    Shadow, ShadowBatchSetKey, ShadowBinKey, ViewKeyCache,
};
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::diagnostic::RecordDiagnostics;
use bevy::render::mesh::allocator::MeshSlabs;
use bevy::render::render_phase::{
    AddRenderCommand, BinnedRenderPhaseType, DrawFunctions, InputUniformIndex, PhaseItem, PhaseItemExtraIndex,
    RenderCommand, RenderCommandResult, SetItemPipeline, TrackedRenderPass, ViewBinnedRenderPhases,
    ViewSortedRenderPhases,
};
use bevy::render::render_resource::binding_types::{
    sampler, storage_buffer_read_only_sized, storage_buffer_sized, texture_2d_array, uniform_buffer_sized,
};
use bevy::render::render_resource::{
    AddressMode, Extent3d, Face, FilterMode, MipmapFilterMode, Sampler, SamplerBindingType, SamplerDescriptor,
    TextureDataOrder, TextureDescriptor, TextureDimension, TextureSampleType, TextureUsages, TextureView,
    TextureViewDescriptor, TextureViewDimension, WgpuFeatures,
};
use bevy::render::render_resource::{
    BindGroup, BindGroupEntries, BindGroupLayoutDescriptor, BindGroupLayoutEntries, Buffer, BufferDescriptor, BufferId,
    BufferUsages, CachedComputePipelineId, CompareFunction, ComputePassDescriptor, ComputePipelineDescriptor,
    DepthStencilState, FragmentState, PipelineCache, PrimitiveState, RenderPipelineDescriptor, ShaderStages,
    SpecializedMeshPipeline, SpecializedRenderPipeline, SpecializedRenderPipelines, TextureFormat, VertexState,
};
use bevy::render::render_resource::{
    BlendState, CachedRenderPipelineId, ColorTargetState, ColorWrites, LoadOp, MultisampleState, Operations,
    RenderPassDepthStencilAttachment, RenderPassDescriptor, StoreOp,
};
use bevy::render::renderer::{RenderAdapterInfo, RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::sync_world::MainEntity;
use bevy::render::view::ExtractedView;
use bevy::render::view::{ViewDepthTexture, ViewUniformOffset};
use bevy::render::{Extract, ExtractSchedule, Render, RenderApp, RenderStartup, RenderSystems};
use bevy::shader::{Shader, ShaderDefVal};
use std::sync::Arc;

/// Every tree drawn by the compact path, grouped by species; only trees
/// that changed are rewritten.
#[derive(Resource, Default, Debug)]
pub struct CompactInstances {
    species: HashMap<AssetId<ConiferSpecies>, SpeciesInstances>,
    slots: EntityHashMap<(AssetId<ConiferSpecies>, u32)>,
    /// Phase keys of species that lost their last tree, to despawn.
    retired_keys: Vec<[Entity; PART_KINDS]>,
}

#[derive(Default, Debug, Clone)]
struct SpeciesInstances {
    instances: Vec<GpuInstance>,
    entities: Vec<Entity>,
    /// Bumped at every change, so extraction copies only what changed.
    generation: u64,
    /// Main-world entities (empty) that key the species' parts in Bevy's
    /// render phases: phases key items by main-world entity, so keys made
    /// up in the render world could collide with real entities' items.
    phase_keys: Option<[Entity; PART_KINDS]>,
}

impl CompactInstances {
    /// Trees tracked, over all species.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// `true` without trees.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Trees of one species.
    pub fn species_len(&self, species: AssetId<ConiferSpecies>) -> usize {
        self.species.get(&species).map_or(0, |s| s.instances.len())
    }

    /// A tracked tree's species and GPU instance (what the instance buffer
    /// holds for it).
    pub fn get(&self, entity: Entity) -> Option<(AssetId<ConiferSpecies>, &GpuInstance)> {
        let &(species, slot) = self.slots.get(&entity)?;
        let list = self.species.get(&species)?;
        (list.entities.get(slot as usize) == Some(&entity)).then(|| (species, &list.instances[slot as usize]))
    }

    fn remove(&mut self, entity: Entity) {
        let Some((species, slot)) = self.slots.remove(&entity) else {
            return;
        };
        let Some(list) = self.species.get_mut(&species) else {
            return;
        };
        let slot = slot as usize;
        list.instances.swap_remove(slot);
        list.entities.swap_remove(slot);
        if let Some(&moved) = list.entities.get(slot) {
            self.slots.insert(moved, (species, slot as u32));
        }
        list.generation += 1;
        if list.instances.is_empty()
            && let Some(gone) = self.species.remove(&species)
            && let Some(keys) = gone.phase_keys
        {
            self.retired_keys.push(keys);
        }
    }

    fn allocate_phase_keys(&mut self, commands: &mut Commands) {
        for list in self.species.values_mut().filter(|s| s.phase_keys.is_none()) {
            list.phase_keys = Some(std::array::from_fn(|_| commands.spawn_empty().id()));
        }
    }

    fn upsert(&mut self, entity: Entity, species: AssetId<ConiferSpecies>, instance: GpuInstance) {
        match self.slots.get(&entity) {
            Some(&(old, slot)) if old == species => {
                let list = self.species.entry(species).or_default();
                if list.instances[slot as usize] != instance {
                    list.instances[slot as usize] = instance;
                    list.generation += 1;
                }
            }
            Some(_) => {
                self.remove(entity);
                self.upsert(entity, species, instance);
            }
            None => {
                let list = self.species.entry(species).or_default();
                self.slots.insert(entity, (species, list.instances.len() as u32));
                list.instances.push(instance);
                list.entities.push(entity);
                list.generation += 1;
            }
        }
    }
}

fn gpu_instance(
    transform: &GlobalTransform,
    over: Option<&ConiferLodOverride>,
    visible: bool,
    layers: Option<&RenderLayers>,
) -> GpuInstance {
    let affine = transform.affine();
    let m = affine.matrix3;
    let t = affine.translation;
    let rule = match over.and_then(|o| o.line_opacity) {
        None => 0,
        Some(LineOpacity::Paper) => 1,
        Some(LineOpacity::AreaPreserving) => 2,
        Some(LineOpacity::Coverage) => 3,
    };
    let layer_mask = view_layers(layers);
    // A NaN or negative override would make every error NaN: such a tree
    // takes the global setting.
    let pixel_error = over.and_then(|o| o.pixel_error).filter(|p| *p >= 0.0);
    let transition = over.and_then(|o| o.transition).filter(|t| t.is_finite());
    GpuInstance {
        rows: [
            [m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x],
            [m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y],
            [m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z],
        ],
        pixel_error: pixel_error.unwrap_or(0.0),
        transition: transition.unwrap_or(0.0),
        flags: (u32::from(visible) * FLAG_VISIBLE)
            | (u32::from(pixel_error.is_some()) * FLAG_PIXEL_ERROR_OVERRIDE)
            | (u32::from(transition.is_some()) * FLAG_TRANSITION_OVERRIDE)
            | (rule << OPACITY_OVERRIDE_SHIFT)
            | match over.and_then(|o| o.far_impostor) {
                None => 0,
                Some(false) => FLAG_IMPOSTOR_OVERRIDE,
                Some(true) => FLAG_IMPOSTOR_OVERRIDE | FLAG_IMPOSTOR_ON,
            },
        layers: layer_mask,
    }
}

type TreeData = (
    Entity,
    &'static ConiferFoliage,
    &'static GlobalTransform,
    Option<&'static ConiferLodOverride>,
    &'static InheritedVisibility,
    Option<&'static RenderLayers>,
);

/// Keeps [`CompactInstances`] in step with the trees (spawned, moved,
/// re-targeted, hidden, despawned), touching only trees that changed.
#[allow(clippy::type_complexity, clippy::too_many_arguments)] // a Bevy system's parameters
pub(super) fn track_instances(
    mut tracked: ResMut<CompactInstances>,
    changed: Query<
        TreeData,
        Or<(
            Changed<GlobalTransform>,
            Changed<ConiferFoliage>,
            Changed<ConiferLodOverride>,
            Changed<InheritedVisibility>,
            Changed<RenderLayers>,
        )>,
    >,
    all: Query<TreeData>,
    mut removed_trees: RemovedComponents<ConiferFoliage>,
    mut removed_overrides: RemovedComponents<ConiferLodOverride>,
    mut removed_layers: RemovedComponents<RenderLayers>,
    mut cpu_time: ResMut<super::ConiferLodCpuTime>,
    mut commands: Commands,
) {
    let _timer = super::systems::CpuTimer::start(&mut cpu_time, true);
    // Phase keys of species that lost their last tree go with them.
    for keys in tracked.retired_keys.drain(..) {
        keys.into_iter().for_each(|key| commands.entity(key).despawn());
    }
    for entity in removed_trees.read() {
        tracked.remove(entity);
    }
    let mut upsert = |(entity, foliage, transform, over, visibility, layers): ROQueryItem<'_, '_, TreeData>| {
        let instance = gpu_instance(transform, over, visibility.get(), layers);
        tracked.upsert(entity, foliage.0.id(), instance);
    };
    // A system's first run sees every component as changed: trees spawned
    // before the plugin's first frame are tracked here too.
    changed.iter().for_each(&mut upsert);
    for entity in removed_overrides.read().chain(removed_layers.read()) {
        if let Ok(tree) = all.get(entity) {
            upsert(tree);
        }
    }
    tracked.allocate_phase_keys(&mut commands);
}

/// The render world's copy of a species: its compact arrays, its trees,
/// and (once prepared) its GPU buffers.
struct RenderSpecies {
    compact: Arc<CompactSpecies>,
    /// The far representation, when the species has one.
    impostor: Option<Arc<CrownImpostor>>,
    params: SpeciesParams,
    instances: Vec<GpuInstance>,
    generation: u64,
    instances_dirty: bool,
    /// Where the trees are, on average: the transparent items' sort point.
    center: Vec3,
    gpu: Option<SpeciesBuffers>,
    /// Render-world entities standing for the species' parts in phases.
    draw_entities: [Entity; PART_KINDS],
    /// The main-world entities that key them there.
    phase_keys: [MainEntity; PART_KINDS],
    /// A second render-world entity for the wood lines: a phase keys its
    /// items by (render, main) entity, and the wood lines are two items,
    /// drawn under and over the foliage lines ([`WoodLineLayer`]).
    wood_over_entity: Entity,
    /// The sphere light table and the material's roughness and reflectance
    /// (bits) it was made for.
    sphere_light: ([u32; 2], SphereLight),
    /// The impostor's crown radius and extinction by height
    /// ([`CrownShade::of`]) and the sky its crown lets each point see
    /// ([`CrownShade::sky_visibility_table`]); `None` without an impostor.
    crown_shade: Option<(CrownShade, SkyVisibility)>,
}

impl RenderSpecies {
    /// Whether the species has anything `kind` could draw.
    fn draws(&self, kind: PartKind) -> bool {
        match kind {
            PartKind::Impostor => self.impostor.is_some(),
            _ => kind.present_in(&self.compact),
        }
    }

    /// Whether a camera draws `kind` of the species, with `by_entry` (its
    /// lines back to front, [`lines_by_entry`]): each expanded placement's
    /// merged and original lines are then one draw, the original lines'.
    fn camera_draws(&self, kind: PartKind, by_entry: bool) -> bool {
        match kind {
            PartKind::PlacedOriginalLines if by_entry => {
                self.draws(PartKind::PlacedOriginalLines) || self.draws(PartKind::PlacedMergedLines)
            }
            PartKind::PlacedMergedLines if by_entry => false,
            _ => self.draws(kind),
        }
    }
}

/// Whether a camera draws each expanded placement's lines on their own, its
/// merged lines then its original lines in one draw (`CONIFER_LINES_BY_ENTRY`):
/// under [`LineOrder::BackToFront`]. Its view buffers hold the draws when it
/// has room for placements ([`PlacedViewBuffers::depth_ordered`]).
fn lines_by_entry(line_order: LineOrder) -> bool {
    line_order == LineOrder::BackToFront
}

/// A species' GPU buffers.
struct SpeciesBuffers {
    params: Buffer,
    instances: Buffer,
    instance_capacity: usize,
    needles: Buffer,
    /// The original-line order, then the prototypes' merged lines by own code.
    line_orders: Buffer,
    merged_lines: Buffer,
    wood_segments: Buffer,
    wood_mesh: Buffer,
    placements: Buffer,
    prototypes: Buffer,
    tree_spheres: Buffer,
    tree_line_parents: Buffer,
    /// The crown impostor's views, one layer each, with their mips (a
    /// blank 1×1 layer for a species without one).
    impostor: TextureView,
    /// Bytes of the impostor texture, every mip level.
    impostor_bytes: u64,
}

impl SpeciesBuffers {
    /// The species' shared arrays (not its trees).
    fn arrays(&self) -> [&Buffer; 9] {
        [
            &self.needles,
            &self.line_orders,
            &self.merged_lines,
            &self.wood_segments,
            &self.wood_mesh,
            &self.placements,
            &self.prototypes,
            &self.tree_spheres,
            &self.tree_line_parents,
        ]
    }

    /// Its parameters and instance buffer.
    fn per_tree(&self) -> [&Buffer; 2] {
        [&self.params, &self.instances]
    }
}

/// Bytes allocated for `buffers`.
fn allocated(buffers: &[&Buffer]) -> u64 {
    buffers.iter().map(|b| b.size()).sum()
}

/// Marks the render-world entities that stand for a species' parts in the
/// render phases.
#[derive(Component, Clone, Copy, Debug)]
pub struct CompactDrawItem {
    species: AssetId<ConiferSpecies>,
    kind: PartKind,
}

/// Every species on the compact path, in the render world.
#[derive(Resource, Default)]
pub struct RenderCompactSpecies {
    species: HashMap<AssetId<ConiferSpecies>, RenderSpecies>,
    /// Phase keys of species that went away, to take out of the phases
    /// (by `queue_compact`, then `queue_compact_shadows`, which clears it).
    retired: Vec<MainEntity>,
    /// [`ConiferLodSettings::max_expanded_placements`].
    max_expanded_placements: u32,
    /// [`ConiferLodSettings::shadow_error_factor`].
    shadow_error_factor: f32,
    /// [`ConiferLodSettings::shadow_line_quads`].
    shadow_line_quads: bool,
    /// [`ConiferLodSettings::line_lighting`].
    line_lighting: LineLighting,
    /// [`ConiferLodSettings::line_raster`].
    line_raster: LineRaster,
    /// [`ConiferLodSettings::wood_line_order`].
    wood_line_order: WoodLineOrder,
    /// [`ConiferLodSettings::line_order`].
    line_order: LineOrder,
    /// The wind's clock at the last extraction ([`ConiferWind::seconds`]),
    /// for the motion vectors' previous positions.
    wind_seconds: Option<f64>,
}

impl RenderCompactSpecies {
    /// Whether a camera whose main texture is `main_format` draws lines as
    /// quads ([`LineRaster::draws_quads`]). The cull pass's six vertices a line
    /// (`VIEW_LINE_QUADS`) and the main and motion vector pipelines'
    /// triangle lists all follow this one answer.
    fn camera_line_quads(&self, main_format: TextureFormat) -> bool {
        self.line_raster.draws_quads(main_format)
    }
}

/// GPU memory the compact path allocated, summed from the sizes of the
/// `wgpu` buffers it created (render world; copied to the main world as
/// [`CompactGpuMemory`]).
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct CompactGpuMemory {
    /// Per species: bytes of its shared arrays (needles, lines, wood).
    pub species_bytes: HashMap<AssetId<ConiferSpecies>, u64>,
    /// Per species: bytes of its parameters and instance buffer.
    pub instance_bytes: HashMap<AssetId<ConiferSpecies>, u64>,
    /// Per species: bytes of its crown impostor's texture, every mip level
    /// (a 4-byte blank without one).
    pub impostor_bytes: HashMap<AssetId<ConiferSpecies>, u64>,
    /// Bytes of the per-view buffers (culling inputs, LOD results,
    /// indirect draws) over all views and species.
    pub view_bytes: u64,
    /// Buffers alive.
    pub buffers: usize,
    /// Sets of per-view bind groups made since the start: made again only
    /// when a buffer they hold is replaced, never per frame.
    pub bind_group_sets_made: u64,
}

impl CompactGpuMemory {
    /// All bytes.
    pub fn total(&self) -> u64 {
        self.species_bytes.values().sum::<u64>()
            + self.instance_bytes.values().sum::<u64>()
            + self.impostor_bytes.values().sum::<u64>()
            + self.view_bytes
    }
}

fn species_params(
    species: &ConiferSpecies,
    compact: &CompactSpecies,
    settings: &ConiferLodSettings,
    wind: &ConiferWind,
    seconds: f64,
    wind_step: f64,
    sphere_light: &SphereLight,
) -> SpeciesParams {
    let (impostor_box, impostor_span) = match &species.impostor {
        Some(i) => (
            [i.axis.x, i.axis.y, i.half_width, i.texel],
            [
                i.bottom,
                i.top(),
                i.views as f32,
                if settings.far_impostor { 2.0 } else { 1.0 },
            ],
        ),
        None => ([0.0; 4], [0.0; 4]),
    };
    let material = &species.material;
    let center = species.crown_center;
    let (lo, hi) = (Vec3::from(species.aabb.min()), Vec3::from(species.aabb.max()));
    let radius = (lo - center).abs().max((hi - center).abs()).length();
    let mut params = SpeciesParams {
        crown_center: center.extend(radius).to_array(),
        grid: compact.grid.origin.extend(compact.grid.step).to_array(),
        wood_grid: compact.wood_grid.origin.extend(compact.wood_grid.step).to_array(),
        needle_color: material.needle_color,
        wood_color: material.wood_color,
        needle_count: compact.tree_counts[0],
        original_line_count: compact.tree_counts[1],
        merged_line_count: compact.tree_counts[2],
        wood_segment_count: compact.wood_segments.len() as u32,
        wood_index_count: compact.wood_indices.len() as u32,
        instance_count: 0,
        max_sides: u32::from(compact.max_sides),
        prism_vertices: crate::model::prism::prism_slot_vertices(compact.max_sides),
        merged_code_min: u32::from(compact.merged_code_range[0]),
        merged_code_max: u32::from(compact.merged_code_range[1]),
        lod_enabled: u32::from(settings.enabled),
        debug_colors: u32::from(settings.debug_colors),
        pixel_error: settings.pixel_error.max(0.0),
        transition: settings.transition.clamp(0.0, 1.0),
        opacity_rule: match settings.line_opacity {
            LineOpacity::Paper => 0,
            LineOpacity::AreaPreserving => 1,
            LineOpacity::Coverage => 2,
        },
        wood_line_fade: WOOD_LINE_FADE,
        roughness: material.roughness,
        reflectance: material.reflectance,
        placement_count: compact.placements.len() as u32,
        prototype_count: compact.prototypes.len() as u32,
        total_needle_count: compact.needles.len() as u32,
        error_scope: match settings.error_scope {
            ErrorScope::Tree => 0,
            ErrorScope::Placement => 1,
        },
        crown_widest_radius: 0.0,
        tree_sphere: compact.tree_sphere.to_array(),
        impostor_box,
        impostor_span,
        impostor_steep: {
            let steep = settings.impostor_steep_fade();
            [steep.start, steep.end, 0.0, 0.0]
        },
        young_needle_color: material.young_needle_color,
        needle_underside_color: material.needle_underside_color,
        upper_wood_color: material.upper_wood_color,
        far_needle_color: compact.far_needle_color.extend(1.0).to_array(),
        wood_heights: [material.upper_wood_heights[0], material.upper_wood_heights[1], 0.0, 0.0],
        sky_visibility: SkyVisibility::open().rows,
        ..SpeciesParams::default()
    };
    params.set_wind(&wind.model(), &species.wind_shape, wind.seconds(seconds), wind_step);
    params.set_sphere_light(sphere_light);
    params.set_line_calibration(species.line_calibration.as_ref());
    params
}

/// An impostor's crown radius and extinction by height, and its sky
/// visibility table (`None` without one).
fn crown_shade(impostor: Option<&CrownImpostor>) -> Option<(CrownShade, SkyVisibility)> {
    impostor.map(|impostor| {
        let shade = CrownShade::of(impostor);
        (shade, shade.sky_visibility_table())
    })
}

/// Copies the species and trees that changed into the render world.
fn extract_compact(
    mut commands: Commands,
    instances: Extract<Res<CompactInstances>>,
    species_assets: Extract<Res<Assets<ConiferSpecies>>>,
    settings: Extract<Res<ConiferLodSettings>>,
    wind: Extract<Res<ConiferWind>>,
    time: Extract<Res<Time>>,
    mut render: ResMut<RenderCompactSpecies>,
) {
    let seconds = time.elapsed_secs_f64();
    let render = &mut *render;
    let wind_seconds = wind.seconds(seconds);
    let wind_step = render.wind_seconds.map_or(0.0, |previous| wind_seconds - previous);
    render.wind_seconds = Some(wind_seconds);
    render.max_expanded_placements = settings.max_expanded_placements;
    render.shadow_error_factor = settings.shadow_error_factor();
    render.shadow_line_quads = settings.shadow_line_quads;
    render.line_lighting = settings.line_lighting;
    render.wood_line_order = settings.wood_line_order;
    render.line_order = settings.line_order;
    render.line_raster = settings.line_raster;
    let mut gone: Vec<AssetId<ConiferSpecies>> = Vec::new();
    for &id in render.species.keys() {
        if !instances.species.contains_key(&id) || species_assets.get(id).is_none() {
            gone.push(id);
        }
    }
    for id in gone {
        if let Some(species) = render.species.remove(&id) {
            render.retired.extend(species.phase_keys);
            for entity in species.draw_entities.into_iter().chain([species.wood_over_entity]) {
                commands.entity(entity).despawn();
            }
        }
    }
    for (&id, tracked) in &instances.species {
        let Some(asset) = species_assets.get(id) else {
            continue;
        };
        let compact = &asset.compact;
        let Some(keys) = tracked.phase_keys else {
            continue;
        };
        let material_key = [asset.material.roughness.to_bits(), asset.material.reflectance.to_bits()];
        let sphere_light = || SphereLight::new(asset.material.roughness, asset.material.reflectance);
        let entry = render.species.entry(id).or_insert_with(|| RenderSpecies {
            compact: compact.clone(),
            impostor: asset.impostor.clone(),
            params: SpeciesParams::default(),
            instances: Vec::new(),
            generation: u64::MAX,
            instances_dirty: true,
            center: Vec3::ZERO,
            gpu: None,
            draw_entities: PartKind::ALL.map(|kind| commands.spawn(CompactDrawItem { species: id, kind }).id()),
            phase_keys: keys.map(MainEntity::from),
            wood_over_entity: commands
                .spawn(CompactDrawItem {
                    species: id,
                    kind: PartKind::WoodLines,
                })
                .id(),
            sphere_light: (material_key, sphere_light()),
            crown_shade: crown_shade(asset.impostor.as_deref()),
        });
        if entry.sphere_light.0 != material_key {
            entry.sphere_light = (material_key, sphere_light());
        }
        if !Arc::ptr_eq(&entry.compact, compact) {
            // A reloaded record: new arrays.
            entry.compact = compact.clone();
            entry.impostor = asset.impostor.clone();
            entry.crown_shade = crown_shade(asset.impostor.as_deref());
            entry.gpu = None;
            entry.instances_dirty = true;
        }
        if entry.generation != tracked.generation {
            entry.instances.clone_from(&tracked.instances);
            entry.generation = tracked.generation;
            entry.instances_dirty = true;
            let sum = entry.instances.iter().fold(Vec3::ZERO, |s, i| {
                s + Vec3::new(i.rows[0][3], i.rows[1][3], i.rows[2][3])
            });
            entry.center = sum / entry.instances.len().max(1) as f32 + asset.crown_center;
        }
        entry.params = species_params(
            asset,
            compact,
            &settings,
            &wind,
            seconds,
            wind_step,
            &entry.sphere_light.1,
        );
        entry.params.set_trunk(&asset.trunk);
        if let Some((shade, sky)) = &entry.crown_shade {
            entry.params.set_crown_shade(shade);
            if settings.sky_occlusion {
                entry.params.set_sky_visibility(sky);
            }
        }
        entry
            .params
            .set_view_light_scale(entry.impostor.as_ref().and_then(|i| i.view_light_scale.as_ref()));
        // Without an impostor the wood lines are drawn once, unlayered.
        if let Some(impostor) = &entry.impostor {
            entry.params.set_wood_visibility(&impostor.wood_visibility);
            entry.params.set_crown_density(&impostor.crown_density);
        }
        entry.params.instance_count = entry.instances.len() as u32;
    }
}

/// The new capacity of a buffer of `capacity` slots holding `len`: grown
/// to the next power of two, shrunk back when under a quarter full, never
/// below 64; `None` when it stays.
fn resized_capacity(capacity: usize, len: usize) -> Option<usize> {
    (len > capacity || (len * 4 < capacity && capacity > 64)).then(|| initial_capacity(len))
}

/// The capacity a new buffer gets for `len` slots.
fn initial_capacity(len: usize) -> usize {
    len.next_power_of_two().max(64)
}

/// A storage buffer holding `bytes` (at least 128 bytes: a binding cannot
/// be empty, nor shorter than one element of its array).
fn storage_buffer(device: &RenderDevice, label: &'static str, bytes: &[u8]) -> Buffer {
    let mut contents = bytes.to_vec();
    contents.resize(contents.len().max(128).next_multiple_of(4), 0);
    device.create_buffer_with_data(&bevy::render::render_resource::BufferInitDescriptor {
        label: Some(label),
        contents: &contents,
        usage: BufferUsages::STORAGE | BufferUsages::COPY_DST,
    })
}

/// An instance buffer of `capacity` trees.
fn instance_buffer(device: &RenderDevice, capacity: usize) -> Buffer {
    let size = (capacity * size_of::<GpuInstance>()) as u64;
    empty_buffer(device, "conifer instances", size, BufferUsages::STORAGE)
}

fn empty_buffer(device: &RenderDevice, label: &'static str, size: u64, usage: BufferUsages) -> Buffer {
    device.create_buffer(&BufferDescriptor {
        label: Some(label),
        size: size.max(16),
        // Copied from by `CompactReadback`.
        usage: usage | BufferUsages::COPY_DST | BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// Creates the buffers of new or reloaded species and writes the trees and
/// parameters that changed.
fn prepare_species(
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    mut render: ResMut<RenderCompactSpecies>,
    mut memory: ResMut<CompactGpuMemory>,
) {
    memory.species_bytes.clear();
    memory.instance_bytes.clear();
    memory.impostor_bytes.clear();
    for (&id, species) in &mut render.species {
        let instance_bytes: &[u8] = bytemuck::cast_slice(&species.instances);
        if species.gpu.is_none() {
            let c = &species.compact;
            let mut wood_mesh: Vec<u32> = c.wood_indices.clone();
            wood_mesh.extend(c.wood_vertices.iter().flatten());
            let capacity = initial_capacity(species.instances.len());
            let (impostor, impostor_bytes) = impostor_texture(&device, &queue, species.impostor.as_deref());
            species.gpu = Some(SpeciesBuffers {
                params: device.create_buffer_with_data(&bevy::render::render_resource::BufferInitDescriptor {
                    label: Some("conifer species params"),
                    contents: bytemuck::bytes_of(&species.params),
                    usage: BufferUsages::UNIFORM | BufferUsages::COPY_DST,
                }),
                instances: instance_buffer(&device, capacity),
                instance_capacity: capacity,
                needles: storage_buffer(&device, "conifer needles", bytemuck::cast_slice(&c.needles)),
                line_orders: storage_buffer(
                    &device,
                    "conifer line orders",
                    bytemuck::cast_slice(&[c.original_lines.as_slice(), &c.merged_by_own].concat()),
                ),
                merged_lines: storage_buffer(&device, "conifer merged lines", bytemuck::cast_slice(&c.merged_lines)),
                wood_segments: storage_buffer(&device, "conifer wood segments", bytemuck::cast_slice(&c.wood_segments)),
                wood_mesh: storage_buffer(&device, "conifer wood mesh", bytemuck::cast_slice(&wood_mesh)),
                placements: storage_buffer(
                    &device,
                    "conifer placements",
                    bytemuck::cast_slice(&c.placements.iter().map(GpuPlacement::new).collect::<Vec<_>>()),
                ),
                prototypes: storage_buffer(
                    &device,
                    "conifer prototypes",
                    bytemuck::cast_slice(&c.prototypes.iter().map(|p| GpuPrototype::new(c, p)).collect::<Vec<_>>()),
                ),
                tree_spheres: storage_buffer(
                    &device,
                    "conifer tree spheres",
                    bytemuck::cast_slice(&c.tree_spheres.iter().map(|s| s.to_array()).collect::<Vec<_>>()),
                ),
                tree_line_parents: storage_buffer(
                    &device,
                    "conifer tree line parents",
                    bytemuck::cast_slice(&c.tree_line_parents),
                ),
                impostor,
                impostor_bytes,
            });
            species.instances_dirty = true;
        }
        let Some(gpu) = species.gpu.as_mut() else { continue };
        // Grown by powers of two, shrunk back after most trees went away.
        if let Some(capacity) = resized_capacity(gpu.instance_capacity, species.instances.len()) {
            gpu.instance_capacity = capacity;
            gpu.instances = instance_buffer(&device, capacity);
            species.instances_dirty = true;
        }
        if species.instances_dirty && !instance_bytes.is_empty() {
            queue.write_buffer(&gpu.instances, 0, instance_bytes);
        }
        species.instances_dirty = false;
        queue.write_buffer(&gpu.params, 0, bytemuck::bytes_of(&species.params));
        memory.species_bytes.insert(id, allocated(&gpu.arrays()));
        memory.impostor_bytes.insert(id, gpu.impostor_bytes);
        memory.instance_bytes.insert(id, allocated(&gpu.per_tree()));
    }
}

/// The texture of `impostor`'s views (an array layer each, every mip
/// level) and its bytes; a blank 1×1 layer without one.
fn impostor_texture(
    device: &RenderDevice,
    queue: &RenderQueue,
    impostor: Option<&CrownImpostor>,
) -> (TextureView, u64) {
    let (views, columns, rows, levels, data) = match impostor {
        Some(impostor) => {
            let chain = impostor.mip_chain();
            // Layer-major: each view's levels, then the next view's.
            let mut data = Vec::new();
            for view in 0..impostor.views {
                for (w, h, texels) in &chain {
                    let size = (w * h) as usize;
                    let first = view as usize * size;
                    data.extend(texels[first..first + size].iter().flatten());
                }
            }
            (
                impostor.views,
                impostor.columns,
                impostor.rows,
                chain.len() as u32,
                data,
            )
        }
        None => (1, 1, 1, 1, vec![0u8; 4]),
    };
    let texture = device.create_texture_with_data(
        queue,
        &TextureDescriptor {
            label: Some("conifer impostor"),
            size: Extent3d {
                width: columns,
                height: rows,
                depth_or_array_layers: views,
            },
            mip_level_count: levels,
            sample_count: 1,
            dimension: TextureDimension::D2,
            format: TextureFormat::Rgba8Unorm,
            usage: TextureUsages::TEXTURE_BINDING | TextureUsages::COPY_DST,
            view_formats: &[],
        },
        TextureDataOrder::LayerMajor,
        &data,
    );
    let view = texture.create_view(&TextureViewDescriptor {
        label: Some("conifer impostor"),
        dimension: Some(TextureViewDimension::D2Array),
        ..default()
    });
    (view, data.len() as u64)
}

/// Per view and species: the culling inputs and outputs and both bind groups.
struct ViewSpecies {
    cull_view: Buffer,
    lods: Buffer,
    args: Buffer,
    capacity: usize,
    instance_count: u32,
    /// A perspective view (cameras, point and spot lights).
    perspective: bool,
    /// Vertices a line takes in the view's draws (6 as a quad, 2 as a
    /// hardware line).
    line_vertices: u32,
    placed: PlacedViewBuffers,
    /// Made by `prepare_views` before the view is culled or drawn.
    groups: Option<ViewBindGroups>,
    /// The buffers `groups` were made with: they are made again only when
    /// one of them is replaced.
    bound: Vec<BufferId>,
    used: bool,
}

/// A view's bind groups for one species.
struct ViewBindGroups {
    cull: BindGroup,
    /// The placed passes' group and `prepare_dispatch`'s.
    placed: [BindGroup; 2],
    draw: BindGroup,
}

impl ViewSpecies {
    fn buffers(&self) -> [&Buffer; 10] {
        let p = &self.placed;
        [
            &self.cull_view,
            &self.lods,
            &self.args,
            &p.counters,
            &p.entries,
            &p.sorted,
            &p.args,
            &p.dispatch,
            &p.ordered,
            &p.ordered_splits,
        ]
    }
}

/// Per view and placed species: the expanded placements (as found, and
/// sorted by draw), their counters, the instanced draws' arguments
/// (16-byte stand-ins for a flat species) and a camera's draws of each
/// placement's lines back to front.
struct PlacedViewBuffers {
    counters: Buffer,
    entries: Buffer,
    sorted: Buffer,
    args: Buffer,
    dispatch: Buffer,
    /// A camera's: one draw of its merged and original lines per entry,
    /// back to front; other views' a 16-byte stand-in.
    ordered: Buffer,
    /// A camera's: where each entry's merged lines end and its original
    /// lines start in its draw (8 bytes an entry, by its index in
    /// `sorted`); other views' a 16-byte stand-in.
    ordered_splits: Buffer,
    /// Whether `ordered` holds a camera's depth-ordered line draws (and
    /// `counters` their depth buckets).
    depth_ordered: bool,
    /// Entries `entries` and `sorted` hold.
    entry_capacity: u32,
    /// Draws of each placed part (prototypes × bands).
    draws: u32,
}

impl PlacedViewBuffers {
    fn new(device: &RenderDevice, entry_capacity: u32, draws: u32, depth_ordered: bool) -> Self {
        let storage = BufferUsages::STORAGE;
        let entry_bytes = u64::from(entry_capacity) * PLACED_ENTRY_BYTES;
        // A camera of a placed species orders its lines by depth.
        let depth_ordered = depth_ordered && entry_capacity > 0;
        let (ordered_bytes, split_bytes, depth_counters) = if depth_ordered {
            (
                u64::from(entry_capacity) * DRAW_ARGS_BYTES,
                u64::from(entry_capacity) * ORDERED_SPLIT_BYTES,
                PLACED_DEPTH_COUNTERS,
            )
        } else {
            (0, 0, 0)
        };
        Self {
            counters: empty_buffer(
                device,
                "conifer placement counters",
                4 * (PLACED_COUNTER_HEADER + PLACED_COUNTER_ARRAYS * u64::from(draws) + depth_counters),
                storage,
            ),
            ordered: empty_buffer(
                device,
                "conifer back-to-front line draws",
                ordered_bytes,
                storage | BufferUsages::INDIRECT,
            ),
            ordered_splits: empty_buffer(device, "conifer back-to-front line splits", split_bytes, storage),
            depth_ordered,
            entries: empty_buffer(device, "conifer placement entries", entry_bytes, storage),
            sorted: empty_buffer(device, "conifer sorted placement entries", entry_bytes, storage),
            args: empty_buffer(
                device,
                "conifer placed draws",
                u64::from(draws) * PLACED_PART_KINDS as u64 * DRAW_ARGS_BYTES,
                storage | BufferUsages::INDIRECT,
            ),
            dispatch: empty_buffer(
                device,
                "conifer placement dispatch",
                16,
                storage | BufferUsages::INDIRECT,
            ),
            entry_capacity,
            draws,
        }
    }
}

/// Every buffer a view's bind groups for a species hold.
fn bound_buffers(gpu: &SpeciesBuffers, view: &ViewSpecies) -> Vec<BufferId> {
    gpu.arrays()
        .into_iter()
        .chain(gpu.per_tree())
        .chain(view.buffers())
        .map(Buffer::id)
        .collect()
}

/// Per-view buffers of the compact path, keyed by (view entity, species).
#[derive(Resource, Default)]
pub struct CompactViews {
    views: HashMap<(Entity, AssetId<ConiferSpecies>), ViewSpecies>,
}

/// The compact path's pipelines and layouts.
#[derive(Resource)]
pub struct CompactPipeline {
    mesh_pipeline: MeshPipeline,
    /// The view layouts of depth-only passes (`None` without Bevy's prepass).
    prepass_layouts: Option<(BindGroupLayoutDescriptor, BindGroupLayoutDescriptor)>,
    /// The prepass view layout with the previous frame's view, for the
    /// motion vector pass (`None` without Bevy's prepass).
    motion_view_layout: Option<BindGroupLayoutDescriptor>,
    shader: Handle<Shader>,
    draw_layout: BindGroupLayoutDescriptor,
    cull_layout: BindGroupLayoutDescriptor,
    placed_layout: BindGroupLayoutDescriptor,
    dispatch_layout: BindGroupLayoutDescriptor,
    /// Trilinear, clamped: the impostors' sampler.
    impostor_sampler: Sampler,
    /// The expansion budget (`budget_demand`, `budget_cutoff`; placed
    /// species), `cull`, then the placed passes: `prepare_dispatch`,
    /// `count_placements`, `scan_placements`, `scatter_placements`.
    cull_pipelines: [CachedComputePipelineId; 7],
    no_vertices: MeshVertexBufferLayoutRef,
    /// Whether indirect draws may start at an instance other than 0 (one
    /// draw per tree needs it).
    supported: bool,
    /// Draw with one indirect draw per tree instead of one multi-draw:
    /// Mesa's lavapipe (22.3) takes every draw of a multi-draw from the
    /// first tree's instance in a pass without colour attachments (only
    /// that tree cast a shadow, `tests/render_shadows.rs`), and in the main
    /// pass once a mesh of Bevy's is drawn in it too (a tree's trunk
    /// vanished beside the forest's terrain, `tests/render_trunk.rs`).
    split_multi_draws: bool,
}

/// The key of a compact draw pipeline: the view's mesh key and the part.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CompactPipelineKey {
    mesh_key: MeshPipelineKey,
    kind: PartKind,
    /// Which pass the pipeline draws in.
    pass: CompactPass,
    /// How lines are lit (the default for every other part).
    line_lighting: LineLighting,
    /// Lines drawn as quads covering each pixel by their strip's area
    /// ([`LineRaster::Area`] in cameras; in shadow views with
    /// [`ConiferLodSettings::shadow_line_quads`]; `false` for every other
    /// part).
    line_quads: bool,
    /// Which of the wood lines' draws this is ([`WoodLineLayer::Whole`]
    /// for every other part and pass).
    wood_layer: WoodLineLayer,
    /// A camera's expanded placements' lines drawn one placement at a
    /// time, its merged and original lines in one draw ([`lines_by_entry`];
    /// the placed original lines' key only).
    lines_by_entry: bool,
}

/// The wood lines' draws. Blended lines are not sorted one by one, so the
/// order of a species' draws decides what lies on top in a pixel both
/// cover. A camera draws a tree's wood lines twice, before its foliage
/// lines and after them, at opacities that split the wood's `a` by the
/// share `g` of the wood the needles leave in sight where they cover the
/// picture ([`crate::model::impostor::WoodVisibility`], measured by the impostor's bake;
/// [`crate::model::impostor::wood_layer_opacities`]): in a pixel the
/// needle lines let `t` through, the wood then takes `a·(g + (1 − g)·t)`
/// and what lies behind the tree `t·(1 − a)`, as among the needles. Drawn
/// only before the foliage lines, the crown hid its branches (the young
/// Scots pine's densest crown pixels 7.7 of 255 short in red,
/// `docs/eval/wood-layers/`); drawn only after, it showed them through
/// its needles (11.0 over).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum WoodLineLayer {
    /// One draw at the wood's opacity (every other part, and the shadow
    /// and motion vector passes).
    #[default]
    Whole,
    /// A camera's draw before the foliage lines.
    UnderFoliage,
    /// Its draw after them.
    OverFoliage,
}

/// The MSAA sample count under which a fading tree's cut and impostor
/// split each pixel's samples (`model::impostor::impostor_samples`); at
/// other counts they split whole pixels.
const CROSSFADE_MSAA_SAMPLES: u32 = 4;

/// The shader definition that makes the camera passes' fragments write
/// their cross-fade's sample mask.
const CROSSFADE_SAMPLES_DEF: &str = "CONIFER_CROSSFADE_SAMPLES";

/// The passes the compact parts are drawn in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CompactPass {
    /// The main pass: lit, in the opaque or the transparent phase.
    Main,
    /// A shadow map: depth only (prepass view layout, hashed alpha test
    /// for lines).
    Shadow,
    /// The motion vector pass ([`draw_motion_vectors`]), after Bevy's
    /// prepass, at the view's MSAA `samples`; with `writes_depth`, prisms
    /// write the prepass depth texture (lines never write depth), and with
    /// `normals` the normal prepass texture too.
    MotionVectors {
        /// The view's MSAA samples.
        samples: u32,
        /// Whether the view has a prepass depth texture to write.
        writes_depth: bool,
        /// Whether the view has a normal prepass texture to write.
        normals: bool,
    },
}

/// The view's key for lines: a line is a pixel wide or less, so the
/// shadow it receives is one hardware-filtered tap (2×2 PCF) of the shadow
/// map instead of the view's wider filter: the filter's width would blur
/// across the pixel the line covers, not along the needles it stands for,
/// and its taps are most of a software rasterizer's cost per line fragment.
fn line_view_key(view_key: MeshPipelineKey) -> MeshPipelineKey {
    (view_key - MeshPipelineKey::SHADOW_FILTER_METHOD_RESERVED_BITS)
        | MeshPipelineKey::SHADOW_FILTER_METHOD_HARDWARE_2X2
}

#[allow(clippy::too_many_arguments)] // a Bevy system's parameters
fn init_compact_pipeline(
    mut commands: Commands,
    asset_server: Res<AssetServer>,
    mesh_pipeline: Res<MeshPipeline>,
    prepass_pipeline: Option<Res<PrepassPipeline>>,
    pipeline_cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
    adapter: Res<RenderAdapterInfo>,
    mut layouts: ResMut<MeshVertexBufferLayouts>,
) {
    let split_multi_draws = adapter.driver.contains("llvmpipe") || adapter.name.contains("llvmpipe");
    let supported = device.features().contains(WgpuFeatures::INDIRECT_FIRST_INSTANCE);
    if !supported {
        warn!(
            "this adapter cannot start indirect draws at an instance (INDIRECT_FIRST_INSTANCE): \
             the conifer plugin draws no trees here (it needs Vulkan, Metal, DX12 or a WebGPU \
             with `indirect-first-instance`)"
        );
    }
    let read = || storage_buffer_read_only_sized(false, None);
    let draw_layout = BindGroupLayoutDescriptor::new(
        "conifer compact draw",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::VERTEX_FRAGMENT,
            (
                uniform_buffer_sized(false, None),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                read(),
                texture_2d_array(TextureSampleType::Float { filterable: true }),
                sampler(SamplerBindingType::Filtering),
                read(),
            ),
        ),
    );
    let cull_layout = BindGroupLayoutDescriptor::new(
        "conifer compact cull",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer_sized(false, None),
                uniform_buffer_sized(false, None),
                read(),
                read(),
                read(),
                read(),
                read(),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
            ),
        ),
    );
    let placed_layout = BindGroupLayoutDescriptor::new(
        "conifer compact placements",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                read(),
                read(),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
                read(),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
            ),
        ),
    );
    let dispatch_layout = BindGroupLayoutDescriptor::new(
        "conifer compact placement dispatch",
        &BindGroupLayoutEntries::single(ShaderStages::COMPUTE, storage_buffer_sized(false, None)),
    );
    let cull_shader = asset_server.load(shader_path("conifer_cull.wgsl"));
    let cull_pipelines = [
        "budget_demand",
        "budget_cutoff",
        "cull",
        "prepare_dispatch",
        "count_placements",
        "scan_placements",
        "scatter_placements",
    ]
    .map(|entry_point| {
        pipeline_cache.queue_compute_pipeline(ComputePipelineDescriptor {
            label: Some(format!("conifer compact {entry_point}").into()),
            layout: if entry_point == "prepare_dispatch" {
                vec![cull_layout.clone(), placed_layout.clone(), dispatch_layout.clone()]
            } else {
                vec![cull_layout.clone(), placed_layout.clone()]
            },
            shader: cull_shader.clone(),
            entry_point: Some(entry_point.into()),
            ..default()
        })
    });
    // The mesh pipeline builds the view layout and shader definitions from
    // a mesh layout; ours pulls its vertices, so its vertex buffers are
    // dropped after.
    let mut positions = Mesh::new(PrimitiveTopology::TriangleList, bevy::asset::RenderAssetUsages::all());
    positions.insert_attribute(Mesh::ATTRIBUTE_POSITION, vec![[0.0f32; 3]]);
    let no_vertices = positions.get_mesh_vertex_buffer_layout(&mut layouts);
    commands.insert_resource(CompactPipeline {
        mesh_pipeline: mesh_pipeline.clone(),
        prepass_layouts: prepass_pipeline
            .as_ref()
            .map(|p| (p.view_layout_no_motion_vectors.clone(), p.empty_layout.clone())),
        motion_view_layout: prepass_pipeline.as_ref().map(|p| p.view_layout_motion_vectors.clone()),
        shader: asset_server.load(shader_path("conifer_compact.wgsl")),
        draw_layout,
        cull_layout,
        placed_layout,
        dispatch_layout,
        impostor_sampler: device.create_sampler(&SamplerDescriptor {
            label: Some("conifer impostor sampler"),
            address_mode_u: AddressMode::ClampToEdge,
            address_mode_v: AddressMode::ClampToEdge,
            address_mode_w: AddressMode::ClampToEdge,
            mag_filter: FilterMode::Linear,
            min_filter: FilterMode::Linear,
            mipmap_filter: MipmapFilterMode::Linear,
            ..default()
        }),
        cull_pipelines,
        no_vertices,
        supported,
        split_multi_draws,
    });
}

impl SpecializedRenderPipeline for CompactPipeline {
    type Key = CompactPipelineKey;

    fn specialize(&self, key: Self::Key) -> RenderPipelineDescriptor {
        match key.pass {
            CompactPass::Main => {}
            CompactPass::Shadow => return self.shadow_descriptor(key.kind, key.line_quads),
            CompactPass::MotionVectors {
                samples,
                writes_depth,
                normals,
            } => {
                return self.motion_descriptor(
                    key.kind,
                    samples,
                    writes_depth,
                    normals,
                    key.line_quads,
                    key.lines_by_entry,
                );
            }
        }
        // A layout with positions never misses an attribute; an error here
        // leaves an empty descriptor, which the pipeline cache reports.
        let mut descriptor =
            match SpecializedMeshPipeline::specialize(&self.mesh_pipeline, key.mesh_key, &self.no_vertices) {
                Ok(descriptor) => descriptor,
                Err(error) => {
                    error!("conifer compact pipeline: {error}");
                    return RenderPipelineDescriptor::default();
                }
            };
        descriptor.label = Some(format!("conifer compact {:?}", key.kind).into());
        descriptor.vertex.shader = self.shader.clone();
        descriptor.vertex.buffers.clear();
        let mut defs: Vec<ShaderDefVal> = vec![
            key.kind.shader_def().into(),
            ShaderDefVal::UInt("MATERIAL_BIND_GROUP".into(), 3),
        ];
        if key.kind.is_blended() {
            defs.push("CONIFER_LINES".into());
            match key.line_lighting {
                LineLighting::Bundle => defs.push("CONIFER_BUNDLE".into()),
                LineLighting::Cylinder => {}
                LineLighting::FacingStrip => defs.push("CONIFER_FACING_STRIP".into()),
            }
        }
        if key.kind.placed_index().is_some() {
            defs.push("CONIFER_PLACED".into());
        }
        if key.lines_by_entry {
            defs.push("CONIFER_LINES_BY_ENTRY".into());
        }
        if key.line_quads {
            defs.push("CONIFER_LINE_QUADS".into());
        }
        if key.wood_layer != WoodLineLayer::Whole {
            defs.push("CONIFER_WOOD_LAYERS".into());
        }
        if key.mesh_key.msaa_samples() == CROSSFADE_MSAA_SAMPLES {
            defs.push(CROSSFADE_SAMPLES_DEF.into());
        }
        if key.wood_layer == WoodLineLayer::OverFoliage {
            defs.push("CONIFER_WOOD_OVER_FOLIAGE".into());
        }
        if matches!(
            key.kind,
            PartKind::Prisms | PartKind::PlacedPrisms | PartKind::WoodPrisms
        ) {
            // Prisms shaded as the round cylinders they stand for.
            defs.push("CONIFER_ROUND_PRISMS".into());
        }
        if matches!(
            key.kind,
            PartKind::WoodPrisms | PartKind::WoodLines | PartKind::WoodMesh
        ) {
            // Bark coloured by the height of each fragment.
            defs.push("CONIFER_BARK".into());
        }
        descriptor.vertex.shader_defs.extend(defs.iter().cloned());
        if let Some(fragment) = descriptor.fragment.as_mut() {
            fragment.shader = self.shader.clone();
            fragment.shader_defs.extend(defs);
        }
        descriptor.layout.truncate(2);
        descriptor.layout.push(self.draw_layout.clone());
        // Prisms are closed and wound as the CPU tessellator winds them.
        descriptor.primitive.cull_mode = (!key.kind.is_blended()).then_some(Face::Back);
        descriptor
    }
}

impl CompactPipeline {
    /// A depth-only pipeline for shadow maps: prisms write depth, lines
    /// keep each fragment with their opacity (hashed; as quads of their
    /// strip with `line_quads`), the impostor
    /// with its texels' coverage (hashed).
    fn shadow_descriptor(&self, kind: PartKind, line_quads: bool) -> RenderPipelineDescriptor {
        let Some((view_layout, _)) = self.prepass_layouts.clone() else {
            return RenderPipelineDescriptor::default();
        };
        let mut defs: Vec<ShaderDefVal> = vec![kind.shader_def().into(), "CONIFER_SHADOW".into()];
        if kind.placed_index().is_some() {
            defs.push("CONIFER_PLACED".into());
        }
        if line_quads {
            defs.push("CONIFER_LINE_QUADS".into());
        }
        let fragment = (kind.is_lines() || kind == PartKind::Impostor).then(|| self.fragment_state(&defs, Vec::new()));
        let label = format!("conifer compact shadow {kind:?}");
        self.prepass_layout_descriptor(label, view_layout, kind, &defs, fragment, None, true, line_quads)
    }

    /// The fragment stage of `conifer_compact.wgsl` with `defs`, writing
    /// `targets`.
    fn fragment_state(&self, defs: &[ShaderDefVal], targets: Vec<Option<ColorTargetState>>) -> FragmentState {
        FragmentState {
            shader: self.shader.clone(),
            shader_defs: defs.to_vec(),
            entry_point: Some("fragment".into()),
            targets,
        }
    }

    /// A pipeline of a part drawn with one of Bevy's prepass view layouts
    /// (`view_layout`, then the prepass's empty group and the species'
    /// draw group): its vertices pulled by `conifer_compact.wgsl` with
    /// `defs`, lines as line lists (as triangle lists with `line_quads`),
    /// tested against `Depth32Float` (reversed Z), writing depth when
    /// `writes_depth`, culling `cull_mode`. An empty
    /// descriptor without Bevy's prepass (the pipeline cache reports it).
    #[allow(clippy::too_many_arguments)] // one descriptor's parts
    fn prepass_layout_descriptor(
        &self,
        label: String,
        view_layout: BindGroupLayoutDescriptor,
        kind: PartKind,
        defs: &[ShaderDefVal],
        fragment: Option<FragmentState>,
        cull_mode: Option<Face>,
        writes_depth: bool,
        line_quads: bool,
    ) -> RenderPipelineDescriptor {
        let Some((_, empty_layout)) = self.prepass_layouts.clone() else {
            return RenderPipelineDescriptor::default();
        };
        RenderPipelineDescriptor {
            label: Some(label.into()),
            layout: vec![view_layout, empty_layout, self.draw_layout.clone()],
            vertex: VertexState {
                shader: self.shader.clone(),
                shader_defs: defs.to_vec(),
                entry_point: Some("vertex".into()),
                buffers: Vec::new(),
            },
            fragment,
            primitive: PrimitiveState {
                topology: if kind.is_lines() && !line_quads {
                    PrimitiveTopology::LineList
                } else {
                    PrimitiveTopology::TriangleList
                },
                cull_mode,
                ..default()
            },
            depth_stencil: Some(DepthStencilState {
                format: TextureFormat::Depth32Float,
                depth_write_enabled: Some(writes_depth),
                depth_compare: Some(CompareFunction::GreaterEqual),
                stencil: default(),
                bias: default(),
            }),
            ..default()
        }
    }
}

impl CompactPipeline {
    /// The motion vector pipeline of a part: the prepass view layout with
    /// the previous frame's view; the fragment writes the motion vector
    /// target (location 1, as in Bevy's prepass). Prisms and wood replace
    /// what is there; a line blends its motion over it by its opacity
    /// (skipping fragments under `MOTION_MIN_OPACITY`, 1/64): Bevy's target
    /// holds one vector a pixel, and a pixel a faint near line crosses is
    /// mostly what lies behind it (claiming all of it for the line let TAA
    /// drag the far trees' history along the near line's motion: a haze). Prisms and wood write
    /// the prepass depth texture when the view has one (`writes_depth`),
    /// so the nearest part's motion wins and TAA finds it by depth; lines
    /// only test depth: they are translucent, and a depth write would hide
    /// the lines behind them. With `normals` (a normal prepass) the parts
    /// that write depth write their normals too, as Bevy's prepass does,
    /// so what reads both (SSAO) sees one surface.
    fn motion_descriptor(
        &self,
        kind: PartKind,
        samples: u32,
        writes_depth: bool,
        normals: bool,
        line_quads: bool,
        lines_by_entry: bool,
    ) -> RenderPipelineDescriptor {
        let Some(view_layout) = self.motion_view_layout.clone() else {
            return RenderPipelineDescriptor::default();
        };
        let mut defs: Vec<ShaderDefVal> = vec![
            kind.shader_def().into(),
            "CONIFER_SHADOW".into(),
            "CONIFER_MOTION_VECTORS".into(),
        ];
        if kind.is_blended() {
            defs.push("CONIFER_LINES".into());
        }
        if kind.placed_index().is_some() {
            defs.push("CONIFER_PLACED".into());
        }
        if line_quads {
            defs.push("CONIFER_LINE_QUADS".into());
        }
        if lines_by_entry {
            defs.push("CONIFER_LINES_BY_ENTRY".into());
        }
        let writes_surface = writes_depth && !kind.is_blended();
        if normals {
            defs.push("CONIFER_NORMALS".into());
        }
        if samples == CROSSFADE_MSAA_SAMPLES {
            defs.push(CROSSFADE_SAMPLES_DEF.into());
        }
        let targets = vec![
            normals.then_some(ColorTargetState {
                format: NORMAL_PREPASS_FORMAT,
                blend: None,
                write_mask: if writes_surface {
                    ColorWrites::ALL
                } else {
                    ColorWrites::empty()
                },
            }),
            Some(ColorTargetState {
                format: MOTION_VECTOR_PREPASS_FORMAT,
                // A translucent line moves a pixel by its share: what lies
                // behind it keeps the rest.
                blend: kind.is_blended().then_some(BlendState::ALPHA_BLENDING),
                write_mask: ColorWrites::ALL,
            }),
        ];
        let fragment = Some(self.fragment_state(&defs, targets));
        let label = format!("conifer compact motion vectors {kind:?}");
        let cull_mode = (!kind.is_blended()).then_some(Face::Back);
        let mut descriptor = self.prepass_layout_descriptor(
            label,
            view_layout,
            kind,
            &defs,
            fragment,
            cull_mode,
            writes_surface,
            line_quads,
        );
        descriptor.multisample = MultisampleState {
            count: samples,
            ..default()
        };
        descriptor
    }
}

/// Frustum planes of `clip_from_world` (Gribb and Hartmann), normals
/// pointing inside, normalized; reversed-Z infinite projections have no far
/// plane (it comes out zero and culls nothing).
fn frustum_planes(clip_from_world: &Mat4) -> [[f32; 4]; 6] {
    let rows = [
        clip_from_world.row(0),
        clip_from_world.row(1),
        clip_from_world.row(2),
        clip_from_world.row(3),
    ];
    let planes = [
        rows[3] + rows[0],
        rows[3] - rows[0],
        rows[3] + rows[1],
        rows[3] - rows[1],
        rows[2],
        rows[3] - rows[2],
    ];
    planes.map(|p| {
        let length = p.truncate().length();
        if length > 1e-12 {
            (p / length).to_array()
        } else {
            [0.0, 0.0, 0.0, 1.0]
        }
    })
}

fn view_layers(layers: Option<&RenderLayers>) -> u32 {
    match layers {
        None => 1,
        Some(layers) => (0..32)
            .filter(|&l| layers.intersects(&RenderLayers::layer(l)))
            .fold(0u32, |m, l| m | 1 << l),
    }
}

/// Writes each view's culling inputs and (re)creates the per-view buffers
/// and bind groups.
#[allow(clippy::too_many_arguments)] // a Bevy system's parameters
fn prepare_views(
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    pipeline: Res<CompactPipeline>,
    pipeline_cache: Res<PipelineCache>,
    render: Res<RenderCompactSpecies>,
    mut compact_views: ResMut<CompactViews>,
    mut memory: ResMut<CompactGpuMemory>,
    opaque_phases: Res<ViewBinnedRenderPhases<Opaque3d>>,
    shadow_phases: Res<ViewBinnedRenderPhases<Shadow>>,
    views: Query<(Entity, &ExtractedView, Option<&RenderLayers>)>,
    cameras: Query<(&ExtractedView, &bevy::pbr::ViewLightEntities)>,
    cascades: Query<&bevy::pbr::LightEntity>,
) {
    for view in compact_views.views.values_mut() {
        view.used = false;
    }
    // A directional light's cascades belong to one camera each: their
    // budget goes to the trees nearest that camera.
    let mut budget_origins = EntityHashMap::<[f32; 4]>::default();
    for (camera, light_views) in &cameras {
        let Some((slope, true)) = super::view_error_slope(&camera.clip_from_view, camera.viewport.w as f32) else {
            continue;
        };
        let origin = camera.world_from_view.translation().extend(slope).to_array();
        for &light_view in &light_views.lights {
            if matches!(cascades.get(light_view), Ok(bevy::pbr::LightEntity::Directional { .. })) {
                budget_origins.insert(light_view, origin);
            }
        }
    }
    let draw_layout = pipeline_cache.get_bind_group_layout(&pipeline.draw_layout);
    let cull_layout = pipeline_cache.get_bind_group_layout(&pipeline.cull_layout);
    let placed_layout = pipeline_cache.get_bind_group_layout(&pipeline.placed_layout);
    let dispatch_layout = pipeline_cache.get_bind_group_layout(&pipeline.dispatch_layout);
    // Entries one storage binding of the device holds: no view's budget
    // may pass it (a larger buffer would fail to bind, drawing nothing).
    let device_entries = device.limits().max_storage_buffer_binding_size / PLACED_ENTRY_BYTES;
    for (view_entity, view, layers) in &views {
        if !opaque_phases.contains_key(&view.retained_view_entity)
            && !shadow_phases.contains_key(&view.retained_view_entity)
        {
            continue;
        }
        let clip_from_world = view
            .clip_from_world
            .unwrap_or_else(|| view.clip_from_view * view.world_from_view.to_matrix().inverse());
        let height = view.viewport.w as f32;
        let Some((slope, perspective)) = super::view_error_slope(&view.clip_from_view, height) else {
            continue;
        };
        let mut planes = frustum_planes(&clip_from_world);
        if !perspective {
            // Orthographic views are directional shadow cascades: casters
            // between the light and the near plane still cast (they are
            // flattened onto it), so the near plane culls nothing.
            planes[5] = [0.0, 0.0, 0.0, 1.0];
        }
        // Cameras fade trees into their impostors; a shadow view casts the
        // lines' shadows at its own texel's error, and the impostor only
        // for the trees past its budget.
        let camera = opaque_phases.contains_key(&view.retained_view_entity);
        let cull_view = CullView {
            planes,
            world_position: view
                .world_from_view
                .translation()
                .extend(if camera { 1.0 } else { render.shadow_error_factor })
                .to_array(),
            error_slope: slope,
            perspective: u32::from(perspective)
                | if camera { VIEW_CAMERA } else { 0 }
                | if (camera && render.camera_line_quads(view.target_format)) || (!camera && render.shadow_line_quads) {
                    VIEW_LINE_QUADS
                } else {
                    0
                },
            layers: view_layers(layers),
            entry_capacity: 0,
            budget_origin: budget_origins.get(&view_entity).copied().unwrap_or_default(),
        };
        for (&id, species) in &render.species {
            let Some(gpu) = species.gpu.as_ref() else { continue };
            let n = species.instances.len();
            if n == 0 {
                continue;
            }
            let placements = species.compact.placements.len();
            let draws = species.compact.prototypes.len() as u32 * PLACED_BANDS;
            // A camera blends its expanded placements' lines back to front.
            let depth_ordered = camera && lines_by_entry(render.line_order);
            let max_entries = u64::from(render.max_expanded_placements.max(1)).min(device_entries) as usize;
            let entries_needed = (n.saturating_mul(placements)).min(max_entries);
            let fresh = |capacity: usize| {
                let cull_view = empty_buffer(
                    &device,
                    "conifer cull view",
                    size_of::<CullView>() as u64,
                    BufferUsages::UNIFORM,
                );
                let lods = empty_buffer(
                    &device,
                    "conifer instance lods",
                    capacity as u64 * INSTANCE_LOD_BYTES,
                    BufferUsages::STORAGE,
                );
                let args = empty_buffer(
                    &device,
                    "conifer indirect draws",
                    capacity as u64 * DRAW_ARGS_BYTES * TREE_PART_KINDS as u64,
                    BufferUsages::STORAGE | BufferUsages::INDIRECT,
                );
                (cull_view, lods, args)
            };
            // The entry capacity a view's placement buffers of `current`
            // entries should have, when it changes (0 for a flat species).
            let placed_capacity = |current: u32| -> Option<u32> {
                if placements == 0 {
                    return (current != 0).then_some(0);
                }
                let resized = match current {
                    0 => Some(initial_capacity(entries_needed)),
                    c => resized_capacity(c as usize, entries_needed),
                };
                resized.map(|c| c.min(max_entries) as u32)
            };
            let make_groups = |cull_view: &Buffer, lods: &Buffer, args: &Buffer, placed: &PlacedViewBuffers| {
                let cull = device.create_bind_group(
                    "conifer compact cull",
                    &cull_layout,
                    &BindGroupEntries::sequential((
                        cull_view.as_entire_binding(),
                        gpu.params.as_entire_binding(),
                        gpu.instances.as_entire_binding(),
                        gpu.needles.as_entire_binding(),
                        gpu.line_orders.as_entire_binding(),
                        gpu.merged_lines.as_entire_binding(),
                        gpu.wood_segments.as_entire_binding(),
                        lods.as_entire_binding(),
                        args.as_entire_binding(),
                    )),
                );
                let placed_group = device.create_bind_group(
                    "conifer compact placements",
                    &placed_layout,
                    &BindGroupEntries::sequential((
                        gpu.placements.as_entire_binding(),
                        gpu.prototypes.as_entire_binding(),
                        placed.counters.as_entire_binding(),
                        placed.entries.as_entire_binding(),
                        placed.sorted.as_entire_binding(),
                        placed.args.as_entire_binding(),
                        gpu.tree_spheres.as_entire_binding(),
                        placed.ordered.as_entire_binding(),
                        placed.ordered_splits.as_entire_binding(),
                    )),
                );
                let dispatch_group = device.create_bind_group(
                    "conifer compact placement dispatch",
                    &dispatch_layout,
                    &BindGroupEntries::single(placed.dispatch.as_entire_binding()),
                );
                let draw = device.create_bind_group(
                    "conifer compact draw",
                    &draw_layout,
                    &BindGroupEntries::sequential((
                        gpu.params.as_entire_binding(),
                        gpu.instances.as_entire_binding(),
                        lods.as_entire_binding(),
                        gpu.needles.as_entire_binding(),
                        gpu.line_orders.as_entire_binding(),
                        gpu.merged_lines.as_entire_binding(),
                        gpu.wood_segments.as_entire_binding(),
                        gpu.wood_mesh.as_entire_binding(),
                        gpu.placements.as_entire_binding(),
                        gpu.prototypes.as_entire_binding(),
                        placed.sorted.as_entire_binding(),
                        gpu.tree_spheres.as_entire_binding(),
                        gpu.tree_line_parents.as_entire_binding(),
                        &gpu.impostor,
                        &pipeline.impostor_sampler,
                        placed.ordered_splits.as_entire_binding(),
                    )),
                );
                ViewBindGroups {
                    cull,
                    placed: [placed_group, dispatch_group],
                    draw,
                }
            };
            let v = compact_views.views.entry((view_entity, id)).or_insert_with(|| {
                let capacity = initial_capacity(n);
                let (cull_view, lods, args) = fresh(capacity);
                ViewSpecies {
                    cull_view,
                    lods,
                    args,
                    capacity,
                    instance_count: 0,
                    perspective,
                    line_vertices: 2,
                    placed: PlacedViewBuffers::new(&device, placed_capacity(0).unwrap_or(0), draws, depth_ordered),
                    groups: None,
                    bound: Vec::new(),
                    used: false,
                }
            });
            if let Some(capacity) = resized_capacity(v.capacity, n) {
                (v.cull_view, v.lods, v.args) = fresh(capacity);
                v.capacity = capacity;
            }
            if let Some(entry_capacity) = placed_capacity(v.placed.entry_capacity) {
                v.placed = PlacedViewBuffers::new(&device, entry_capacity, draws, depth_ordered);
            } else if v.placed.draws != draws
                || v.placed.depth_ordered != (depth_ordered && v.placed.entry_capacity > 0)
            {
                v.placed = PlacedViewBuffers::new(&device, v.placed.entry_capacity, draws, depth_ordered);
            }
            let bound = bound_buffers(gpu, v);
            if bound != v.bound {
                memory.bind_group_sets_made += 1;
                v.groups = Some(make_groups(&v.cull_view, &v.lods, &v.args, &v.placed));
                v.bound = bound;
            }
            v.instance_count = n as u32;
            v.perspective = perspective;
            v.line_vertices = if cull_view.perspective & VIEW_LINE_QUADS != 0 {
                6
            } else {
                2
            };
            v.used = true;
            // The budget is the setting, however large the buffers grew
            // (they shrink only well below their length).
            let cull_view = CullView {
                entry_capacity: v.placed.entry_capacity.min(max_entries as u32),
                perspective: cull_view.perspective | if v.placed.depth_ordered { VIEW_DEPTH_ORDERED } else { 0 },
                ..cull_view
            };
            queue.write_buffer(&v.cull_view, 0, bytemuck::bytes_of(&cull_view));
        }
    }
    compact_views.views.retain(|_, v| v.used);
    memory.view_bytes = compact_views.views.values().map(|v| allocated(&v.buffers())).sum();
    let species_buffers = render
        .species
        .values()
        .filter_map(|s| s.gpu.as_ref())
        .map(|gpu| gpu.arrays().len() + gpu.per_tree().len());
    memory.buffers =
        compact_views.views.values().map(|v| v.buffers().len()).sum::<usize>() + species_buffers.sum::<usize>();
}

/// Puts each species' parts in each view's opaque and transparent phases.
#[allow(clippy::too_many_arguments)] // a Bevy system's parameters
fn queue_compact(
    pipeline: Res<CompactPipeline>,
    mut pipelines: ResMut<SpecializedRenderPipelines<CompactPipeline>>,
    pipeline_cache: Res<PipelineCache>,
    render: Res<RenderCompactSpecies>,
    view_key_cache: Res<ViewKeyCache>,
    opaque_draw_functions: Res<DrawFunctions<Opaque3d>>,
    transparent_draw_functions: Res<DrawFunctions<Transparent3d>>,
    mut opaque_phases: ResMut<ViewBinnedRenderPhases<Opaque3d>>,
    mut transparent_phases: ResMut<ViewSortedRenderPhases<Transparent3d>>,
    views: Query<&ExtractedView>,
) {
    if !pipeline.supported {
        return;
    }
    let draw_opaque = opaque_draw_functions.read().id::<DrawCompact>();
    let draw_transparent = transparent_draw_functions.read().id::<DrawCompact>();
    let retired = &render.retired;
    for view in &views {
        let Some(opaque) = opaque_phases.get_mut(&view.retained_view_entity) else {
            continue;
        };
        for &entity in retired {
            opaque.remove(entity);
        }
        let Some(transparent) = transparent_phases.get_mut(&view.retained_view_entity) else {
            continue;
        };
        let Some(&view_key) = view_key_cache.get(&view.retained_view_entity) else {
            continue;
        };
        for (&id, species) in &render.species {
            // Queueing runs before this frame's buffers are prepared: a
            // species with trees is queued, and its draw skips a view whose
            // buffers could not be made.
            let drawn = !species.instances.is_empty();
            let by_entry = lines_by_entry(render.line_order);
            for kind in PartKind::ALL {
                let entity = species.draw_entities[kind.index()];
                let main_entity = species.phase_keys[kind.index()];
                if !kind.is_blended() {
                    opaque.remove(main_entity);
                }
                if !drawn || !species.camera_draws(kind, by_entry) {
                    continue;
                }
                let line_quads = kind.is_lines() && render.camera_line_quads(view.target_format);
                let (topology, blend, mesh_view_key) = if kind.is_lines() {
                    (
                        if line_quads {
                            PrimitiveTopology::TriangleList
                        } else {
                            PrimitiveTopology::LineList
                        },
                        MeshPipelineKey::BLEND_ALPHA,
                        line_view_key(view_key),
                    )
                } else if kind == PartKind::Impostor {
                    (PrimitiveTopology::TriangleList, MeshPipelineKey::BLEND_ALPHA, view_key)
                } else {
                    (PrimitiveTopology::TriangleList, MeshPipelineKey::empty(), view_key)
                };
                // A species' wood lines are drawn under its foliage lines
                // (as if a millimetre farther) and, layered, over them too
                // (a millimetre nearer) ([`WoodLineLayer`]), which takes
                // the impostor's wood visibility; every other part once.
                let layered = render.wood_line_order == WoodLineOrder::Layered && species.impostor.is_some();
                let layers: &[(WoodLineLayer, f32, Entity)] = match (kind, layered) {
                    (PartKind::WoodLines, true) => &[
                        (WoodLineLayer::UnderFoliage, -1e-3, entity),
                        (WoodLineLayer::OverFoliage, 1e-3, species.wood_over_entity),
                    ],
                    (PartKind::WoodLines, false) => &[(WoodLineLayer::Whole, -1e-3, entity)],
                    _ => &[(WoodLineLayer::Whole, 0.0, entity)],
                };
                for &(wood_layer, depth_bias, entity) in layers {
                    let key = CompactPipelineKey {
                        mesh_key: mesh_view_key
                            | blend
                            | MeshPipelineKey::from_primitive_topology_and_strip_index(topology, None),
                        kind,
                        pass: CompactPass::Main,
                        line_lighting: if kind.is_blended() {
                            render.line_lighting
                        } else {
                            LineLighting::default()
                        },
                        line_quads,
                        wood_layer,
                        lines_by_entry: by_entry && kind == PartKind::PlacedOriginalLines,
                    };
                    let pipeline_id = pipelines.specialize(&pipeline_cache, &pipeline, key);
                    if kind.is_blended() {
                        transparent.add_transient(Transparent3d {
                            sorting_info: TransparentSortingInfo3d::Sorted {
                                mesh_center: species.center,
                                depth_bias,
                            },
                            entity: (entity, main_entity),
                            pipeline: pipeline_id,
                            draw_function: draw_transparent,
                            distance: 0.0,
                            batch_range: 0..1,
                            extra_index: PhaseItemExtraIndex::None,
                            indexed: false,
                        });
                        continue;
                    }
                    opaque.add(
                        Opaque3dBatchSetKey {
                            draw_function: draw_opaque,
                            pipeline: pipeline_id,
                            material_bind_group_index: None,
                            lightmap_slab: None,
                            slabs: MeshSlabs::default(),
                        },
                        Opaque3dBinKey { asset_id: id.untyped() },
                        (entity, main_entity),
                        InputUniformIndex::default(),
                        BinnedRenderPhaseType::NonMesh,
                    );
                }
            }
        }
    }
}

/// Puts each species' parts in each shadow view's phase (directional
/// cascades, point-light faces, spot lights).
#[allow(clippy::too_many_arguments)] // a Bevy system's parameters
fn queue_compact_shadows(
    pipeline: Res<CompactPipeline>,
    mut pipelines: ResMut<SpecializedRenderPipelines<CompactPipeline>>,
    pipeline_cache: Res<PipelineCache>,
    mut render: ResMut<RenderCompactSpecies>,
    shadow_draw_functions: Res<DrawFunctions<Shadow>>,
    mut shadow_phases: ResMut<ViewBinnedRenderPhases<Shadow>>,
    views: Query<&ExtractedView, With<LightEntity>>,
) {
    // The last queue system: the retired keys are out of every phase after it.
    let retired = std::mem::take(&mut render.retired);
    if pipeline.prepass_layouts.is_none() || !pipeline.supported {
        return;
    }
    let draw = shadow_draw_functions.read().id::<DrawCompactShadow>();
    for view in &views {
        let Some(phase) = shadow_phases.get_mut(&view.retained_view_entity) else {
            continue;
        };
        for &entity in &retired {
            phase.remove(entity);
        }
        for (&id, species) in &render.species {
            // Queueing runs before this frame's buffers are prepared: a
            // species with trees is queued, and its draw skips a view whose
            // buffers could not be made.
            let drawn = !species.instances.is_empty();
            for kind in PartKind::ALL {
                let entity = species.draw_entities[kind.index()];
                let main_entity = species.phase_keys[kind.index()];
                phase.remove(main_entity);
                // The impostor casts for the trees past the view's budget.
                if !drawn || !species.draws(kind) {
                    continue;
                }
                let key = CompactPipelineKey {
                    mesh_key: MeshPipelineKey::DEPTH_PREPASS,
                    kind,
                    pass: CompactPass::Shadow,
                    line_lighting: LineLighting::default(),
                    line_quads: kind.is_lines() && render.shadow_line_quads,
                    wood_layer: WoodLineLayer::Whole,
                    lines_by_entry: false,
                };
                let pipeline_id = pipelines.specialize(&pipeline_cache, &pipeline, key);
                phase.add(
                    ShadowBatchSetKey {
                        pipeline: pipeline_id,
                        draw_function: draw,
                        material_bind_group_index: None,
                        slabs: MeshSlabs::default(),
                    },
                    ShadowBinKey { asset_id: id.untyped() },
                    (entity, main_entity),
                    InputUniformIndex::default(),
                    BinnedRenderPhaseType::NonMesh,
                );
            }
        }
    }
}

/// The compact parts each view with a [`MotionVectorPrepass`] draws into
/// its motion vectors, and their pipelines, queued each frame.
#[derive(Resource, Default)]
pub struct CompactMotionDraws {
    views: EntityHashMap<Vec<(AssetId<ConiferSpecies>, PartKind, CachedRenderPipelineId)>>,
}

/// Queues the motion vector draws of every view with a
/// [`MotionVectorPrepass`]: opaque parts first (they write the prepass
/// depth), then lines. The impostor is left to the background's motion
/// vectors: it stands for a crown at hundreds of metres, where a camera's
/// move shows as its turn.
#[allow(clippy::type_complexity)] // a view query
fn queue_compact_motion_vectors(
    pipeline: Res<CompactPipeline>,
    mut pipelines: ResMut<SpecializedRenderPipelines<CompactPipeline>>,
    pipeline_cache: Res<PipelineCache>,
    render: Res<RenderCompactSpecies>,
    mut draws: ResMut<CompactMotionDraws>,
    views: Query<(Entity, &ExtractedView, &Msaa, Has<DepthPrepass>, Has<NormalPrepass>), With<MotionVectorPrepass>>,
) {
    draws.views.clear();
    if pipeline.motion_view_layout.is_none() || !pipeline.supported {
        return;
    }
    for (view, extracted, msaa, depth_prepass, normal_prepass) in &views {
        let pass = CompactPass::MotionVectors {
            samples: msaa.samples(),
            writes_depth: depth_prepass,
            normals: normal_prepass,
        };
        let mut list = Vec::new();
        for blended in [false, true] {
            for (&id, species) in &render.species {
                if species.instances.is_empty() {
                    continue;
                }
                let by_entry = lines_by_entry(render.line_order);
                for kind in PartKind::ALL {
                    if kind == PartKind::Impostor
                        || kind.is_blended() != blended
                        || !species.camera_draws(kind, by_entry)
                    {
                        continue;
                    }
                    let key = CompactPipelineKey {
                        mesh_key: MeshPipelineKey::empty(),
                        kind,
                        pass,
                        line_lighting: LineLighting::default(),
                        line_quads: kind.is_lines() && render.camera_line_quads(extracted.target_format),
                        wood_layer: WoodLineLayer::Whole,
                        lines_by_entry: by_entry && kind == PartKind::PlacedOriginalLines,
                    };
                    list.push((id, kind, pipelines.specialize(&pipeline_cache, &pipeline, key)));
                }
            }
        }
        draws.views.insert(view, list);
    }
}

/// Writes the compact parts' motion vectors after Bevy's prepass (so the
/// background's camera-turn vectors, drawn where the prepass left no
/// depth, are overwritten where a tree stands, lines included): each
/// vertex's position this frame and last (last frame's camera, last
/// frame's wind), as Bevy's prepass does for meshes. TAA reprojects the
/// trees' history along them instead of the sky's.
#[allow(clippy::type_complexity)] // a view query
fn draw_motion_vectors(
    view: ViewQuery<
        (
            &ViewDepthTexture,
            &ViewPrepassTextures,
            &ViewUniformOffset,
            &PreviousViewUniformOffset,
        ),
        With<MotionVectorPrepass>,
    >,
    draws: Res<CompactMotionDraws>,
    compact_views: Res<CompactViews>,
    prepass_view_bind_group: Res<PrepassViewBindGroup>,
    pipeline_cache: Res<PipelineCache>,
    compact_pipeline: Res<CompactPipeline>,
    mut ctx: RenderContext,
) {
    let view_entity = view.entity();
    let (view_depth, prepass_textures, view_offset, previous_offset) = view.into_inner();
    let (Some(list), Some(motion_vectors), Some(view_group)) = (
        draws.views.get(&view_entity),
        prepass_textures.motion_vectors.as_ref(),
        prepass_view_bind_group.motion_vectors.as_ref(),
    ) else {
        return;
    };
    if list.is_empty() {
        return;
    }
    // Prisms write the prepass depth (what TAA and the other prepass
    // readers sample), never the main pass's depth; without a depth
    // prepass they test the main depth only.
    let depth_stencil_attachment = match &prepass_textures.depth {
        Some(depth) => RenderPassDepthStencilAttachment {
            view: &depth.texture.default_view,
            depth_ops: Some(Operations {
                load: LoadOp::Load,
                store: StoreOp::Store,
            }),
            stencil_ops: None,
        },
        None => view_depth.get_attachment(StoreOp::Store),
    };
    let color_attachments = [
        prepass_textures.normal.as_ref().map(|normal| normal.get_attachment()),
        Some(motion_vectors.get_attachment()),
    ];
    let diagnostics = ctx.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let mut pass = ctx.begin_tracked_render_pass(RenderPassDescriptor {
        label: Some("conifer motion vectors"),
        color_attachments: &color_attachments,
        depth_stencil_attachment: Some(depth_stencil_attachment),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    let span = diagnostics.pass_span(&mut pass, "conifer_motion_vectors");
    for &(species, kind, pipeline_id) in list {
        let (Some(pipeline), Some(buffers)) = (
            pipeline_cache.get_render_pipeline(pipeline_id),
            compact_views.views.get(&(view_entity, species)),
        ) else {
            continue;
        };
        let Some(groups) = &buffers.groups else { continue };
        pass.set_render_pipeline(pipeline);
        pass.set_bind_group(0, view_group, &[view_offset.offset, previous_offset.offset]);
        pass.set_bind_group(1, &prepass_view_bind_group.empty_bind_group, &[]);
        pass.set_bind_group(2, &groups.draw, &[]);
        draw_indirect_part(&mut pass, buffers, kind, compact_pipeline.split_multi_draws);
    }
    span.end(&mut pass);
}

/// Culls every tree of every species for every view and writes the
/// indirect draws (`conifer_cull.wgsl`).
fn cull_trees(
    mut render_context: RenderContext,
    pipeline: Res<CompactPipeline>,
    pipeline_cache: Res<PipelineCache>,
    compact_views: Res<CompactViews>,
    device: Res<RenderDevice>,
    mut readbacks: ResMut<readback::PendingReadbacks>,
) {
    let [
        Some(budget_demand),
        Some(budget_cutoff),
        Some(cull),
        Some(prepare_dispatch),
        Some(count),
        Some(scan),
        Some(scatter),
    ] = pipeline
        .cull_pipelines
        .map(|id| pipeline_cache.get_compute_pipeline(id))
    else {
        return;
    };
    if compact_views.views.is_empty() {
        return;
    }
    // GPU time of the pass where Bevy's `RenderDiagnosticsPlugin` runs.
    let diagnostics = render_context.diagnostic_recorder();
    let diagnostics = diagnostics.as_deref();
    let encoder = render_context.command_encoder();
    for view in compact_views.views.values() {
        if view.placed.entry_capacity > 0 {
            encoder.clear_buffer(&view.placed.counters, 0, None);
            // Ranks past the entries written draw nothing.
            if view.placed.depth_ordered {
                encoder.clear_buffer(&view.placed.ordered, 0, None);
            }
        }
    }
    let mut pass = encoder.begin_compute_pass(&ComputePassDescriptor {
        label: Some("conifer compact cull"),
        timestamp_writes: None,
    });
    let span = diagnostics.pass_span(&mut pass, "conifer_cull");
    for view in compact_views.views.values() {
        let Some(groups) = &view.groups else { continue };
        pass.set_bind_group(0, &groups.cull, &[]);
        pass.set_bind_group(1, &groups.placed[0], &[]);
        if view.placed.entry_capacity > 0 {
            // The expansion budget goes to the nearest trees: their demand
            // by bucket, then where the budget runs out.
            pass.set_pipeline(budget_demand);
            pass.dispatch_workgroups(view.instance_count.div_ceil(64), 1, 1);
            pass.set_pipeline(budget_cutoff);
            pass.dispatch_workgroups(1, 1, 1);
        }
        pass.set_pipeline(cull);
        pass.dispatch_workgroups(view.instance_count.div_ceil(64), 1, 1);
        if view.placed.entry_capacity == 0 {
            continue;
        }
        // Expanded placements: counted into draws, offsets, sorted.
        pass.set_pipeline(prepare_dispatch);
        pass.set_bind_group(2, &groups.placed[1], &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(count);
        pass.dispatch_workgroups_indirect(&view.placed.dispatch, 0);
        pass.set_pipeline(scan);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(scatter);
        pass.dispatch_workgroups_indirect(&view.placed.dispatch, 0);
    }
    span.end(&mut pass);
    drop(pass);
    readback::stage(encoder, &device, &compact_views, &mut readbacks);
}

/// Binds a species' compact arrays and the view's culling results and draws
/// one part of every tree with one multi-draw-indirect (in the main pass
/// and in shadow passes alike).
pub struct DrawCompactPart;

impl<P: PhaseItem> RenderCommand<P> for DrawCompactPart {
    type Param = (SRes<CompactViews>, SRes<CompactPipeline>);
    type ViewQuery = Entity;
    type ItemQuery = Read<CompactDrawItem>;

    fn render<'w>(
        _item: &P,
        view: ROQueryItem<'w, '_, Self::ViewQuery>,
        item: Option<ROQueryItem<'w, '_, Self::ItemQuery>>,
        (compact_views, pipeline): SystemParamItem<'w, '_, Self::Param>,
        pass: &mut TrackedRenderPass<'w>,
    ) -> RenderCommandResult {
        let Some(item) = item else {
            return RenderCommandResult::Skip;
        };
        let Some(buffers) = compact_views.into_inner().views.get(&(view, item.species)) else {
            return RenderCommandResult::Skip;
        };
        let Some(groups) = &buffers.groups else {
            return RenderCommandResult::Skip;
        };
        pass.set_bind_group(2, &groups.draw, &[]);
        if draw_indirect_part(pass, buffers, item.kind, pipeline.split_multi_draws) {
            RenderCommandResult::Success
        } else {
            RenderCommandResult::Skip
        }
    }
}

/// Issues the indirect draws of one part of a view's trees, the bind
/// groups set: one draw per tree for the tree's parts, one instanced draw
/// per prototype and band for the placed ones, and for a camera's placed
/// lines one draw per expanded placement, back to front, its merged and
/// original lines together (the original lines' part; `split`: one
/// indirect draw each instead of one multi-draw). False when the view has
/// no placed draws for a placed part.
fn draw_indirect_part<'a>(
    pass: &mut TrackedRenderPass<'a>,
    buffers: &'a ViewSpecies,
    kind: PartKind,
    split: bool,
) -> bool {
    let placed = &buffers.placed;
    let (args, draws, block) = match kind.placed_index() {
        None => (&buffers.args, buffers.instance_count, kind.index()),
        Some(_) if placed.entry_capacity == 0 => return false,
        // The original lines' draws hold the merged lines too.
        Some(_) if placed.depth_ordered && kind == PartKind::PlacedMergedLines => return false,
        Some(_) if placed.depth_ordered && kind == PartKind::PlacedOriginalLines => {
            (&placed.ordered, (placed.ordered.size() / DRAW_ARGS_BYTES) as u32, 0)
        }
        Some(block) => (&placed.args, placed.draws, block),
    };
    let offset = block as u64 * u64::from(draws) * DRAW_ARGS_BYTES;
    if split {
        for i in 0..u64::from(draws) {
            pass.draw_indirect(args, offset + i * DRAW_ARGS_BYTES);
        }
    } else {
        pass.multi_draw_indirect(args, offset, draws);
    }
    true
}

/// The draw function of every compact part in shadow maps.
pub type DrawCompactShadow = (
    SetItemPipeline,
    SetPrepassViewBindGroup<0>,
    SetPrepassViewEmptyBindGroup<1>,
    DrawCompactPart,
);

/// The draw function of every compact part.
pub type DrawCompact = (
    SetItemPipeline,
    SetMeshViewBindGroup<0>,
    SetMeshViewBindingArrayBindGroup<1>,
    DrawCompactPart,
);

fn shader_path(file: &str) -> bevy::asset::AssetPath<'static> {
    let path = embedded_path!("conifer_compact.wgsl").with_file_name(file);
    bevy::asset::AssetPath::from_path_buf(path).with_source("embedded")
}

/// The shared WGSL types, kept loaded so the shaders can import them.
#[derive(Resource)]
struct CompactShaderLibrary(#[allow(dead_code)] Handle<Shader>);

/// Copies the render world's [`CompactGpuMemory`] to the main world each
/// frame, where the bench and tests read it.
fn publish_memory(memory: Res<CompactGpuMemory>, mut main_world: ResMut<bevy::render::MainWorld>) {
    if let Some(mut target) = main_world.get_resource_mut::<CompactGpuMemory>() {
        target.clone_from(&memory);
    }
}

/// Adds the compact path: shaders, main-world tracking, and the render
/// world's extraction, preparation, queueing, culling and draw.
pub(super) fn build(app: &mut App) {
    embedded_asset!(app, "compact_types.wgsl");
    embedded_asset!(app, "conifer_cull.wgsl");
    embedded_asset!(app, "conifer_compact.wgsl");
    let library = app
        .world()
        .resource::<AssetServer>()
        .load(shader_path("compact_types.wgsl"));
    app.insert_resource(CompactShaderLibrary(library));
    app.init_resource::<CompactGpuMemory>();
    app.init_resource::<CompactReadback>();
    let Some(render_app) = app.get_sub_app_mut(RenderApp) else {
        return;
    };
    render_app
        .init_resource::<RenderCompactSpecies>()
        .init_resource::<CompactViews>()
        .init_resource::<CompactGpuMemory>()
        .init_resource::<readback::PendingReadbacks>()
        .init_resource::<CompactMotionDraws>()
        .init_resource::<SpecializedRenderPipelines<CompactPipeline>>()
        .add_render_command::<Opaque3d, DrawCompact>()
        .add_render_command::<Transparent3d, DrawCompact>()
        .add_render_command::<Shadow, DrawCompactShadow>()
        .add_systems(
            RenderStartup,
            init_compact_pipeline
                .after(MeshPipelineSystems)
                .after(bevy::pbr::init_prepass_pipeline),
        )
        .add_systems(
            ExtractSchedule,
            (
                extract_compact,
                publish_memory,
                readback::extract_request,
                readback::publish,
            ),
        )
        .add_systems(
            Render,
            (
                (prepare_species, prepare_views)
                    .chain()
                    .in_set(RenderSystems::PrepareResources),
                (queue_compact, queue_compact_motion_vectors, queue_compact_shadows)
                    .chain()
                    .in_set(RenderSystems::QueueMeshes),
                readback::collect.in_set(RenderSystems::Cleanup),
            ),
        )
        // In the render set, so its pass is timed with the frame's (Bevy's
        // `RenderDiagnosticsPlugin` begins a frame's spans before it).
        .add_systems(
            bevy::render::renderer::RenderGraph,
            cull_trees
                .in_set(bevy::render::renderer::RenderGraphSystems::Render)
                .before(camera_driver),
        )
        .add_systems(
            Core3d,
            draw_motion_vectors
                .after(bevy::core_pipeline::prepass::node::late_prepass)
                .in_set(Core3dSystems::Prepass),
        );
}
