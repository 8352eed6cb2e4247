//! The LOD debug overlay: needles coloured by representation, per-tree
//! gizmos (bounding sphere and the distances where representations take
//! over), and a stats panel.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_conifer_lod::prelude::*;
//!
//! fn toggle(keys: Res<ButtonInput<KeyCode>>, mut debug: ResMut<ConiferLodDebug>) {
//!     if keys.just_pressed(KeyCode::F3) {
//!         debug.enabled = !debug.enabled;
//!     }
//! }
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, ConiferLodPlugin::default(), ConiferLodDebugPlugin::default()))
//!     .add_systems(Update, toggle)
//!     .run();
//! ```

use super::{
    ConiferFoliage, ConiferLodCpuTime, ConiferLodOverride, ConiferLodSet, ConiferLodSettings, ConiferLodState,
    ConiferSpecies, ConiferWind, LineOpacity, view_error_slope,
};
use crate::model::CutCounter;
use bevy::camera::visibility::VisibilitySystems;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;

/// Adds the debug overlay, driven by the [`ConiferLodDebug`] resource (off
/// by default), and keeps [`ConiferLodStats`] up to date while it is on.
/// Add it after [`super::ConiferLodPlugin`]; gizmos and the panel appear
/// only where Bevy's gizmo and UI plugins are present.
///
/// ```no_run
/// use bevy::prelude::*;
/// use bevy_conifer_lod::prelude::*;
///
/// // The overlay on from the first frame (F3 toggles it with `conifer_lod_keys`).
/// let overlay = ConiferLodDebugPlugin {
///     debug: ConiferLodDebug { enabled: true, ..default() },
/// };
/// App::new().add_plugins((DefaultPlugins, ConiferLodPlugin::default(), overlay));
/// ```
#[derive(Clone, Copy, Debug, Default)]
pub struct ConiferLodDebugPlugin {
    /// The first value of the [`ConiferLodDebug`] resource (a resource the
    /// app already has is kept).
    pub debug: ConiferLodDebug,
}

impl Plugin for ConiferLodDebugPlugin {
    fn build(&self, app: &mut App) {
        if !app.world().contains_resource::<ConiferLodDebug>() {
            app.insert_resource(self.debug);
        }
        app.init_resource::<ConiferLodStats>()
            .register_type::<ConiferLodDebug>()
            .register_type::<ConiferLodStats>()
            .init_resource::<SpeciesCounters>()
            .init_resource::<FrameRate>()
            .add_systems(
                PostUpdate,
                (
                    measure_frame_rate.after(ConiferLodSet::Select),
                    (sync_debug_colors, collect_stats, update_panel)
                        .chain()
                        .after(VisibilitySystems::CheckVisibility),
                ),
            );
        if app.is_plugin_added::<bevy::gizmos::GizmoPlugin>() {
            app.add_systems(PostUpdate, draw_gizmos.after(VisibilitySystems::CheckVisibility));
        }
    }
}

/// What the overlay shows; change it at any time.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Reflect)]
#[reflect(Resource, Default, Debug, Clone)]
pub struct ConiferLodDebug {
    /// Master switch: nothing below is shown while `false`.
    pub enabled: bool,
    /// Colour needles by representation: prisms blue → cyan by side count,
    /// original lines green, merged lines yellow → red by merge depth.
    pub colors: bool,
    /// Per-tree gizmos: bounding sphere and representation distances.
    pub gizmos: bool,
    /// The stats panel.
    pub panel: bool,
    /// Gizmos are drawn for at most this many trees, nearest the camera first.
    pub gizmo_trees: usize,
    /// Keep [`ConiferLodStats`] up to date even while the overlay is off
    /// (for a game's own display or logs).
    pub always_collect_stats: bool,
}

impl Default for ConiferLodDebug {
    fn default() -> Self {
        Self {
            enabled: false,
            colors: true,
            gizmos: true,
            panel: true,
            gizmo_trees: 12,
            always_collect_stats: false,
        }
    }
}

