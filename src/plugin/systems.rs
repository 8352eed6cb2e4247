//! The plugin's systems: spawning a tree's mesh parts, keeping materials in
//! sync with the settings, and the per-instance LOD state.

use super::material::{ConiferLodExtension, ConiferLodUniform, ConiferMaterial};
use super::{
    ConiferFoliage, ConiferLodOverride, ConiferLodSettings, ConiferLodState, ConiferPart, ConiferParts, ConiferSpecies,
    LineOpacity,
};
use bevy::pbr::ExtendedMaterial;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;

/// Materials are shared by every tree of a species with the same override.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct MaterialKey {
    species: AssetId<ConiferSpecies>,
    pixel_error_bits: Option<u32>,
    transition_bits: Option<u32>,
}

impl MaterialKey {
    fn new(species: AssetId<ConiferSpecies>, over: Option<&ConiferLodOverride>) -> Self {
        Self {
            species,
            pixel_error_bits: over.and_then(|o| o.pixel_error).map(f32::to_bits),
            transition_bits: over.and_then(|o| o.transition).map(f32::to_bits),
        }
    }

    fn settings(&self, global: &ConiferLodSettings) -> ConiferLodSettings {
        ConiferLodSettings {
            pixel_error: self.pixel_error_bits.map_or(global.pixel_error, f32::from_bits),
            transition: self.transition_bits.map_or(global.transition, f32::from_bits),
            ..*global
        }
    }
}

/// The materials of one species (and override).
#[derive(Clone, Debug)]
struct MaterialSet {
    prisms: Handle<ConiferMaterial>,
    lines: Handle<ConiferMaterial>,
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
        padding_a: 0,
        padding_b: 0,
    }
}

fn make_materials(
    species: &ConiferSpecies,
    settings: &ConiferLodSettings,
    conifer_materials: &mut Assets<ConiferMaterial>,
    standard_materials: &mut Assets<StandardMaterial>,
) -> MaterialSet {
    let m = &species.record.material;
    let needle_color = Color::linear_rgba(
        m.needle_color[0],
        m.needle_color[1],
        m.needle_color[2],
        m.needle_color[3],
    );
    let base = StandardMaterial {
        base_color: needle_color,
        perceptual_roughness: m.roughness,
        reflectance: m.reflectance,
        ..default()
    };
    let extension = ConiferLodExtension {
        lod: lod_uniform(species, settings),
        needles: species.needles.clone(),
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
        extension,
    });
    let wood = standard_materials.add(StandardMaterial {
        base_color: Color::linear_rgba(m.wood_color[0], m.wood_color[1], m.wood_color[2], m.wood_color[3]),
        perceptual_roughness: 0.9,
        ..default()
    });
    MaterialSet { prisms, lines, wood }
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
        ),
        Or<(
            Without<ConiferParts>,
            Changed<ConiferFoliage>,
            Changed<ConiferLodOverride>,
        )>,
    >,
    species_assets: Res<Assets<ConiferSpecies>>,
    settings: Res<ConiferLodSettings>,
    mut materials: ResMut<SpeciesMaterials>,
    mut conifer_materials: Option<ResMut<Assets<ConiferMaterial>>>,
    mut standard_materials: Option<ResMut<Assets<StandardMaterial>>>,
) {
    for (entity, foliage, over, parts) in &trees {
        let Some(species) = species_assets.get(&foliage.0) else {
            continue;
        };
        if let Some(parts) = parts {
            for part in [parts.prisms, parts.lines, parts.wood] {
                commands.entity(part).try_despawn();
            }
        }
        let key = MaterialKey::new(foliage.0.id(), over);
        let set = match (&mut conifer_materials, &mut standard_materials) {
            (Some(conifer), Some(standard)) => Some(
                materials
                    .sets
                    .entry(key)
                    .or_insert_with(|| make_materials(species, &key.settings(&settings), conifer, standard))
                    .clone(),
            ),
            _ => None,
        };
        let aabb = species.aabb;
        let mut spawn = |mesh: &Handle<Mesh>, part: ConiferPart| {
            let mut child = commands.spawn((
                Mesh3d(mesh.clone()),
                Transform::IDENTITY,
                Visibility::Inherited,
                aabb,
                part,
                ChildOf(entity),
            ));
            if let Some(set) = &set {
                match part {
                    ConiferPart::Prisms => child.insert(MeshMaterial3d(set.prisms.clone())),
                    ConiferPart::Lines => child.insert(MeshMaterial3d(set.lines.clone())),
                    ConiferPart::Wood => child.insert(MeshMaterial3d(set.wood.clone())),
                };
            }
            child.id()
        };
        let parts = ConiferParts {
            prisms: spawn(&species.prisms, ConiferPart::Prisms),
            lines: spawn(&species.lines, ConiferPart::Lines),
            wood: spawn(&species.wood, ConiferPart::Wood),
        };
        commands.entity(entity).insert(parts);
    }
}

