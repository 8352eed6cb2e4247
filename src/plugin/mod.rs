//! The Bevy plugin: continuous LOD of conifer foliage for every instance of
//! every tree, chosen on the GPU.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_conifer_lod::prelude::*;
//!
//! fn setup(mut commands: Commands, asset_server: Res<AssetServer>) {
//!     commands.spawn((
//!         ConiferFoliage(asset_server.load("trees/scots-pine.conifer")),
//!         Transform::from_xyz(0.0, 0.0, -20.0),
//!     ));
//! }
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, ConiferLodPlugin::default()))
//!     .add_systems(Startup, setup)
//!     .run();
//! ```
//!
//! ## How it draws
//!
//! A [`ConiferSpecies`] asset holds the record's compact arrays
//! ([`crate::model::compact`], ~32 bytes a needle; a tree of shared
//! prototypes keeps them shared) in storage buffers that the vertex shader
//! pulls from; each species keeps one instance buffer, updated only for the
//! trees that changed. Per view (each camera, each directional cascade,
//! each point-light face and spot light) a compute pass computes every
//! tree's spatial error, culls it, and writes the indirect draws of the
//! prefixes its cut needs: one multi-draw-indirect per species and part,
//! nothing spawned per tree, no per-tree CPU work while trees stand still.
//! Lines cast the shadow of the coverage they draw (a hashed alpha test);
//! lighting, fog, shadows and tonemapping are Bevy's. Needs compute shaders
//! and indirect draws with a first instance (`INDIRECT_FIRST_INSTANCE`:
//! Vulkan, Metal, DX12, WebGPU where the browser has it; not WebGL 2).
//! Measured in `docs/bench` and `tests/render_compact.rs`.
//!
//! ## System sets
//!
//! All run in `PostUpdate`. After transform propagation and Bevy's shadow
//! cascades, before visibility checks: [`ConiferLodSet::Select`] (each
//! tree's [`ConiferLodState`] on the CPU, while the debug overlay reads
//! it). After visibility propagation: [`ConiferLodSet::Instances`] (the
//! trees that changed, for the render world's instance buffers).

mod asset;
mod debug;
mod haze;
pub mod headless;
mod preset;
mod render;
mod systems;
mod wind;

pub use asset::{ConiferLoadError, ConiferRecordLoader, ConiferSpecies, triangle_mesh, wood_mesh};
pub use debug::{ConiferLodDebug, ConiferLodDebugPlugin, ConiferLodStats, conifer_lod_keys};
pub use haze::{aerial_perspective, haze_extinction};
pub use preset::{ConiferPresets, PresetCache, PresetLoadError, cache_file_name, load_preset};
pub use render::gpu::{
    FLAG_IMPOSTOR_ON, FLAG_IMPOSTOR_OVERRIDE, FLAG_PIXEL_ERROR_OVERRIDE, FLAG_TRANSITION_OVERRIDE, FLAG_VISIBLE,
    GpuInstance, OPACITY_OVERRIDE_SHIFT, PartKind,
};
pub use render::{CompactGpuMemory, CompactInstances, CompactReadback, ViewReadback};
pub use systems::{ConiferLodCpuTime, view_error_slope};
pub use wind::ConiferWind;

use bevy::asset::AssetApp;
use bevy::camera::visibility::VisibilitySystems;
use bevy::prelude::*;
use bevy::render::render_resource::TextureFormat;
use bevy::transform::TransformSystems;

