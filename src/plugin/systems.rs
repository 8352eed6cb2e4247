//! The plugin's systems: spawning a tree's mesh parts, keeping materials in
//! sync with the settings, and the per-instance LOD state.

use super::material::{ConiferLodExtension, ConiferLodUniform, ConiferMaterial};
use super::{
    ConiferFoliage, ConiferLodOverride, ConiferLodSettings, ConiferLodState, ConiferPart, ConiferParts, ConiferSpecies,
    LineOpacity, RenderPath, SpeciesMeshHandles, SpeciesMeshes,
};
use bevy::camera::visibility::RenderLayers;
use bevy::light::Cascades;
use bevy::pbr::ExtendedMaterial;
use bevy::platform::collections::{HashMap, HashSet};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;

/// Wall time of the plugin's own systems (both sets), measured inside them.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct ConiferLodCpuTime {
    /// The plugin's systems' time in the last complete frame.
    pub last_frame: std::time::Duration,
    accumulating: std::time::Duration,
}

/// Adds the time until it is dropped to [`ConiferLodCpuTime`]; the last
/// system of the frame publishes the sum.
pub(super) struct CpuTimer<'a> {
    time: &'a mut ConiferLodCpuTime,
    started: std::time::Instant,
    publish: bool,
}

impl<'a> CpuTimer<'a> {
    pub(super) fn start(time: &'a mut ConiferLodCpuTime, publish: bool) -> Self {
        Self {
            time,
            started: std::time::Instant::now(),
            publish,
        }
    }
}

impl Drop for CpuTimer<'_> {
    fn drop(&mut self) {
        self.time.accumulating += self.started.elapsed();
        if self.publish {
            self.time.last_frame = self.time.accumulating;
        }
    }
}

/// Materials are shared by every tree of a species with the same override.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct MaterialKey {
    species: AssetId<ConiferSpecies>,
    pixel_error_bits: Option<u32>,
    transition_bits: Option<u32>,
    line_opacity: Option<LineOpacity>,
}

impl MaterialKey {
    fn new(species: AssetId<ConiferSpecies>, over: Option<&ConiferLodOverride>) -> Self {
        Self {
            species,
            pixel_error_bits: over.and_then(|o| o.pixel_error).map(f32::to_bits),
            transition_bits: over.and_then(|o| o.transition).map(f32::to_bits),
            line_opacity: over.and_then(|o| o.line_opacity),
        }
    }

    fn settings(&self, global: &ConiferLodSettings) -> ConiferLodSettings {
        ConiferLodSettings {
            pixel_error: self.pixel_error_bits.map_or(global.pixel_error, f32::from_bits),
            transition: self.transition_bits.map_or(global.transition, f32::from_bits),
            line_opacity: self.line_opacity.unwrap_or(global.line_opacity),
            ..*global
        }
    }
}

/// The materials of one species (and override).
#[derive(Clone, Debug)]
struct MaterialSet {
    prisms: Handle<ConiferMaterial>,
    lines: Handle<ConiferMaterial>,
    wood_prisms: Handle<ConiferMaterial>,
    wood: Handle<StandardMaterial>,
}

/// The materials the plugin made, one set per species and override; a set
/// is dropped when its species is unloaded.
#[derive(Resource, Default, Debug)]
pub struct SpeciesMaterials {
    sets: HashMap<MaterialKey, MaterialSet>,
}

impl SpeciesMaterials {
    /// Number of material sets alive.
    pub fn len(&self) -> usize {
        self.sets.len()
    }

    /// `true` when no material set is alive.
    pub fn is_empty(&self) -> bool {
        self.sets.is_empty()
    }
}

fn lod_uniform(species: &ConiferSpecies, settings: &ConiferLodSettings) -> ConiferLodUniform {
    ConiferLodUniform {
        center: species.crown_center.extend(1.0),
        pixel_error: settings.pixel_error.max(0.0),
        transition: settings.transition.clamp(0.0, 1.0),
        max_sides: species.record.max_sides as u32,
        opacity_rule: match settings.line_opacity {
            LineOpacity::Paper => 0,
            LineOpacity::AreaPreserving => 1,
        },
        lod_enabled: settings.enabled as u32,
        debug_colors: settings.debug_colors as u32,
        max_merge_depth: species.max_merge_depth,
        wood_tint: wood_tint(&species.record.material),
        padding_b: 0,
    }
}