/// Writes the settings into every material when they change (a material
/// asset edit, never a mesh edit).
pub(super) fn sync_materials(
    settings: Res<ConiferLodSettings>,
    materials: Res<SpeciesMaterials>,
    species_assets: Res<Assets<ConiferSpecies>>,
    conifer_materials: Option<ResMut<Assets<ConiferMaterial>>>,
) {
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
        let uniform = lod_uniform(species, &key.settings(&settings));
        for handle in [&set.prisms, &set.lines] {
            if let Some(mut material) = conifer_materials.get_mut(handle)
                && material.extension.lod != uniform
            {
                material.extension.lod = uniform;
            }
        }
    }
}

/// Drops the materials of species that were unloaded.
pub(super) fn release_unused_materials(
    mut events: MessageReader<AssetEvent<ConiferSpecies>>,
    mut materials: ResMut<SpeciesMaterials>,
) {
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

/// Computes every tree's [`ConiferLodState`] over the active cameras and
/// hides the parts that cannot draw anything at its errors.
#[allow(clippy::type_complexity)] // a Bevy query
pub(super) fn select_lod(
    cameras: Query<(&Camera, &GlobalTransform, &Projection)>,
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
) {
    let views: Vec<ViewLod> = cameras
        .iter()
        .filter(|(camera, _, _)| camera.is_active)
        .filter_map(|(camera, transform, projection)| {
            let height = camera.physical_viewport_size()?.y as f32;
            // The projection the camera system hands to the renderer (a
            // sub-camera view only crops it, which keeps P₁₁ per pixel).
            let (slope, perspective) = view_error_slope(&projection.get_clip_from_view(), height)?;
            Some(ViewLod {
                position: transform.translation(),
                slope,
                perspective,
            })
        })
        .collect();
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
        let new_state = ConiferLodState {
            min_spatial_error: min_e,
            max_spatial_error: if any_view { max_e } else { f32::INFINITY },
            views: views.len() as u32,
            prisms_visible: any_view && min_e < species.max_line_error,
            lines_visible: any_view && settings.enabled && max_e >= species.min_line_error,
        };
        let parts_changed = state.prisms_visible != new_state.prisms_visible
            || state.lines_visible != new_state.lines_visible
            || (state.views == 0) != (new_state.views == 0);
        state.set_if_neq(new_state);
        // Parts are touched only when what they show changes (and once
        // when they appear).
        let Some(tree_parts) = tree_parts else { continue };
        if parts_changed || tree_parts.is_changed() {
            for (part, shown) in [
                (tree_parts.prisms, new_state.prisms_visible),
                (tree_parts.lines, new_state.lines_visible),
            ] {
                if let Ok(mut visibility) = parts.get_mut(part) {
                    let wanted = if shown || !any_view {
                        Visibility::Inherited
                    } else {
                        Visibility::Hidden
                    };
                    visibility.set_if_neq(wanted);
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
            lines_visible: false,
        }
    }
}