/// Adds continuous conifer LOD: the `.conifer` asset loader, species
/// from presets ([`ConiferPresets`]), the systems of [`ConiferLodSet`] and
/// the render path.
///
/// What a game sets once goes in the plugin; what changes at run time is
/// a resource ([`ConiferLodSettings`], which starts as
/// [`ConiferLodPlugin::settings`]):
///
/// ```no_run
/// use bevy::prelude::*;
/// use bevy_conifer_lod::prelude::*;
///
/// App::new().add_plugins((
///     DefaultPlugins,
///     ConiferLodPlugin {
///         settings: ConiferLodSettings { pixel_error: 1.5, ..default() },
///         preset_cache: PresetCache::Directory("cache/trees".into()),
///     },
/// ));
/// ```
///
/// Needs Bevy's asset, mesh and (for drawing) render/PBR plugins; without a
/// render app (e.g. `MinimalPlugins` in tests) it still loads records and
/// computes every instance's [`ConiferLodState`].
#[derive(Clone, Debug, Default)]
pub struct ConiferLodPlugin {
    /// The first value of the [`ConiferLodSettings`] resource (a resource
    /// the app already has when the plugin is added is kept).
    pub settings: ConiferLodSettings,
    /// Where species baked from presets are cached.
    pub preset_cache: PresetCache,
}

impl ConiferLodPlugin {
    /// The plugin with these starting settings.
    pub fn with_settings(self, settings: ConiferLodSettings) -> Self {
        Self { settings, ..self }
    }

    /// The plugin with this preset cache.
    pub fn with_preset_cache(self, preset_cache: PresetCache) -> Self {
        Self { preset_cache, ..self }
    }
}

impl Plugin for ConiferLodPlugin {
    fn build(&self, app: &mut App) {
        if !app.world().contains_resource::<ConiferLodSettings>() {
            app.insert_resource(self.settings);
        }
        app.init_asset::<ConiferSpecies>()
            .init_asset_loader::<ConiferRecordLoader>()
            .insert_resource(preset::PresetStore::new(&self.preset_cache))
            .init_resource::<ConiferLodCpuTime>()
            .init_resource::<CompactInstances>()
            .init_resource::<ConiferWind>()
            // Inspectors and Bevy's remote protocol see and edit these.
            .register_type::<ConiferLodSettings>()
            .register_type::<ConiferFoliage>()
            .register_type::<ConiferLodOverride>()
            .register_type::<ConiferLodState>()
            .register_type::<ConiferLodCpuTime>()
            .register_type::<ConiferWind>()
            .configure_sets(
                PostUpdate,
                ConiferLodSet::Select
                    .after(TransformSystems::Propagate)
                    // The cascades of this frame's cameras, which the
                    // selection reads for the shadows.
                    .after(bevy::light::SimulationLightSystems::UpdateDirectionalLightCascades)
                    .before(VisibilitySystems::VisibilityPropagate),
            )
            // After visibility propagation: a hidden tree is not drawn.
            .configure_sets(
                PostUpdate,
                ConiferLodSet::Instances.after(VisibilitySystems::VisibilityPropagate),
            )
            .add_systems(PreUpdate, asset::explain_failed_loads)
            .add_systems(
                PostUpdate,
                (
                    systems::select_lod.in_set(ConiferLodSet::Select),
                    render::track_instances.in_set(ConiferLodSet::Instances),
                ),
            );
        if app.is_plugin_added::<bevy::pbr::PbrPlugin>() {
            render::build(app);
        }
    }
}

/// The plugin's system sets, in `PostUpdate`, in this order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ConiferLodSet {
    /// Computes every tree's [`ConiferLodState`] on the CPU while the debug
    /// overlay (or its stats) reads it; the GPU chooses what is drawn.
    Select,
    /// Records the trees that were spawned, moved, hidden, re-targeted or
    /// despawned in [`CompactInstances`] (after Bevy's visibility
    /// propagation, which it reads).
    Instances,
}