/// Wood colour over needle colour: the line material's base colour is the
/// needles', and a wood line's vertex colour scales it to the wood's.
fn wood_tint(material: &crate::model::FoliageMaterial) -> Vec4 {
    let [nr, ng, nb, _] = material.needle_color;
    let [wr, wg, wb, _] = material.wood_color;
    Vec4::new(wr / nr.max(1e-3), wg / ng.max(1e-3), wb / nb.max(1e-3), 1.0)
}

/// Base colours of the needles and the wood; white under debug colours,
/// which the shader's vertex colour would otherwise be multiplied by.
fn base_colors(material: &crate::model::FoliageMaterial, debug_colors: bool) -> [Color; 2] {
    [material.needle_color, material.wood_color].map(|[r, g, b, a]| {
        if debug_colors {
            Color::WHITE
        } else {
            Color::linear_rgba(r, g, b, a)
        }
    })
}

fn make_materials(
    species: &ConiferSpecies,
    species_meshes: &SpeciesMeshHandles,
    settings: &ConiferLodSettings,
    conifer_materials: &mut Assets<ConiferMaterial>,
    standard_materials: &mut Assets<StandardMaterial>,
) -> MaterialSet {
    let m = &species.record.material;
    let [needle_color, wood_color] = base_colors(m, settings.debug_colors);
    let base = StandardMaterial {
        base_color: needle_color,
        perceptual_roughness: m.roughness,
        reflectance: m.reflectance,
        ..default()
    };
    let extension = ConiferLodExtension {
        lod: lod_uniform(species, settings),
        needles: species_meshes.needles.clone(),
    };
    let prisms = conifer_materials.add(ExtendedMaterial {
        base: base.clone(),
        extension: extension.clone(),
    });
    let lines = conifer_materials.add(ExtendedMaterial {
        base: StandardMaterial {
            alpha_mode: AlphaMode::Blend,
            cull_mode: None,
            ..base
        },
        extension: extension.clone(),
    });
    let wood_base = StandardMaterial {
        base_color: wood_color,
        perceptual_roughness: 0.9,
        ..default()
    };
    let wood_prisms = conifer_materials.add(ExtendedMaterial {
        base: wood_base.clone(),
        extension: ConiferLodExtension {
            needles: species_meshes.wood_segments.clone(),
            ..extension
        },
    });
    let wood = standard_materials.add(wood_base);
    MaterialSet {
        prisms,
        lines,
        wood_prisms,
        wood,
    }
}

