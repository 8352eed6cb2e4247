//! The plugin's main-world systems: the per-tree LOD state the debug
//! overlay reads, and the CPU time they take.

use super::{ConiferFoliage, ConiferLodOverride, ConiferLodSettings, ConiferLodState, ConiferSpecies};
use bevy::light::Cascades;
use bevy::prelude::*;

/// Wall time of the plugin's own systems (both sets), measured inside them.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Reflect)]
#[reflect(Resource, Default, Debug, Clone)]
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
/// spatial error is its texel size (`ε · texel`); the GPU gives it its own
/// cut, and the state reports what it may draw.
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
/// the shadow views (the directional lights' cascades, the point and spot
/// lights' shadow maps) while the debug overlay or its stats read it.
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
    )>,
    species_assets: Res<Assets<ConiferSpecies>>,
    settings: Res<ConiferLodSettings>,
    debug: Option<Res<super::ConiferLodDebug>>,
    mut cpu_time: ResMut<ConiferLodCpuTime>,
) {
    // The first of the plugin's systems in a frame.
    cpu_time.accumulating = std::time::Duration::ZERO;
    let _timer = CpuTimer::start(&mut cpu_time, false);
    // The GPU chooses alone: the CPU state is for the debug overlay and its
    // stats only.
    if !debug.is_some_and(|d| d.enabled || d.always_collect_stats) {
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
    for (foliage, transform, over, mut state) in &mut trees {
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
        // texel's, the shader's orthographic case, times the settings'
        // shadow error scale), so that a tree casts its shadow at the
        // cascade's detail even where the camera sees it coarser.
        let (mut part_min_e, mut part_max_e) = (min_e, max_e);
        if any_view && settings.enabled {
            let shadow_factor = settings.shadow_error_factor();
            for shadow in &shadows {
                let ndc = shadow.clip_from_world.project_point3(center);
                if ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0 {
                    let e = pixel_error * shadow_factor * shadow.texel_size / scale;
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
                    let e = pixel_error * shadow_factor * center.distance(light.position) * light.slope / scale;
                    part_min_e = part_min_e.min(e);
                    part_max_e = part_max_e.max(e);
                }
            }
        }
        state.set_if_neq(ConiferLodState {
            min_spatial_error: min_e,
            max_spatial_error: if any_view { max_e } else { f32::INFINITY },
            views: views.len() as u32,
            prisms_visible: any_view && part_min_e < species.max_line_error,
            wood_prisms_visible: any_view && part_min_e < species.max_wood_error,
            lines_visible: any_view && settings.enabled && part_max_e >= species.min_line_error,
        });
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
        }
    }
}