/// How merged (and original) lines get their opacity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum LineOpacity {
    /// The paper: `T = 2/ρ` (`2R/e`) for an original line; a merged line,
    /// read as a cylinder of radius `e(X)/2`, gets `e(X)/e`.
    Paper,
    /// The needles' summed side area over the line's pixel area (capped at
    /// 1): the tree keeps its projected density as lines merge.
    #[default]
    AreaPreserving,
    /// A merged line's needles overlap at random within its pixel
    /// footprint: coverage `1 − exp(−Σa/A)` of their summed side area `Σa`
    /// over the line's pixel area `A` (original lines, one needle each,
    /// keep `a/A`). Lower than [`LineOpacity::AreaPreserving`] where a
    /// bundle is dense, where summed areas overshoot.
    Coverage,
}

/// Where a tree's spatial error is measured from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum ErrorScope {
    /// The paper: one error for the whole tree, from the camera's distance
    /// to the crown's centre.
    Tree,
    /// Each placement and level-2 line of a tree of shared prototypes from
    /// the nearest point of its own bounding sphere
    /// ([`crate::model::view`]): a camera inside a tall crown sees prisms
    /// beside it and merged lines across it, and the cut stays an exact
    /// partition. A flat species (no shared prototypes) and orthographic
    /// views (directional shadow maps) keep one error per tree.
    #[default]
    Placement,
}

/// How lines are lit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum LineLighting {
    /// As the cylinder along the line's chord, the radiance of its visible
    /// half averaged over its projected width (Kajiya–Kay's integral,
    /// Bevy's BRDF at four normals across the width;
    /// [`crate::model::shading`]): a merged line as if its needles lay
    /// along its chord. A line lit from the side or behind is as dark as
    /// the needle's prism would be.
    #[default]
    Cylinder,
    /// As what a line stands for: an original line as its needle's
    /// cylinder, a merged line as its bundle of needles, which spread about
    /// its chord: the share of the chord's cylinder its needles' alignment
    /// gives ([`crate::model::shading::bundle_cylinder_share`]), the rest
    /// lit as a sphere (needles spread every way,
    /// [`crate::model::shading::SphereLight`]). Each merged line is about
    /// three times closer to its needles' mean lighting; a merged line's
    /// fragment is dearer (a lavapipe frame of the forest about 14 %
    /// longer) while the picture's crown colour moves by under 0.5 of 255
    /// in `conifer eval`.
    Bundle,
    /// As a flat strip turned toward the viewer (render path v2 before the
    /// cylinder; the paper lights a line with one stored normal): every line
    /// is lit from the front, up to 4/π brighter than its cylinder.
    FacingStrip,
}

/// Where a camera draws each tree's wood lines among its foliage lines.
/// Blended lines are not sorted one by one, so the order of a species'
/// draws decides what lies on top in a pixel both cover.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum WoodLineOrder {
    /// Once, before the foliage lines: the needles blend over every
    /// branch, the ones behind it too, and the crown hides its branches
    /// (the order until record format 10).
    UnderFoliage,
    /// Twice, before the foliage lines and after them, the wood's opacity
    /// split by the share of it the needles leave in sight where they
    /// cover the picture ([`crate::model::impostor::WoodVisibility`],
    /// measured by the impostor's bake; a species without an impostor
    /// draws its wood lines under the foliage): a pixel's wood and what
    /// lies behind the tree take what they take among the needles. Shadow
    /// views draw the wood lines once.
    #[default]
    Layered,
}

/// The order in which a camera blends the lines of trees of shared
/// prototypes (records with placements; a flat record's lines are drawn
/// per tree in the record's order either way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum LineOrder {
    /// Each expanded placement's lines on their own, the farthest first by
    /// depth bucket ([`crate::model::compact::depth_bucket`], 0.36 % of
    /// the distance deep): a pixel shows the needles the camera meets
    /// first, as a crown does. One indirect draw per placement, its
    /// merged lines then its original lines, sorted on the GPU.
    #[default]
    BackToFront,
    /// One instanced draw per prototype and band, in a fixed order: far
    /// fewer draws, but a pixel mixes needles from a crown's whole depth.
    ByPrototype,
}