/// Spawns the prism, line and wood parts of trees whose species has loaded
/// (again when the species handle or the override changes).
#[allow(clippy::too_many_arguments, clippy::type_complexity)] // a Bevy system's parameters
pub(super) fn spawn_parts(
    mut commands: Commands,
    trees: Query<
        (
            Entity,
            &ConiferFoliage,
            Option<&ConiferLodOverride>,
            Option<&ConiferParts>,
            Option<&RenderLayers>,
        ),
        Or<(
            Without<ConiferParts>,
            Changed<ConiferFoliage>,
            Changed<ConiferLodOverride>,
        )>,
    >,
    with_parts: Query<(Entity, &ConiferParts)>,
    mut species_assets: ResMut<Assets<ConiferSpecies>>,
    settings: Res<ConiferLodSettings>,
    mut materials: ResMut<SpeciesMaterials>,
    mut mesh_assets: Option<ResMut<Assets<Mesh>>>,
    mut buffer_assets: Option<ResMut<Assets<ShaderBuffer>>>,
    mut unbuildable: Local<HashSet<AssetId<ConiferSpecies>>>,
    mut conifer_materials: Option<ResMut<Assets<ConiferMaterial>>>,
    mut standard_materials: Option<ResMut<Assets<StandardMaterial>>>,
    mut cpu_time: ResMut<ConiferLodCpuTime>,
) {
    let _timer = CpuTimer::start(&mut cpu_time, false);
    if settings.render_path == RenderPath::Compact {
        // The compact path spawns nothing per tree; take away what the mesh
        // path spawned.
        for (entity, parts) in &with_parts {
            for part in parts.entities() {
                commands.entity(part).try_despawn();
            }
            commands.entity(entity).remove::<ConiferParts>();
        }
        return;
    }
    for (entity, foliage, over, parts, layers) in &trees {
        let id = foliage.0.id();
        let unbuilt = species_assets
            .get(id)
            .filter(|s| s.meshes.is_none() && !unbuildable.contains(&id));
        if let Some(species) = unbuilt {
            // The species' first tree on the mesh path: its meshes now.
            let (Some(meshes), Some(buffers)) = (mesh_assets.as_deref_mut(), buffer_assets.as_deref_mut()) else {
                continue;
            };
            match SpeciesMeshes::build(&species.record) {
                Ok(parts) => {
                    let handles = parts.into_handles(meshes, buffers);
                    if let Some(mut species) = species_assets.get_mut(id) {
                        species.meshes = Some(handles);
                    }
                }
                Err(error) => {
                    warn!("a species cannot be drawn by the mesh path: {error}");
                    unbuildable.insert(id);
                }
            }
        }
        let Some(species) = species_assets.get(&foliage.0) else {
            continue;
        };
        let Some(species_meshes) = species.meshes.as_ref() else {
            continue;
        };
        for part in parts.iter().flat_map(|parts| parts.entities()) {
            commands.entity(part).try_despawn();
        }
        let key = MaterialKey::new(foliage.0.id(), over);
        let set = match (&mut conifer_materials, &mut standard_materials) {
            (Some(conifer), Some(standard)) => Some(
                materials
                    .sets
                    .entry(key)
                    .or_insert_with(|| {
                        make_materials(species, species_meshes, &key.settings(&settings), conifer, standard)
                    })
                    .clone(),
            ),
            _ => None,
        };
        let aabb = species.aabb;
        let mut spawn = |mesh: &Handle<Mesh>, part: ConiferPart| {
            let mut child = commands.spawn((
                Mesh3d(mesh.clone()),
                Transform::IDENTITY,
                // Hidden until select_lod has seen a view.
                if matches!(part, ConiferPart::Wood) {
                    Visibility::Inherited
                } else {
                    Visibility::Hidden
                },
                aabb,
                part,
                ChildOf(entity),
            ));
            if let Some(layers) = layers {
                child.insert(layers.clone());
            }
            if let Some(set) = &set {
                match part {
                    ConiferPart::Prisms => child.insert(MeshMaterial3d(set.prisms.clone())),
                    ConiferPart::Lines => child.insert(MeshMaterial3d(set.lines.clone())),
                    ConiferPart::WoodPrisms => child.insert(MeshMaterial3d(set.wood_prisms.clone())),
                    ConiferPart::Wood => child.insert(MeshMaterial3d(set.wood.clone())),
                };
            }
            child.id()
        };
        let parts = ConiferParts {
            prisms: spawn(&species_meshes.prisms, ConiferPart::Prisms),
            lines: species_meshes
                .lines
                .iter()
                .map(|band| spawn(&band.mesh, ConiferPart::Lines))
                .collect(),
            wood_prisms: species_meshes
                .wood_prisms
                .as_ref()
                .map(|mesh| spawn(mesh, ConiferPart::WoodPrisms)),
            wood: species_meshes.wood.as_ref().map(|mesh| spawn(mesh, ConiferPart::Wood)),
        };
        commands.entity(entity).insert(parts);
    }
}