/// What the plugin drew last frame (kept while the overlay is enabled, or
/// always with [`ConiferLodDebug::always_collect_stats`]).
/// Counts are of the cut at each visible tree's finest view, computed
/// exactly by [`CutCounter`] (no traversal), at the tree's one error (the
/// paper's, from its distance to the crown's centre). Under
/// [`crate::plugin::ErrorScope::Placement`] a tree of shared prototypes
/// draws each placement at its own error: for a tree the camera is near or
/// inside, these counts are then an estimate (the drawn cut has more
/// prisms beside the camera and fewer lines across the crown; `conifer
/// eval --inside` counts both).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Reflect)]
#[reflect(Resource, Default, Debug, Clone)]
pub struct ConiferLodStats {
    /// Trees.
    pub instances: u64,
    /// Trees in some camera's view (not frustum-culled).
    pub visible_instances: u64,
    /// Needles drawn as prisms.
    pub prisms: u64,
    /// Original lines drawn.
    pub lines_original: u64,
    /// Merged lines drawn.
    pub lines_merged: u64,
    /// Triangles of the prisms.
    pub triangles: u64,
    /// Lines drawn (original and merged).
    pub lines: u64,
    /// Trees drawn as their crown impostor alone (one quad each, not in
    /// the counts above), as the first active perspective camera sees them.
    pub impostors: u64,
    /// Trees fading between their lines and their impostor (in both).
    pub fading: u64,
    /// The global pixel error ε.
    pub pixel_error: f32,
    /// Time of the plugin's systems last frame ([`ConiferLodCpuTime`]), milliseconds.
    pub plugin_cpu_ms: f32,
    /// Frames per second, smoothed.
    pub fps: f32,
}

#[derive(Resource, Default)]
struct SpeciesCounters(HashMap<AssetId<ConiferSpecies>, SpeciesDistances>);

/// A species' cut counter and the spatial errors where its representations
/// take over.
struct SpeciesDistances {
    counter: CutCounter,
    /// The last prism becomes a line (largest `2R`).
    prisms_end: f32,
    /// The first merged line appears (smallest merge error).
    merging_starts: f32,
    /// The cut is down to a tenth of the needle count.
    tenth: f32,
}