/// How lines are rasterized.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Reflect)]
pub enum LineRaster {
    /// [`LineRaster::Area`] in views whose main texture blends in 16-bit
    /// float or wider (a camera with Bevy's `Hdr`), [`LineRaster::Hardware`]
    /// in 8-bit ones (a camera without it): an 8-bit main texture rounds
    /// every blend to 8 bits, and an area line's many faint fragments (the
    /// pixels its strip only touches) then darken the picture without
    /// adding to its coverage (see the README's "Cameras: give them
    /// `Hdr`"). Shadow views draw hardware lines whatever this setting,
    /// quads with [`ConiferLodSettings::shadow_line_quads`].
    #[default]
    Auto,
    /// Hardware lines, one pixel wide, every pixel they light taking the
    /// line's whole opacity (the paper's).
    Hardware,
    /// Each line a quad around its segment, every pixel covered by the
    /// area of the line's strip (its opacity wide) inside the pixel's
    /// square, as the supersampled reference box-filters a needle
    /// ([`crate::model::raster`]): a diagonal line splits its coverage
    /// between the pixels it crosses instead of lighting one pixel a step,
    /// and MSAA smears nothing. Exact for lines that do not overlap. In a
    /// dense crown, blending composes overlapping lines as if they fell
    /// independently while a crown's needles clump in depth: under the
    /// area-preserving opacity, the record's line calibration
    /// ([`ConiferSpecies::line_calibration`], measured at bake time by
    /// [`crate::model::calibration`]; a record older than format 9 has
    /// none until `conifer upgrade`) scales each line's opacity by its
    /// pixel size, so the crown's lines cover what its needles do. The
    /// default in `Hdr` cameras ([`LineRaster::Auto`]; see the README's
    /// "Lines that cover each pixel by their area" for how it measures
    /// against hardware lines). Cameras only: shadow views draw hardware
    /// lines unless [`ConiferLodSettings::shadow_line_quads`] is on. Three
    /// times the vertices of
    /// [`LineRaster::Hardware`] and more fragments (the quad reaches 1.25
    /// pixels past the strip; the fragments off the strip are discarded
    /// before lighting).
    Area,
}

impl LineRaster {
    /// Whether a camera rendering into a main texture of `main_format`
    /// draws its lines as quads: always for [`LineRaster::Area`], never for
    /// [`LineRaster::Hardware`], and for [`LineRaster::Auto`] where the
    /// texture blends with at least 16 bits a channel
    /// ([`blends_precisely`]).
    pub fn draws_quads(self, main_format: TextureFormat) -> bool {
        match self {
            LineRaster::Area => true,
            LineRaster::Hardware => false,
            LineRaster::Auto => blends_precisely(main_format),
        }
    }
}

/// Whether a main texture of `format` keeps at least 16 bits a colour and
/// alpha channel through blending (Bevy's `Hdr` texture, `Rgba16Float`,
/// and the wider RGBA formats), where an 8-bit one rounds every blend.
pub fn blends_precisely(format: TextureFormat) -> bool {
    matches!(
        format,
        TextureFormat::Rgba16Float | TextureFormat::Rgba32Float | TextureFormat::Rgba16Unorm
    )
}