/// Writes the settings into every material when they change (a small
/// uniform edit, never a mesh edit). Never per frame: an edited material
/// makes Bevy re-specialize every entity that uses it.
pub(super) fn sync_materials(
    settings: Res<ConiferLodSettings>,
    materials: Res<SpeciesMaterials>,
    species_assets: Res<Assets<ConiferSpecies>>,
    conifer_materials: Option<ResMut<Assets<ConiferMaterial>>>,
    mut cpu_time: ResMut<ConiferLodCpuTime>,
) {
    let _timer = CpuTimer::start(&mut cpu_time, false);
    let Some(mut conifer_materials) = conifer_materials else {
        return;
    };
    if !settings.is_changed() {
        return;
    }
    for (key, set) in &materials.sets {
        let Some(species) = species_assets.get(key.species) else {
            continue;
        };
        let settings = key.settings(&settings);
        let uniform = lod_uniform(species, &settings);
        let [needle, wood] = base_colors(&species.record.material, settings.debug_colors);
        for (handle, base_color) in [(&set.prisms, needle), (&set.lines, needle), (&set.wood_prisms, wood)] {
            // Compare before taking the asset mutably: an unchanged material
            // is not re-uploaded.
            if conifer_materials
                .get(handle)
                .is_some_and(|m| m.extension.lod != uniform || m.base.base_color != base_color)
                && let Some(mut material) = conifer_materials.get_mut(handle)
            {
                material.extension.lod = uniform;
                material.base.base_color = base_color;
            }
        }
    }
}

fn view_lod(camera: &Camera, transform: &GlobalTransform, projection: &Projection) -> Option<ViewLod> {
    let height = camera.physical_viewport_size()?.y as f32;
    // The projection the camera system hands to the renderer (a sub-camera
    // view only crops it, which keeps P₁₁ per pixel).
    let (slope, perspective) = view_error_slope(&projection.get_clip_from_view(), height)?;
    Some(ViewLod {
        position: transform.translation(),
        slope,
        perspective,
    })
}

/// Drops the materials of species that were unloaded.
pub(super) fn release_unused_materials(
    mut events: MessageReader<AssetEvent<ConiferSpecies>>,
    mut materials: ResMut<SpeciesMaterials>,
    mut cpu_time: ResMut<ConiferLodCpuTime>,
) {
    cpu_time.accumulating = std::time::Duration::ZERO;
    let _timer = CpuTimer::start(&mut cpu_time, false);
    for event in events.read() {
        if let AssetEvent::Removed { id } | AssetEvent::Unused { id } = event {
            materials.sets.retain(|key, _| key.species != *id);
        }
    }
}

/// Spatial error per unit of distance of a view (`2 / (P₁₁ · H)`, the paper's
/// `2·tan(θ/2)/W`), and whether it is a perspective view (the error grows
/// with distance) or orthographic (the same everywhere). `None` for a view
/// without height or a degenerate projection.
pub fn view_error_slope(clip_from_view: &Mat4, viewport_height_px: f32) -> Option<(f32, bool)> {
    let p11 = clip_from_view.y_axis.y;
    if !(viewport_height_px >= 1.0 && p11.is_finite() && p11 > 0.0) {
        return None;
    }
    let perspective = clip_from_view.w_axis.w != 1.0;
    Some((2.0 / (p11 * viewport_height_px), perspective))
}

/// One camera's contribution to the LOD.
struct ViewLod {
    position: Vec3,
    slope: f32,
    perspective: bool,
}

/// One directional-light shadow cascade: an orthographic view whose
/// spatial error is its texel size (`ε · texel`); the shader gives it its
/// own cut, so the CPU keeps the line bands it needs visible.
struct ShadowLod {
    clip_from_world: Mat4,
    texel_size: f32,
}

/// A point light's cube faces or a spot light's cone: a perspective
/// shadow view from `position` reaching `range`, whose spatial error per
/// metre of distance is `slope` (its texel at one metre).
struct LocalShadowLod {
    position: Vec3,
    range: f32,
    slope: f32,
}

/// The point and spot lights that cast shadows, and their shadow maps'
/// sizes (Bevy's defaults where the resources are missing).
#[derive(bevy::ecs::system::SystemParam)]
pub(super) struct LocalLights<'w, 's> {
    points: Query<'w, 's, (&'static PointLight, &'static GlobalTransform)>,
    spots: Query<'w, 's, (&'static SpotLight, &'static GlobalTransform)>,
    point_map: Option<Res<'w, bevy::light::PointLightShadowMap>>,
    directional_map: Option<Res<'w, bevy::light::DirectionalLightShadowMap>>,
}