impl SpeciesDistances {
    fn new(species: &ConiferSpecies) -> Self {
        // A tree of prototypes is counted without flattening it.
        let counter = match species.prototypes() {
            Some(prototypes) => CutCounter::from_prototypes(prototypes),
            None => CutCounter::new(species.record()),
        };
        let merging_starts = counter.min_merged_error().unwrap_or(f32::INFINITY);
        // Bisection on a log scale: the cut's size falls as the error grows.
        let target = (species.needle_count / 10).max(1);
        let (mut lo, mut hi) = (species.min_line_error.max(1e-6), species.max_line_error.max(1e-6) * 1e4);
        for _ in 0..40 {
            let mid = (lo * hi).sqrt();
            if counter.count(mid).primitives() > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Self {
            counter,
            prisms_end: species.max_line_error,
            merging_starts,
            tenth: hi,
        }
    }
}

/// Frames per second, smoothed.
#[derive(Resource, Default)]
struct FrameRate {
    fps: f32,
}

fn measure_frame_rate(mut timer: ResMut<FrameRate>, time: Res<Time>) {
    let dt = time.delta_secs();
    if dt > 0.0 {
        let fps = 1.0 / dt;
        timer.fps = if timer.fps > 0.0 {
            timer.fps * 0.9 + fps * 0.1
        } else {
            fps
        };
    }
}

/// The overlay's colours are the materials' debug colours.
fn sync_debug_colors(debug: Res<ConiferLodDebug>, mut settings: ResMut<ConiferLodSettings>) {
    if !debug.is_changed() {
        return;
    }
    let wanted = debug.enabled && debug.colors;
    if settings.debug_colors != wanted {
        settings.debug_colors = wanted;
    }
}

#[allow(clippy::type_complexity, clippy::too_many_arguments)] // a Bevy system
fn collect_stats(
    debug: Res<ConiferLodDebug>,
    trees: Query<(
        &ConiferFoliage,
        &ConiferLodState,
        &GlobalTransform,
        &InheritedVisibility,
        Option<&ConiferLodOverride>,
    )>,
    cameras: Query<(&Camera, &GlobalTransform, &Projection)>,
    species_assets: Res<Assets<ConiferSpecies>>,
    mut counters: ResMut<SpeciesCounters>,
    settings: Res<ConiferLodSettings>,
    timer: Res<FrameRate>,
    cpu_time: Res<ConiferLodCpuTime>,
    mut stats: ResMut<ConiferLodStats>,
) {
    if !(debug.enabled || debug.always_collect_stats) {
        return;
    }
    let mut next = ConiferLodStats {
        pixel_error: settings.pixel_error,
        plugin_cpu_ms: cpu_time.last_frame.as_secs_f32() * 1e3,
        fps: timer.fps,
        ..default()
    };
    counters.0.retain(|id, _| species_assets.contains(*id));
    // The cameras' frusta, computed here so that they hold without Bevy's
    // frustum system.
    let frusta: Vec<bevy::camera::primitives::Frustum> = cameras
        .iter()
        .filter(|(camera, _, _)| camera.is_active)
        .map(|(_, transform, projection)| projection.compute_frustum(transform))
        .collect();
    // The first active perspective camera decides which trees are
    // impostors (as its cull pass does: `impostor_fade`).
    let viewer = first_perspective_camera(&cameras);
    for (foliage, state, transform, visibility, over) in &trees {
        next.instances += 1;
        let Some(species) = species_assets.get(&foliage.0) else {
            continue;
        };
        // The GPU culls each tree's box against each view's frustum; the
        // same test here.
        let affine = transform.affine();
        let seen = visibility.get()
            && frusta
                .iter()
                .any(|frustum| frustum.intersects_obb(&species.aabb, &affine, true, false));
        if !seen || state.views == 0 {
            continue;
        }
        next.visible_instances += 1;
        let entry = counters
            .0
            .entry(foliage.0.id())
            .or_insert_with(|| SpeciesDistances::new(species));
        let fade = match (&species.impostor, viewer) {
            (Some(impostor), Some((camera, slope)))
                if settings.enabled && over.and_then(|o| o.far_impostor).unwrap_or(settings.far_impostor) =>
            {
                let scale = transform.compute_transform().scale.abs().element_sum() / 3.0;
                let centre = transform.transform_point(species.crown_center);
                let pixel_error = over.and_then(|o| o.pixel_error).unwrap_or(settings.pixel_error);
                let e = pixel_error.max(0.0) * centre.distance(camera) * slope / scale.max(1e-6);
                let elevation = crate::model::impostor::elevation_tangent(camera - centre);
                crate::model::impostor::impostor_fade(e, impostor.texel, elevation, settings.impostor_steep_fade())
            }
            _ => 0.0,
        };
        if fade >= 1.0 {
            next.impostors += 1;
            continue;
        }
        next.fading += u64::from(fade > 0.0);
        let counts = entry.counter.count(state.min_spatial_error);
        next.prisms += counts.prisms;
        next.triangles += counts.triangles;
        next.lines_original += counts.lines_original;
        next.lines_merged += counts.lines_merged;
    }
    next.lines = next.lines_original + next.lines_merged;
    stats.set_if_neq(next);
}

#[allow(clippy::type_complexity, clippy::too_many_arguments)] // a Bevy system
fn draw_gizmos(
    debug: Res<ConiferLodDebug>,
    mut gizmos: Gizmos,
    cameras: Query<(&Camera, &GlobalTransform, &Projection)>,
    trees: Query<(&ConiferFoliage, &GlobalTransform, Option<&ConiferLodOverride>)>,
    species_assets: Res<Assets<ConiferSpecies>>,
    mut counters: ResMut<SpeciesCounters>,
    settings: Res<ConiferLodSettings>,
) {
    if !(debug.enabled && debug.gizmos) {
        return;
    }
    let Some((camera_position, slope)) = first_perspective_camera(&cameras) else {
        return;
    };
    let mut nearest: Vec<(f32, Vec3, f32, &ConiferFoliage, f32)> = trees
        .iter()
        .filter_map(|(foliage, transform, over)| {
            let species = species_assets.get(&foliage.0)?;
            let scale = transform.compute_transform().scale.abs().element_sum() / 3.0;
            let centre = transform.transform_point(species.crown_center);
            let pixel_error = over.and_then(|o| o.pixel_error).unwrap_or(settings.pixel_error);
            Some((centre.distance(camera_position), centre, scale, foliage, pixel_error))
        })
        .collect();
    nearest.sort_by(|a, b| a.0.total_cmp(&b.0));
    for &(_, centre, scale, foliage, pixel_error) in nearest.iter().take(debug.gizmo_trees) {
        let Some(species) = species_assets.get(&foliage.0) else {
            continue;
        };
        let half = Vec3::from(species.aabb.half_extents) * scale;
        gizmos.sphere(
            Isometry3d::from_translation(centre),
            half.length(),
            Color::srgb(0.9, 0.9, 0.9),
        );
        let bands = counters
            .0
            .entry(foliage.0.id())
            .or_insert_with(|| SpeciesDistances::new(species));
        // Distance where the tree's spatial error reaches e: D = e·s / (ε·slope).
        let distance = |e: f32| e * scale / (pixel_error.max(1e-6) * slope);
        let ground = Isometry3d::new(
            Vec3::new(centre.x, centre.y - half.y, centre.z),
            Quat::from_rotation_x(std::f32::consts::FRAC_PI_2),
        );
        for (e, color) in [
            (bands.prisms_end, Color::srgb(0.1, 0.5, 1.0)),
            (bands.merging_starts, Color::srgb(1.0, 1.0, 0.1)),
            (bands.tenth, Color::srgb(1.0, 0.2, 0.05)),
        ] {
            let radius = distance(e);
            if radius.is_finite() && radius > 0.0 && radius < 1e5 {
                gizmos.circle(ground, radius, color).resolution(96);
            }
        }
    }
}

/// The position and error slope (`view_error_slope`) of the first active
/// perspective camera with a viewport.
fn first_perspective_camera(cameras: &Query<(&Camera, &GlobalTransform, &Projection)>) -> Option<(Vec3, f32)> {
    cameras.iter().filter(|(c, _, _)| c.is_active).find_map(|(c, t, p)| {
        let height = c.physical_viewport_size()?.y as f32;
        let (slope, perspective) = view_error_slope(&p.get_clip_from_view(), height)?;
        perspective.then_some((t.translation(), slope))
    })
}

/// Marks the stats panel's text.
#[derive(Component)]
struct StatsPanel;

fn update_panel(
    mut commands: Commands,
    debug: Res<ConiferLodDebug>,
    stats: Res<ConiferLodStats>,
    wind: Option<Res<ConiferWind>>,
    mut panels: Query<(Entity, &mut Text), With<StatsPanel>>,
) {
    let shown = debug.enabled && debug.panel;
    if !shown {
        for (entity, _) in &panels {
            commands.entity(entity).despawn();
        }
        return;
    }
    let text = format!(
        "conifer LOD   pixel error {:.2} px\n\
         trees {} ({} visible)\n\
         prisms {}   triangles {}\n\
         lines {} original + {} merged = {}\n\
         impostors {} (+{} fading)\n\
         plugin CPU {:.3} ms   {:.0} FPS\n\
         wind {:.1}",
        stats.pixel_error,
        stats.instances,
        stats.visible_instances,
        stats.prisms,
        stats.triangles,
        stats.lines_original,
        stats.lines_merged,
        stats.lines,
        stats.impostors,
        stats.fading,
        stats.plugin_cpu_ms,
        stats.fps,
        wind.map_or(0.0, |w| w.strength),
    );
    if let Some((_, mut current)) = panels.iter_mut().next() {
        if current.0 != text {
            current.0 = text;
        }
        return;
    }
    commands.spawn((
        StatsPanel,
        Text::new(text),
        TextFont {
            font_size: FontSize::Px(14.0),
            ..default()
        },
        TextColor(Color::WHITE),
        BackgroundColor(Color::srgba(0.0, 0.0, 0.0, 0.6)),
        Node {
            position_type: PositionType::Absolute,
            top: px(8),
            left: px(8),
            padding: UiRect::all(px(6)),
            ..default()
        },
    ));
}

/// Keyboard control of the LOD, for examples and tools; add it to `Update`
/// yourself (`app.add_systems(Update, conifer_lod_keys)`): `[`/`]` pixel
/// error ε ÷/× 1.25 (0.05–64), `,`/`.` transition δ −/+ 0.1 (0.1–1), `L`
/// LOD on/off, `P` the line opacity rule (area-preserving → coverage →
/// paper), `-`/`=` wind strength −/+ 0.5 (0–4, [`ConiferWind`]), `F3` or
/// `O` the debug overlay.
pub fn conifer_lod_keys(
    keys: Res<ButtonInput<KeyCode>>,
    mut settings: ResMut<ConiferLodSettings>,
    mut debug: ResMut<ConiferLodDebug>,
    wind: Option<ResMut<ConiferWind>>,
) {
    if let Some(mut wind) = wind {
        if keys.just_pressed(KeyCode::Equal) {
            wind.strength = (wind.strength + 0.5).min(4.0);
        }
        if keys.just_pressed(KeyCode::Minus) {
            wind.strength = (wind.strength - 0.5).max(0.0);
        }
    }
    if keys.just_pressed(KeyCode::BracketRight) {
        settings.pixel_error = (settings.pixel_error * 1.25).min(64.0);
    }
    if keys.just_pressed(KeyCode::BracketLeft) {
        settings.pixel_error = (settings.pixel_error / 1.25).max(0.05);
    }
    if keys.just_pressed(KeyCode::Period) {
        settings.transition = (settings.transition + 0.1).min(1.0);
    }
    if keys.just_pressed(KeyCode::Comma) {
        settings.transition = (settings.transition - 0.1).max(0.1);
    }
    if keys.just_pressed(KeyCode::KeyL) {
        settings.enabled = !settings.enabled;
    }
    if keys.just_pressed(KeyCode::KeyP) {
        settings.line_opacity = match settings.line_opacity {
            LineOpacity::Paper => LineOpacity::AreaPreserving,
            LineOpacity::AreaPreserving => LineOpacity::Coverage,
            LineOpacity::Coverage => LineOpacity::Paper,
        };
    }
    if keys.just_pressed(KeyCode::F3) || keys.just_pressed(KeyCode::KeyO) {
        debug.enabled = !debug.enabled;
    }
}