/// Run-time LOD settings, shared by every tree; change them at any time.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Reflect)]
#[reflect(Resource, Default, Debug, Clone)]
pub struct ConiferLodSettings {
    /// Pixel error ε: how many pixels of deviation the simplification may
    /// cause. Larger is faster and coarser. Default 1.
    pub pixel_error: f32,
    /// Transition coefficient δ in `(0, 1]`: scales the opacity of original
    /// lines where they take over from prisms. Default 1.
    pub transition: f32,
    /// Opacity rule of lines.
    pub line_opacity: LineOpacity,
    /// How lines are lit.
    pub line_lighting: LineLighting,
    /// How lines are rasterized in cameras' views.
    pub line_raster: LineRaster,
    /// Where cameras draw the wood lines among the foliage lines.
    pub wood_line_order: WoodLineOrder,
    /// The order in which cameras blend the lines of expanded placements.
    pub line_order: LineOrder,
    /// `false` draws every needle as a prism of `Lmax` sides (LOD off).
    pub enabled: bool,
    /// Colour needles by representation (prisms blue, original lines green,
    /// merged lines yellow to red).
    pub debug_colors: bool,
    /// Trees of shared prototypes: most placements
    /// one view (a camera, a shadow cascade or face) expands into their
    /// prototypes' detail over all trees of a species (8 bytes each, twice,
    /// per view). The nearest trees get it first (by their spatial error,
    /// in buckets of a factor 1.29; [`crate::model::compact::budget_expands`]);
    /// a tree whose placements do not fit that frame is drawn as its
    /// impostor where a camera may draw one (`far_impostor`, not looked at
    /// steeply) and cast as its impostor in a shadow view (turned toward
    /// the light, each texel casting its coverage), else as its coarser
    /// cut (its level-2 lines). In a directional light's cascade every tree
    /// has the same error: there the budget goes to the trees nearest the
    /// camera the cascade serves ([`crate::model::compact::budget_error`]),
    /// whose shadows that camera sees closest and whose own crowns it sees
    /// self-shadowed by their lines. Default
    /// 131,072 (about 100 mature trees within full detail of one view);
    /// at most what one storage binding of the device holds (8 bytes an
    /// entry: 16,777,216 under wgpu's default 128 MiB), whatever is set.
    pub max_expanded_placements: u32,
    /// Where a tree's spatial error is measured from: one error per tree
    /// (the paper's) or each placement's own (default).
    pub error_scope: ErrorScope,
    /// Draw a far tree as its crown impostor
    /// ([`crate::model::impostor`]): from where one of its texels is
    /// smaller than the pixel error, the lines fade into one textured quad
    /// per tree, each sample of the tree's pixels drawn by one or the other
    /// ([`crate::model::impostor::impostor_samples`]; under 4× MSAA a pixel
    /// mixes both by quarters). Default on; [`ConiferLodSettings::paper`]
    /// turns it off.
    pub far_impostor: bool,
    /// The camera elevations over a tree's crown centre, in degrees,
    /// across which its far impostor gives way to its lines: drawn in
    /// full up to `[0]`, not at all from `[1]`
    /// ([`crate::model::impostor::SteepFade::from_degrees`], which clamps
    /// them). The impostor's pictures are side views: from 27° above, the
    /// mature spruce and pine as impostors are 2–3.5 times further from
    /// their reference in colour than their lines are (README, "Seen from
    /// above"). A lower band (say 15° to 30°) draws crowns seen from a
    /// hillside or a tower truer, at the cost of the lines of every tree
    /// it turns back: from the `forest` example's hillside, 15° to 30°
    /// doubles the lines drawn and the frame (README, "The steep band").
    /// Default `[30.0, 45.0]`.
    pub impostor_steep_degrees: [f32; 2],
    /// Dim the ambient light by the share of the sky each point of a
    /// crown sees through the crown
    /// ([`crate::model::crown_shade::SkyVisibility`], from the crown
    /// impostor's profile; species without an impostor are not dimmed).
    /// Bevy's `GlobalAmbientLight` lights a needle deep in a crown as
    /// brightly as one on its top; with this on, the crown's shaded body
    /// darkens as a real crown's does, every representation (prisms,
    /// lines, impostor) by the same function of where it lies, so a
    /// change of detail does not change it. Default off (the ambient light
    /// as Bevy gives it, as `conifer eval`'s reference has it); the
    /// `forest` example turns it on.
    pub sky_occlusion: bool,
    /// The shadow views' spatial error as a multiple of their own: a
    /// directional cascade's `ε · texel`, a point or spot light's map's
    /// `ε` texels at the tree's distance. At 1 (the default) every tree
    /// casts the lines a view of the shadow map's resolution would draw;
    /// above 1 the shadow passes draw a coarser cut (fewer lines, each
    /// standing for more needles), the shadow engines' "shadow LOD bias":
    /// a forest's shadow maps draw its lines once per cascade, which on a
    /// software renderer costs most of its frame. Shadow views draw lines
    /// one texel thick, so a line casts its needles' coverage while their
    /// bundle is not much wider than a texel: up to about 6 texels of
    /// error (`pixel_error` × this) the shadows keep their darkness (the
    /// README forest at `pixel_error` 3 and scale 2 draws its shadow
    /// passes in about half the time, its picture 0.5 of 255 lighter); at
    /// scale 4 its shadows are a quarter lighter unless
    /// [`ConiferLodSettings::shadow_line_quads`] is on. Cameras are not
    /// affected. Values below 1, NaN or infinite are taken as 1.
    pub shadow_error_scale: f32,
    /// Shadow views draw lines as quads of their bundle's width, each
    /// texel of the strip kept with the line's opacity (hashed), instead
    /// of hardware lines one texel thick, which cast a bundle several
    /// texels wide at an opacity of at most 1. For coarse shadow cuts
    /// ([`ConiferLodSettings::shadow_error_scale`] of 4 or more at a
    /// `pixel_error` of 3): there the shadows keep their darkness (the
    /// README forest at scale 4 0.4 of 255 darker than at scale 1, where
    /// hardware lines leave it 4.1 lighter). A quad is six vertices where
    /// a hardware line is two: on Mesa's lavapipe the same cut's shadow
    /// passes take 1.5–2.1 times as long, so at scale 2 quads are slower
    /// than scale 1 with hardware lines, and at 4 they cost what scale 2
    /// does with them (the README's "A coarser cut for the shadow maps").
    /// Default off.
    pub shadow_line_quads: bool,
}