impl LocalLights<'_, '_> {
    /// Every shadow-casting point and spot light as a view. A cube face is
    /// a 90° view of `PointLightShadowMap::size` texels (texel `2/size` at
    /// one metre); a spot light's map has `DirectionalLightShadowMap::size`
    /// texels over its cone (`2·tan(outer angle)/size`), as Bevy renders
    /// them.
    fn views(&self) -> Vec<LocalShadowLod> {
        let point_size = self
            .point_map
            .as_ref()
            .map_or(bevy::light::PointLightShadowMap::default().size, |m| m.size) as f32;
        let spot_size = self
            .directional_map
            .as_ref()
            .map_or(bevy::light::DirectionalLightShadowMap::default().size, |m| m.size) as f32;
        let points = self
            .points
            .iter()
            .filter(|(light, _)| light.shadow_maps_enabled)
            .map(|(light, transform)| LocalShadowLod {
                position: transform.translation(),
                range: light.range,
                slope: 2.0 / point_size.max(1.0),
            });
        let spots = self
            .spots
            .iter()
            .filter(|(light, _)| light.shadow_maps_enabled)
            .map(|(light, transform)| LocalShadowLod {
                position: transform.translation(),
                range: light.range,
                slope: 2.0 * light.outer_angle.clamp(0.0, 1.5).tan() / spot_size.max(1.0),
            });
        points
            .chain(spots)
            .filter(|view| view.position.is_finite() && view.range > 0.0 && view.slope > 0.0)
            .collect()
    }
}

/// Computes every tree's [`ConiferLodState`] over the active cameras and
/// hides the parts that cannot draw anything at its errors (for the cameras,
/// the directional lights' shadow cascades, and the point and spot lights'
/// shadow maps).
#[allow(clippy::type_complexity, clippy::too_many_arguments)] // a Bevy system
pub(super) fn select_lod(
    cameras: Query<(&Camera, &GlobalTransform, &Projection)>,
    lights: Query<(&DirectionalLight, &Cascades)>,
    local_lights: LocalLights,
    mut trees: Query<(
        &ConiferFoliage,
        &GlobalTransform,
        Option<&ConiferLodOverride>,
        &mut ConiferLodState,
        Option<Ref<ConiferParts>>,
    )>,
    mut parts: Query<&mut Visibility, With<ConiferPart>>,
    species_assets: Res<Assets<ConiferSpecies>>,
    settings: Res<ConiferLodSettings>,
    debug: Option<Res<super::ConiferLodDebug>>,
    mut cpu_time: ResMut<ConiferLodCpuTime>,
) {
    let _timer = CpuTimer::start(&mut cpu_time, true);
    // The compact path's GPU pass chooses alone: the CPU state is for the
    // debug overlay and its stats only.
    let overlay_reads_state = debug.is_some_and(|d| d.enabled || d.always_collect_stats);
    if settings.render_path == RenderPath::Compact && !overlay_reads_state {
        return;
    }
    let views: Vec<ViewLod> = cameras
        .iter()
        .filter(|(camera, _, _)| camera.is_active)
        .filter_map(|(camera, transform, projection)| view_lod(camera, transform, projection))
        .collect();
    let shadows: Vec<ShadowLod> = lights
        .iter()
        .filter(|(light, _)| light.shadow_maps_enabled)
        .flat_map(|(_, cascades)| cascades.cascades.values().flatten())
        .filter(|cascade| cascade.texel_size.is_finite() && cascade.texel_size > 0.0)
        .map(|cascade| ShadowLod {
            clip_from_world: cascade.clip_from_world,
            texel_size: cascade.texel_size,
        })
        .collect();
    let local_shadows = local_lights.views();
    for (foliage, transform, over, mut state, tree_parts) in &mut trees {
        let Some(species) = species_assets.get(&foliage.0) else {
            continue;
        };
        let pixel_error = over
            .and_then(|o| o.pixel_error)
            .unwrap_or(settings.pixel_error)
            .max(0.0);
        // Mean axis scale: the columns' lengths (cheaper than a decomposition).
        let m = transform.affine().matrix3;
        let scale = ((m.x_axis.length() + m.y_axis.length() + m.z_axis.length()) / 3.0).max(1e-6);
        let center = transform.transform_point(species.crown_center);
        let (mut min_e, mut max_e) = (f32::INFINITY, 0.0f32);
        for view in &views {
            let distance = if view.perspective {
                center.distance(view.position)
            } else {
                1.0
            };
            let e = if settings.enabled {
                pixel_error * distance * view.slope / scale
            } else {
                0.0
            };
            min_e = min_e.min(e);
            max_e = max_e.max(e);
        }
        let any_view = !views.is_empty();
        // The errors the parts must serve: the cameras', and those of the
        // shadow cascades covering the tree (a cascade's error is its
        // texel's, the shader's orthographic case), so that a tree casts its
        // shadow at the cascade's detail even where the camera sees it coarser.
        let (mut part_min_e, mut part_max_e) = (min_e, max_e);
        if any_view && settings.enabled {
            for shadow in &shadows {
                let ndc = shadow.clip_from_world.project_point3(center);
                if ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0 {
                    let e = pixel_error * shadow.texel_size / scale;
                    part_min_e = part_min_e.min(e);
                    part_max_e = part_max_e.max(e);
                }
            }
            // Point and spot lights whose range reaches the tree's box.
            let (box_center, radius) = if local_shadows.is_empty() {
                (Vec3::ZERO, 0.0)
            } else {
                (
                    transform.transform_point(Vec3::from(species.aabb.center)),
                    Vec3::from(species.aabb.half_extents).length() * scale,
                )
            };
            for light in &local_shadows {
                if box_center.distance(light.position) <= light.range + radius {
                    let e = pixel_error * center.distance(light.position) * light.slope / scale;
                    part_min_e = part_min_e.min(e);
                    part_max_e = part_max_e.max(e);
                }
            }
        }
        let mut line_bands = 0u32;
        if any_view && settings.enabled {
            for (k, band) in species.line_bands().iter().enumerate().take(32) {
                if band.errors.may_draw(part_min_e, part_max_e) {
                    line_bands |= 1 << k;
                }
            }
        }
        let new_state = ConiferLodState {
            min_spatial_error: min_e,
            max_spatial_error: if any_view { max_e } else { f32::INFINITY },
            views: views.len() as u32,
            prisms_visible: any_view && part_min_e < species.max_line_error,
            wood_prisms_visible: any_view && part_min_e < species.max_wood_error,
            lines_visible: line_bands != 0,
            line_bands,
        };
        let parts_changed = state.prisms_visible != new_state.prisms_visible
            || state.wood_prisms_visible != new_state.wood_prisms_visible
            || state.line_bands != new_state.line_bands;
        state.set_if_neq(new_state);
        // Parts are touched only when what they show changes (and once
        // when they appear).
        let Some(tree_parts) = tree_parts else { continue };
        if parts_changed || tree_parts.is_changed() {
            let bands = tree_parts
                .lines
                .iter()
                .enumerate()
                .map(|(k, &part)| (part, k < 32 && line_bands & (1 << k) != 0));
            let wood = tree_parts.wood_prisms.map(|part| (part, new_state.wood_prisms_visible));
            for (part, shown) in [(tree_parts.prisms, new_state.prisms_visible)]
                .into_iter()
                .chain(wood)
                .chain(bands)
            {
                if let Ok(mut visibility) = parts.get_mut(part) {
                    visibility.set_if_neq(if shown {
                        Visibility::Inherited
                    } else {
                        Visibility::Hidden
                    });
                }
            }
        }
    }
}

impl Default for ConiferLodState {
    /// No view yet: infinite errors, nothing visible.
    fn default() -> Self {
        Self {
            min_spatial_error: f32::INFINITY,
            max_spatial_error: f32::INFINITY,
            views: 0,
            prisms_visible: false,
            wood_prisms_visible: false,
            lines_visible: false,
            line_bands: 0,
        }
    }
}