impl Default for ConiferLodSettings {
    fn default() -> Self {
        Self {
            pixel_error: 1.0,
            transition: 1.0,
            line_opacity: LineOpacity::default(),
            line_lighting: LineLighting::default(),
            line_raster: LineRaster::default(),
            wood_line_order: WoodLineOrder::default(),
            line_order: LineOrder::default(),
            enabled: true,
            debug_colors: false,
            max_expanded_placements: 1 << 17,
            error_scope: ErrorScope::default(),
            far_impostor: true,
            impostor_steep_degrees: crate::model::impostor::SteepFade::DEFAULT_DEGREES,
            sky_occlusion: false,
            shadow_error_scale: 1.0,
            shadow_line_quads: false,
        }
    }
}

impl ConiferLodSettings {
    /// [`ConiferLodSettings::shadow_error_scale`] as the views apply it:
    /// at least 1, and 1 for a value that is not a number or infinite.
    pub fn shadow_error_factor(&self) -> f32 {
        let scale = self.shadow_error_scale;
        if scale.is_finite() { scale.max(1.0) } else { 1.0 }
    }

    /// [`ConiferLodSettings::impostor_steep_degrees`] as the cull pass
    /// applies it.
    pub fn impostor_steep_fade(&self) -> crate::model::impostor::SteepFade {
        let [start, end] = self.impostor_steep_degrees;
        crate::model::impostor::SteepFade::from_degrees(start, end)
    }

    /// The paper's configuration: `T = 2/ρ` opacity, one error per tree,
    /// hardware lines and lines at every distance, everything else as
    /// given.
    pub fn paper() -> Self {
        Self {
            line_opacity: LineOpacity::Paper,
            line_raster: LineRaster::Hardware,
            error_scope: ErrorScope::Tree,
            far_impostor: false,
            ..Self::default()
        }
    }
}

/// A tree: spawn it with a `Transform` and it is drawn with continuous LOD.
///
/// Nothing is spawned for it: the species' instance buffer holds its
/// transform, override, visibility and `RenderLayers` (if any).
#[derive(Component, Clone, Debug, PartialEq, Eq, Reflect)]
#[reflect(Component, Debug, Clone)]
#[require(Transform, Visibility, ConiferLodState)]
pub struct ConiferFoliage(pub Handle<ConiferSpecies>);

/// Per-tree override of the global [`ConiferLodSettings`] (e.g. a hero tree
/// with a finer pixel error).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Reflect)]
#[reflect(Component, Default, Debug, Clone)]
pub struct ConiferLodOverride {
    /// Pixel error ε for this tree.
    pub pixel_error: Option<f32>,
    /// Transition coefficient δ for this tree.
    pub transition: Option<f32>,
    /// Line opacity rule for this tree (`conifer eval` draws the paper's and
    /// ours side by side this way).
    pub line_opacity: Option<LineOpacity>,
    /// Whether this tree turns into its crown impostor far away
    /// ([`ConiferLodSettings::far_impostor`]).
    pub far_impostor: Option<bool>,
}

/// What a tree's LOD is this frame, over every active camera (written by
/// [`ConiferLodSet::Select`]). The GPU chooses what is drawn on its own;
/// the CPU keeps this up to date only while the debug overlay (or its
/// stats) is on.
#[derive(Component, Clone, Copy, Debug, PartialEq, Reflect)]
#[reflect(Component, Default, Debug, Clone)]
pub struct ConiferLodState {
    /// Smallest spatial error over the views (tree-local metres); infinite
    /// with no camera.
    pub min_spatial_error: f32,
    /// Largest spatial error over the views.
    pub max_spatial_error: f32,
    /// Cameras that see this tree's LOD.
    pub views: u32,
    /// Whether any needle can be a prism in some view (a camera, or a
    /// directional light's shadow cascade covering the tree).
    pub prisms_visible: bool,
    /// Whether any wood segment can be a prism in some view (cameras and
    /// shadow cascades).
    pub wood_prisms_visible: bool,
    /// Whether any line can be drawn in some view.
    pub lines_visible: bool,
}

/// The transform of a scatter placement: at its position, turned by its yaw
/// about +Y, scaled uniformly.
pub fn placement_transform(placement: &crate::scatter::Placement) -> Transform {
    Transform::from_translation(placement.position)
        .with_rotation(Quat::from_rotation_y(placement.yaw))
        .with_scale(Vec3::splat(placement.scale))
}

/// Spawns a tree per placement of a [`crate::scatter::Scatter`]: species
/// `species[placement.species]` (placements whose index is out of range are
/// skipped), at [`placement_transform`]. Returns the trees spawned.
pub fn spawn_forest(
    commands: &mut Commands,
    placements: &[crate::scatter::Placement],
    species: &[Handle<ConiferSpecies>],
) -> Vec<Entity> {
    placements
        .iter()
        .filter_map(|placement| {
            let handle = species.get(placement.species)?;
            Some(
                commands
                    .spawn((ConiferFoliage(handle.clone()), placement_transform(placement)))
                    .id(),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `LineRaster::Auto` draws quads in float main textures only; the two
    /// others whatever the texture.
    #[test]
    fn auto_raster_draws_quads_where_blending_keeps_precision() {
        let float = [TextureFormat::Rgba16Float, TextureFormat::Rgba32Float];
        let eight_bit = [
            TextureFormat::Rgba8UnormSrgb,
            TextureFormat::Rgba8Unorm,
            TextureFormat::Bgra8UnormSrgb,
            TextureFormat::Rgb10a2Unorm,
        ];
        for format in float.into_iter().chain(eight_bit) {
            assert!(LineRaster::Area.draws_quads(format));
            assert!(!LineRaster::Hardware.draws_quads(format));
            assert_eq!(
                LineRaster::Auto.draws_quads(format),
                float.contains(&format),
                "{format:?}"
            );
        }
    }
}
