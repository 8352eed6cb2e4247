//! The scene `conifer eval` renders: one tree, drawn by every method at
//! once, each on its own render layer seen by its own camera, plus the
//! supersampled reference, all in one headless Bevy app.
//!
//! * `paper` and `ours`: the plugin (a [`ConiferFoliage`]) with the paper's
//!   line opacity and with the plugin's defaults.
//! * `raw`: every needle as an `Lmax`-sided prism and the wood as cones, one
//!   ordinary `StandardMaterial` mesh each, no LOD. The reference is the same
//!   geometry rendered `supersampling²` times larger and box-filtered down,
//!   shaded at the centroid of each pixel's covered samples
//!   ([`super::reference`]; `raw`'s `StandardMaterial` extrapolates the
//!   normals of sub-pixel needles to the pixel's centre).
//! * `bevy-lod`: the raw mesh plus four meshoptimizer simplifications
//!   (50/25/12/6 %), switched by Bevy's `VisibilityRange` with its dithered
//!   crossfade, each level entering where its simplification error reaches
//!   the pixel error.
//! * `sampling`: the paper's rejected alternative to merging (§3): the
//!   prisms and wood of `ours`' cut, and instead of merged lines a random
//!   sample of the original lines, as many as `ours` draws at that
//!   distance, their opacity scaled up by the sampling factor. Built on the
//!   CPU for each distance as ordinary meshes (`StandardMaterial`, the
//!   lines blended with their opacity as vertex alpha).

use super::decimate::{DecimatedLevel, decimate, needle_mesh_with_corners_at};
use super::reference::{ReferenceMaterialPlugin, ReferenceSurface, reference_shoots, spawn_reference_tree};
use super::tonemap::ToneMap;
use crate::model::impostor::{elevation_tangent, impostor_fade};
use crate::model::metric::{line_error, prism_sides};
use crate::model::needle::WoodSegment;
use crate::model::prism::{
    TriangleMesh, WOOD_LINE_FADE, append_prism, append_wood_segment, prism_triangle_count, round_silhouette_scale,
    wood_segment_error,
};
use crate::model::wind::{TreeWindPhase, Wind, WindClock, WindShape, wind_offset};
use crate::model::{CutCounter, LodRecord, PixelError, PrototypeRecord, ViewParams};
use crate::plugin::headless::{HeadlessError, HeadlessRenderer};
use crate::plugin::{
    ConiferFoliage, ConiferLoadError, ConiferLodOverride, ConiferLodSettings, ConiferSpecies, ConiferWind, ErrorScope,
    LineLighting, LineOpacity, LineOrder, LineRaster, WoodLineOrder, triangle_mesh,
};
use bevy::asset::RenderAssetUsages;
use bevy::camera::Hdr;
use bevy::camera::visibility::{RenderLayers, VisibilityRange};
use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::mesh::PrimitiveTopology;
use bevy::prelude::*;
use bevy::render::render_resource::TextureFormat;
use image::RgbaImage;
use std::time::Instant;

/// A way of drawing the tree that `conifer eval` compares.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Method {
    /// The paper's configuration: its line opacity `T = 2/ρ`, δ as given,
    /// and its merge forest: the record's needles merged again with the
    /// paper's weighted cost and nested error ([`crate::model::paper_model`]).
    Paper,
    /// The plugin's defaults (area-preserving merged-line opacity, wood LOD).
    Ours,
    /// The raw needle geometry, no LOD.
    Raw,
    /// meshoptimizer LODs switched by Bevy's `VisibilityRange`.
    BevyLod,
    /// A random sample of original lines at `ours`' primitive budget.
    Sampling,
}

/// The render layer of the supersampled reference (the raw meshes with
/// [`super::reference::ReferenceMaterial`]); the methods' are `1..=5`.
pub const REFERENCE_LAYER: usize = 1 + Method::ALL.len();

impl Method {
    /// Every method, in report order.
    pub const ALL: [Method; 5] = [
        Method::Paper,
        Method::Ours,
        Method::Raw,
        Method::BevyLod,
        Method::Sampling,
    ];

    /// The method's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::Paper => "paper",
            Method::Ours => "ours",
            Method::Raw => "raw",
            Method::BevyLod => "bevy-lod",
            Method::Sampling => "sampling",
        }
    }

    /// The method called `name`.
    pub fn from_name(name: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == name.trim())
    }

    fn layer(self) -> usize {
        1 + self as usize
    }

    /// The merged-line opacity of the plugin's methods, `ours` drawing with
    /// `ours` (`None`: the method does not draw through the plugin).
    pub fn line_opacity(self, ours: LineOpacity) -> Option<LineOpacity> {
        match self {
            Method::Paper => Some(LineOpacity::Paper),
            Method::Ours => Some(ours),
            _ => None,
        }
    }
}

/// A headless renderer with the plugin set to `view`'s ε and δ (one error
/// per tree), and `tree` made a species as a game loading it would (not
/// yet added to the assets). Both eval scenes start here.
pub(super) fn renderer_with_species(
    tree: EvalTree,
    view: &EvalView,
) -> Result<(HeadlessRenderer, ConiferSpecies), EvalError> {
    if tree.needle_count() == 0 {
        return Err(EvalError::NoNeedles);
    }
    if view.width == 0 || view.height == 0 {
        return Err(EvalError::EmptyPicture(view.width, view.height));
    }
    let mut renderer = HeadlessRenderer::with_setup(".", |app| {
        app.add_plugins(ReferenceMaterialPlugin);
    });
    *renderer.world_mut().resource_mut::<ConiferLodSettings>() = ConiferLodSettings {
        pixel_error: view.pixel_error,
        transition: view.transition,
        line_lighting: view.line_lighting,
        line_raster: view.line_raster,
        wood_line_order: view.wood_line_order,
        line_order: view.line_order,
        impostor_steep_degrees: view.impostor_steep_degrees,
        // One error per tree, as the CPU cut the counts come from
        // (`EvalScene::counts`); `conifer eval --inside` measures each
        // placement's own.
        error_scope: ErrorScope::Tree,
        ..ConiferLodSettings::default()
    };
    let species = match tree {
        EvalTree::Flat(record) => ConiferSpecies::from_record(record)?,
        EvalTree::Placed(record) => ConiferSpecies::from_prototype_record(&record)?,
    };
    Ok((renderer, species))
}

/// The tree `conifer eval` measures, as a game would load it: a flat
/// record, or a tree of shared prototypes, which the plugin draws by its
/// placements (each shoot in its own colour, [`crate::model::color`]) and
/// the reference colours needle by needle alike
/// ([`super::reference::spawn_reference_tree`]).
#[derive(Clone, Debug)]
pub enum EvalTree {
    /// A flat record: one needle colour.
    Flat(LodRecord),
    /// A tree of shared prototypes (the mature presets' records).
    Placed(PrototypeRecord),
}

impl EvalTree {
    /// Its needles.
    pub fn needle_count(&self) -> u64 {
        match self {
            EvalTree::Flat(record) => record.needle_count() as u64,
            EvalTree::Placed(record) => record.needle_count(),
        }
    }
}

impl From<LodRecord> for EvalTree {
    fn from(record: LodRecord) -> Self {
        EvalTree::Flat(record)
    }
}

impl From<PrototypeRecord> for EvalTree {
    fn from(record: PrototypeRecord) -> Self {
        EvalTree::Placed(record)
    }
}

/// The species the plugin's methods draw, in the app's assets: ours (the
/// record as baked) and, where `paper` is measured, the paper's (the
/// record's needles merged again with the paper's weighted cost and nested
/// error, [`crate::model::paper_model`]).
pub(super) struct MethodSpecies {
    ours: Handle<ConiferSpecies>,
    paper: Option<Handle<ConiferSpecies>>,
    /// The paper's model the `paper` species draws.
    paper_record: Option<std::sync::Arc<LodRecord>>,
}

impl MethodSpecies {
    /// Adds `species`, and the paper's where `methods` has `paper`: from
    /// `paper_record` when a scene of the same record already baked it,
    /// else baked here.
    pub(super) fn add(
        world: &mut World,
        species: ConiferSpecies,
        methods: &[Method],
        paper_record: Option<std::sync::Arc<LodRecord>>,
    ) -> Result<Self, EvalError> {
        let paper = if methods.contains(&Method::Paper) {
            let record = match paper_record {
                Some(record) => LodRecord::clone(&record),
                None => crate::model::paper_model(species.record()).map_err(EvalError::PaperModel)?,
            };
            Some(ConiferSpecies::from_record(record)?)
        } else {
            None
        };
        let paper_record = paper.as_ref().map(|paper| paper.record().clone());
        let mut assets = world.resource_mut::<Assets<ConiferSpecies>>();
        Ok(Self {
            ours: assets.add(species),
            paper: paper.map(|paper| assets.add(paper)),
            paper_record,
        })
    }

    /// The paper's model the `paper` species draws (`None` without it).
    pub(super) fn paper_record(&self) -> Option<&std::sync::Arc<LodRecord>> {
        self.paper_record.as_ref()
    }

    /// The species `method` draws.
    pub(super) fn handle(&self, method: Method) -> Handle<ConiferSpecies> {
        match (method, &self.paper) {
            (Method::Paper, Some(paper)) => paper.clone(),
            _ => self.ours.clone(),
        }
    }
}

/// The picture every method is rendered at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalView {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Vertical field of view, degrees.
    pub fov_deg: f32,
    /// Pixel error ε.
    pub pixel_error: f32,
    /// Transition coefficient δ.
    pub transition: f32,
    /// Reference supersampling per axis (at least 4 for the issue's
    /// "4×4 per pixel").
    pub supersampling: u32,
    /// Where the sun stands.
    pub sun: EvalSun,
    /// Which lights shine.
    pub lights: EvalLights,
    /// How the plugin's methods light their lines.
    pub line_lighting: LineLighting,
    /// How the plugin's methods rasterize their lines.
    pub line_raster: LineRaster,
    /// Where the plugin's methods draw the wood lines among the foliage
    /// lines.
    pub wood_line_order: WoodLineOrder,
    /// The order in which the plugin's methods blend the lines of expanded
    /// placements.
    pub line_order: LineOrder,
    /// The merged-line opacity `ours` draws with.
    pub ours_line_opacity: LineOpacity,
    /// Whether `ours` fades far trees into the crown impostor (its
    /// default); `false` keeps its lines at every distance.
    pub ours_impostor: bool,
    /// Whether every camera renders into Bevy's high dynamic range main
    /// texture (`Hdr`: 16-bit float) instead of the 8-bit sRGB one a
    /// camera gets by default, where each blend of a translucent line is
    /// rounded to 8 bits.
    pub hdr: bool,
    /// Whether the cameras tone-map (Bevy's default, TonyMcMapface);
    /// `false` writes linear light clamped to [0, 1] (`Tonemapping::None`),
    /// leaving the background the clear colour in both main textures.
    pub tonemapping: bool,
    /// Whether the methods' cameras blend in 32-bit float: each renders
    /// linear light into an `Rgba32Float` target (no `Hdr`, no tone
    /// mapping) and is tone-mapped on the CPU as the reference is, instead
    /// of blending in `Hdr`'s `Rgba16Float`. Lavapipe rounds every blend
    /// into a 16-bit float toward zero (Mesa's `lp_build_float_to_half`),
    /// so a pixel under a hundred translucent lines comes out darker than
    /// its coverage allows; a 32-bit float blend rounds far below what a
    /// picture shows, as a GPU rounding 16-bit blends to nearest does.
    /// The cameras keep Bevy's default 4× MSAA, so the device must
    /// multisample `Rgba32Float` (lavapipe does; WebGPU does not promise
    /// it).
    pub float_blending: bool,
    /// Degrees the cameras stand above the crown centre's level, looking
    /// at it (negative: below); 0 looks level at the crown, as the paper's
    /// views do. A crown impostor's pictures are side views: from above
    /// they show what a side view shows.
    pub elevation_deg: f32,
    /// The elevations, degrees, across which `ours`'s impostor gives way
    /// to its lines (`ConiferLodSettings::impostor_steep_degrees`).
    pub impostor_steep_degrees: [f32; 2],
}

/// Where the sun of `conifer eval`'s scene stands (the camera looks at the
/// crown along −Z).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EvalSun {
    /// High behind the camera's right shoulder, 48° up (the headless
    /// renderer's sun).
    #[default]
    Front,
    /// Low, 15° up, from the camera's right, across the view: half of every
    /// needle is in its own shade.
    Side,
    /// Low, 15° up, from behind the tree toward the camera: back light.
    Back,
}

/// Which of `conifer eval`'s lights shine: the scene's sun and Bevy's
/// ambient light together, as a game has them, or one alone, to tell which
/// of them a method lights differently from the reference (a colour error
/// under both is a sum of the two).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EvalLights {
    /// The sun and the ambient light.
    #[default]
    Both,
    /// The sun alone (the ambient light's brightness 0).
    Sun,
    /// The ambient light alone (the sun's illuminance 0).
    Ambient,
}

impl EvalLights {
    /// Every choice, in order.
    pub const ALL: [EvalLights; 3] = [EvalLights::Both, EvalLights::Sun, EvalLights::Ambient];

    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            EvalLights::Both => "both",
            EvalLights::Sun => "sun",
            EvalLights::Ambient => "ambient",
        }
    }

    /// Turns off what does not shine: the `world`'s `GlobalAmbientLight`,
    /// or the `sun`'s illuminance.
    pub fn apply(self, world: &mut World, sun: Entity) {
        match self {
            EvalLights::Both => {}
            EvalLights::Sun => {
                if let Some(mut ambient) = world.get_resource_mut::<GlobalAmbientLight>() {
                    ambient.brightness = 0.0;
                }
            }
            EvalLights::Ambient => {
                if let Some(mut light) = world.get_mut::<DirectionalLight>(sun) {
                    light.illuminance = 0.0;
                }
            }
        }
    }
}

impl EvalSun {
    /// Every sun, in order.
    pub const ALL: [EvalSun; 3] = [EvalSun::Front, EvalSun::Side, EvalSun::Back];

    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            EvalSun::Front => "front",
            EvalSun::Side => "side",
            EvalSun::Back => "back",
        }
    }

    /// The sun's transform (a directional light shines along its −Z).
    pub fn transform(self) -> Transform {
        let low = 15f32.to_radians();
        let from = match self {
            EvalSun::Front => Vec3::new(4.0, 8.0, 6.0),
            EvalSun::Side => Vec3::new(low.cos(), low.sin(), 0.0),
            EvalSun::Back => Vec3::new(0.0, low.sin(), -low.cos()),
        };
        Transform::from_translation(from).looking_at(Vec3::ZERO, Vec3::Y)
    }
}

impl EvalView {
    /// A `size × size` picture with a vertical field of view of
    /// `fov_deg`: ε 1, δ 1, 4×4 reference samples, the front sun, and the
    /// plugin's defaults for lines and the impostor (what the tests use).
    pub fn square(size: u32, fov_deg: f32) -> Self {
        Self {
            width: size,
            height: size,
            fov_deg,
            pixel_error: 1.0,
            transition: 1.0,
            supersampling: 4,
            sun: EvalSun::default(),
            lights: EvalLights::default(),
            line_lighting: LineLighting::default(),
            line_raster: LineRaster::default(),
            wood_line_order: WoodLineOrder::default(),
            line_order: LineOrder::default(),
            ours_line_opacity: LineOpacity::default(),
            ours_impostor: true,
            hdr: false,
            tonemapping: true,
            float_blending: false,
            elevation_deg: 0.0,
            impostor_steep_degrees: ConiferLodSettings::default().impostor_steep_degrees,
        }
    }

    /// The unit direction from the crown centre to a camera at azimuth
    /// `azimuth` radians round it (0: on +Z), [`Self::elevation_deg`]
    /// above its level (clamped to ±89°; 0 where not finite).
    pub fn eye_direction(&self, azimuth: f32) -> Vec3 {
        let elevation = if self.elevation_deg.is_finite() {
            self.elevation_deg.clamp(-89.0, 89.0).to_radians()
        } else {
            0.0
        };
        Vec3::new(
            azimuth.sin() * elevation.cos(),
            elevation.sin(),
            azimuth.cos() * elevation.cos(),
        )
    }

    /// Gives a method's `camera` this view's main texture (`Hdr` where
    /// [`Self::hdr`]) and tone mapping (`Tonemapping::None` where not
    /// [`Self::tonemapping`]); where [`Self::float_blending`], its target's
    /// `Rgba32Float` with neither tone mapping nor dither (the picture is
    /// tone-mapped on the CPU, [`Self::methods_tone_map_on_cpu`]).
    pub fn configure_camera(&self, camera: &mut EntityWorldMut) {
        if self.float_blending {
            camera.insert((Tonemapping::None, DebandDither::Disabled));
            return;
        }
        if self.hdr {
            camera.insert(Hdr);
        }
        if !self.tonemapping {
            camera.insert(Tonemapping::None);
        }
    }

    /// Whether the reference renders linear light and is tone-mapped on
    /// the CPU after its box filter ([`super::tonemap`]): where the
    /// methods' cameras tone-map and have `Hdr` or blend in 32-bit float.
    pub fn reference_tone_maps_on_cpu(&self) -> bool {
        (self.hdr || self.float_blending) && self.tonemapping
    }

    /// Whether the methods' pictures are tone-mapped on the CPU: where
    /// they blend in 32-bit float ([`Self::float_blending`]) and tone-map.
    pub fn methods_tone_map_on_cpu(&self) -> bool {
        self.float_blending && self.tonemapping
    }

    /// Tone-maps the methods' `pictures` with `tone` (the reference's LUT)
    /// where they were drawn in linear light
    /// ([`Self::methods_tone_map_on_cpu`]); leaves them as they are
    /// otherwise.
    pub fn tone_map_methods(&self, tone: Option<&ToneMap>, pictures: &mut [RgbaImage]) {
        if self.methods_tone_map_on_cpu()
            && let Some(tone) = tone
        {
            for picture in pictures {
                tone.apply(picture);
            }
        }
    }

    /// The format of the methods' render targets: `Rgba32Float` where
    /// they blend in it ([`Self::float_blending`]), else 8-bit sRGB.
    pub fn methods_target_format(&self) -> TextureFormat {
        if self.float_blending {
            TextureFormat::Rgba32Float
        } else {
            TextureFormat::Rgba8UnormSrgb
        }
    }

    /// Gives the reference's camera its main texture: this view's, but
    /// writing linear light (`Tonemapping::None`, no deband dither) where
    /// [`Self::reference_tone_maps_on_cpu`].
    pub fn configure_reference_camera(&self, camera: &mut EntityWorldMut) {
        if self.float_blending {
            camera.insert((Hdr, Tonemapping::None, DebandDither::Disabled));
            return;
        }
        self.configure_camera(camera);
        if self.reference_tone_maps_on_cpu() {
            camera.insert((Tonemapping::None, DebandDither::Disabled));
        }
    }

    /// The raster the plugin's methods draw their lines with in these
    /// cameras ([`LineRaster::Auto`] resolved by the main texture [`Self::hdr`]
    /// picks).
    pub fn drawn_line_raster(&self) -> LineRaster {
        let main_format = if self.float_blending {
            TextureFormat::Rgba32Float
        } else if self.hdr {
            TextureFormat::Rgba16Float
        } else {
            TextureFormat::Rgba8UnormSrgb
        };
        if self.line_raster.draws_quads(main_format) {
            LineRaster::Area
        } else {
            LineRaster::Hardware
        }
    }

    /// The LOD model's view parameters for this picture.
    pub fn params(&self) -> ViewParams {
        ViewParams {
            vertical_fov: self.fov_deg.to_radians(),
            viewport_height_px: self.height as f32,
            pixel_error: PixelError(self.pixel_error),
        }
    }
}

/// Primitives a method draws at one distance.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DrawCounts {
    /// Triangles (needles and wood).
    pub triangles: u64,
    /// Line segments (needles and wood).
    pub lines: u64,
    /// Triangles and lines of the needles only (the paper's Table 1 measure).
    pub needle_primitives: u64,
}

impl DrawCounts {
    /// Triangles plus lines (the paper counts a line like a polygon).
    pub fn primitives(&self) -> u64 {
        self.triangles + self.lines
    }
}

/// One level of the `bevy-lod` chain.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LodLevelInfo {
    /// Needle triangles kept over the raw mesh's.
    pub ratio: f32,
    /// meshoptimizer's error, metres.
    pub error: f32,
    /// Whether the vertex-clustering simplifier was needed.
    pub sloppy: bool,
    /// Distance from the crown where the level fades in (the start of its
    /// crossfade margin is 10 % nearer).
    pub enters_at: f32,
    /// Triangles of the level (needles and wood).
    pub triangles: u64,
    /// Needle triangles of the level.
    pub needle_triangles: u64,
}

/// Margin of a `bevy-lod` crossfade, as a fraction of the switch distance
/// on each side.
const CROSSFADE_MARGIN: f32 = 0.1;

struct View {
    camera: Entity,
    target: Handle<Image>,
}

struct SamplingState {
    /// The cut's needle prisms.
    prisms: Handle<Mesh>,
    /// The wood prisms.
    wood: Handle<Mesh>,
    /// The sampled needle lines and the wood lines.
    lines: Handle<Mesh>,
    order: Vec<u32>,
    /// Needle line errors `2R`, sorted.
    line_errors: Vec<f32>,
    /// The spatial error the meshes were built for.
    built_for: Option<f32>,
}

/// Why the scene could not be built or rendered.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The record cannot become a species.
    #[error(transparent)]
    Species(#[from] ConiferLoadError),
    /// Rendering failed.
    #[error(transparent)]
    Render(#[from] HeadlessError),
    /// The record has no needles.
    #[error("the record has no needles")]
    NoNeedles,
    /// The paper's model of the record could not be baked.
    #[error("the paper's model of the record: {0}")]
    PaperModel(crate::model::BakeError),
    /// A picture could not be written.
    #[error("{0}: {1}")]
    Picture(String, String),
    /// A zero-sized picture.
    #[error("the picture has no pixels ({0}×{1})")]
    EmptyPicture(u32, u32),
    /// Tone mapping is on but Bevy's TonyMcMapface LUT is not loaded.
    #[error("Bevy's TonyMcMapface LUT is not loaded (Bevy's `tonemapping_luts` feature); run with --no-tonemapping")]
    NoToneMapLut,
}

/// The reference's picture at the methods' size: `supersampled`
/// box-filtered in linear light by `factor`, then tone-mapped by `tone`
/// where the reference rendered linear light
/// ([`EvalView::reference_tone_maps_on_cpu`]).
pub fn resolve_reference(supersampled: &RgbaImage, factor: u32, tone: Option<&ToneMap>) -> RgbaImage {
    let mut picture = super::measure::downsample(supersampled, factor);
    if let Some(tone) = tone {
        tone.apply(&mut picture);
    }
    picture
}

/// Pictures of one frame: each method's and the reference (box-filtered
/// to the methods' size).
pub struct EvalFrame {
    /// The reference.
    pub reference: RgbaImage,
    /// Each method's picture, in the scene's method order.
    pub methods: Vec<(Method, RgbaImage)>,
}

/// The headless app with every method's tree and camera.
pub struct EvalScene {
    renderer: HeadlessRenderer,
    record: std::sync::Arc<LodRecord>,
    /// The paper's model the `paper` method draws (`None` without it).
    paper_record: Option<std::sync::Arc<LodRecord>>,
    view: EvalView,
    methods: Vec<Method>,
    views: Vec<(Method, View)>,
    reference: View,
    counter: CutCounter,
    raw_counts: DrawCounts,
    levels: Vec<LodLevelInfo>,
    sampling: Option<SamplingState>,
    /// Texel side of the species' crown impostor (`ours` fades into it).
    impostor_texel: Option<f32>,
    /// The wind the scene sways in (`None`: calm): the plugin's trees sway
    /// on the GPU, every mesh (the reference, the peers) by the CPU
    /// reference, [`crate::model::wind::wind_offset`].
    wind: Option<ConiferWind>,
    /// The tree as the wind sees it.
    wind_shape: WindShape,
    /// Each mesh in calm (kept only in wind).
    wind_rest: std::collections::HashMap<AssetId<Mesh>, Mesh>,
    /// The wind's clock, seconds.
    wind_seconds: f64,
    /// Tone mapping applied to the reference after its box filter.
    reference_tone: Option<ToneMap>,
}

/// Background of every picture (alpha 0: the alpha channel is coverage).
pub const BACKGROUND: [f32; 3] = [0.92, 0.93, 0.95];

/// How far a lateral pan moves the picture of the crown a step, pixels: a
/// slow pan, under a pixel a frame, where lines crawl the most.
pub const PAN_PIXELS_PER_STEP: f32 = 0.37;

/// A camera path of `conifer eval`'s shimmer measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CameraPath {
    /// The camera circles the crown at a fixed distance, looking at it.
    Orbit,
    /// The camera moves sideways, looking straight ahead (−z), the crown
    /// crossing the middle of the picture.
    Pan,
}

impl CameraPath {
    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            CameraPath::Orbit => "orbit",
            CameraPath::Pan => "pan",
        }
    }
}

/// The wind's clock between two pictures of the dolly, seconds (a 30 FPS
/// game): in wind, the camera moves and the tree sways at once.
pub const DOLLY_STEP_SECONDS: f64 = 1.0 / 30.0;

impl EvalScene {
    /// Builds the scene for `tree` (a flat record or a tree of shared
    /// prototypes, [`EvalTree`]) with `methods` (the reference is always
    /// there), loads it and lets it reach the GPU.
    pub fn new(tree: impl Into<EvalTree>, methods: &[Method], view: EvalView) -> Result<Self, EvalError> {
        Self::new_in_wind(tree, methods, view, None)
    }

    /// [`EvalScene::new`] in `wind` (`None` or calm: calm), its clock set
    /// by [`EvalScene::set_wind_time`]: the plugin's trees sway on the GPU,
    /// every mesh (the reference, the peers) by the CPU reference of the
    /// same field. The meshes' calm copies are kept for it (as much memory
    /// again).
    pub fn new_in_wind(
        tree: impl Into<EvalTree>,
        methods: &[Method],
        view: EvalView,
        wind: Option<ConiferWind>,
    ) -> Result<Self, EvalError> {
        let wind = wind.filter(|w| !w.model().is_calm());
        let (mut renderer, species) = renderer_with_species(tree.into(), &view)?;
        let record = species.record().clone();
        let shoots = reference_shoots(&species);
        let impostor_texel = species.impostor.as_ref().map(|i| i.texel);
        let wind_shape = species.wind_shape;
        let mut methods: Vec<Method> = methods.to_vec();
        methods.sort();
        methods.dedup();

        let all_layers = RenderLayers::from_layers(&[0, 1, 2, 3, 4, 5, REFERENCE_LAYER]);
        let world = renderer.world_mut();
        let sun = HeadlessRenderer::spawn_lights(world);
        world.entity_mut(sun).insert((all_layers, view.sun.transform()));
        view.lights.apply(world, sun);

        // The plugin's methods.
        let method_species = MethodSpecies::add(world, species, &methods, None)?;
        for method in [Method::Paper, Method::Ours] {
            if let Some(opacity) = method
                .line_opacity(view.ours_line_opacity)
                .filter(|_| methods.contains(&method))
            {
                world.spawn((
                    ConiferFoliage(method_species.handle(method)),
                    ConiferLodOverride {
                        line_opacity: Some(opacity),
                        // The paper draws lines at every distance.
                        far_impostor: Some(method == Method::Ours && view.ours_impostor),
                        ..default()
                    },
                    Transform::IDENTITY,
                    RenderLayers::layer(method.layer()),
                ));
            }
        }

        // The raw geometry only where `raw` or `bevy-lod` draws it: the
        // same prisms as the reference's, so the reference's counts are
        // raw's (a mature tree's mesh is large).
        let (needle_material, wood_material) = raw_materials(world, &record);
        let raw = (methods.contains(&Method::Raw) || methods.contains(&Method::BevyLod)).then(|| RawTree::new(&record));
        let spawn_mesh = |world: &mut World, mesh: &TriangleMesh, material: &Handle<StandardMaterial>, layer: usize| {
            let handle = world.resource_mut::<Assets<Mesh>>().add(triangle_mesh(mesh));
            world
                .spawn((
                    Mesh3d(handle),
                    MeshMaterial3d(material.clone()),
                    Transform::IDENTITY,
                    RenderLayers::layer(layer),
                ))
                .id()
        };
        if let Some(raw) = raw.as_ref().filter(|_| methods.contains(&Method::Raw)) {
            for (mesh, material) in [(&raw.needles, &needle_material), (&raw.wood, &wood_material)] {
                spawn_mesh(world, mesh, material, Method::Raw.layer());
            }
        }
        // The reference draws its own geometry (`RawTree::reference`: each
        // prism as wide as its needle on average) with its own material
        // and the tree's colours (each needle its shoot's), on its own
        // layer; in wind it sways as every mesh of the scene does.
        let [needle_triangles, wood_triangles] =
            spawn_reference_tree(world, &record, shoots.as_deref(), RenderLayers::layer(REFERENCE_LAYER));
        let raw_counts = DrawCounts {
            triangles: needle_triangles + wood_triangles,
            lines: 0,
            needle_primitives: needle_triangles,
        };

        // bevy-lod: the raw level and four simplifications.
        let params = view.params();
        let crown = record.crown_center();
        let mut levels = Vec::new();
        if let Some(raw) = raw.as_ref().filter(|_| methods.contains(&Method::BevyLod)) {
            let chain = bevy_lod_chain(raw);
            let enters = enter_distances(&chain, params.error_per_distance());
            // VisibilityRange measures from the camera to the entity's origin
            // (the tree's foot); eval's camera looks at the crown along +Z.
            let to_origin = |d: f32| (crown + Vec3::Z * d).length();
            for (k, level) in chain.iter().enumerate() {
                let range = visibility_range(&enters, k, to_origin);
                for (mesh, material) in [
                    (&level.needles.mesh, &needle_material),
                    (&level.wood.mesh, &wood_material),
                ] {
                    let entity = spawn_mesh(world, mesh, material, Method::BevyLod.layer());
                    world.entity_mut(entity).insert(range.clone());
                }
                levels.push(LodLevelInfo {
                    ratio: level.needles.ratio,
                    error: level.error(),
                    sloppy: level.needles.sloppy || level.wood.sloppy,
                    enters_at: enters[k],
                    triangles: (level.needles.mesh.triangle_count() + level.wood.mesh.triangle_count()) as u64,
                    needle_triangles: level.needles.mesh.triangle_count() as u64,
                });
            }
        }

        // sampling: meshes rebuilt for each distance (`set_distance`).
        let mut sampling = None;
        if methods.contains(&Method::Sampling) {
            let m = &record.material;
            let mut materials = world.resource_mut::<Assets<StandardMaterial>>();
            let lines_material = materials.add(StandardMaterial {
                // The vertex colours carry each line's colour and opacity.
                base_color: Color::WHITE,
                perceptual_roughness: m.roughness,
                reflectance: m.reflectance,
                alpha_mode: AlphaMode::Blend,
                cull_mode: None,
                ..default()
            });
            let mut meshes = world.resource_mut::<Assets<Mesh>>();
            let mut empty = TriangleMesh::default();
            never_empty(&mut empty);
            let empty = triangle_mesh(&empty);
            let (prisms, wood, lines) = (meshes.add(empty.clone()), meshes.add(empty), meshes.add(empty_lines()));
            for (mesh, material) in [
                (&prisms, &needle_material),
                (&wood, &wood_material),
                (&lines, &lines_material),
            ] {
                world.spawn((
                    Mesh3d(mesh.clone()),
                    MeshMaterial3d(material.clone()),
                    Transform::IDENTITY,
                    RenderLayers::layer(Method::Sampling.layer()),
                ));
            }
            let mut line_errors: Vec<f32> = record.needles.iter().map(|n| line_error(n.radius)).collect();
            line_errors.sort_by(f32::total_cmp);
            sampling = Some(SamplingState {
                prisms,
                wood,
                lines,
                order: sampling_order(record.needle_count(), 0x5A3D),
                line_errors,
                built_for: None,
            });
        }

        // Cameras: one per method, and the reference's.
        let mut views = Vec::new();
        let camera = |renderer: &mut HeadlessRenderer,
                      width: u32,
                      height: u32,
                      format: TextureFormat,
                      layer: usize,
                      order: isize| {
            let target = renderer.render_target_with_format(width, height, format);
            let [r, g, b] = BACKGROUND;
            let camera = renderer
                .world_mut()
                .spawn((
                    HeadlessRenderer::camera_bundle(&target, Transform::IDENTITY, view.fov_deg.to_radians()),
                    Camera {
                        clear_color: ClearColorConfig::Custom(Color::srgba(r, g, b, 0.0)),
                        order,
                        ..default()
                    },
                    RenderLayers::layer(layer),
                ))
                .id();
            view.configure_camera(&mut renderer.world_mut().entity_mut(camera));
            View { camera, target }
        };
        for (k, &method) in methods.iter().enumerate() {
            views.push((
                method,
                camera(
                    &mut renderer,
                    view.width,
                    view.height,
                    view.methods_target_format(),
                    method.layer(),
                    k as isize,
                ),
            ));
        }
        let s = view.supersampling.max(1);
        let reference = camera(
            &mut renderer,
            view.width * s,
            view.height * s,
            TextureFormat::Rgba8UnormSrgb,
            REFERENCE_LAYER,
            methods.len() as isize,
        );
        view.configure_reference_camera(&mut renderer.world_mut().entity_mut(reference.camera));
        let reference_tone = if view.reference_tone_maps_on_cpu() {
            Some(ToneMap::from_world(renderer.world_mut()).ok_or(EvalError::NoToneMapLut)?)
        } else {
            None
        };
        // The reference keeps Bevy's 4× MSAA on top of its supersampling:
        // needles a hundredth of a pixel wide need many samples per pixel
        // before the coverage converges (see `conifer eval`'s docs).
        let counter = CutCounter::new(&record);
        // The meshes in calm, before the render world takes their data.
        let mut wind_rest = std::collections::HashMap::new();
        if wind.is_some() {
            let world = renderer.world_mut();
            let handles: Vec<Handle<Mesh>> = world.query::<&Mesh3d>().iter(world).map(|m| m.0.clone()).collect();
            let meshes = world.resource::<Assets<Mesh>>();
            for handle in handles {
                if let Some(mesh) = meshes.get(&handle) {
                    wind_rest.insert(handle.id(), mesh.clone());
                }
            }
        }
        let mut scene = Self {
            renderer,
            record,
            paper_record: method_species.paper_record().cloned(),
            view,
            methods,
            views,
            reference,
            counter,
            raw_counts,
            levels,
            sampling,
            impostor_texel,
            wind,
            wind_shape,
            wind_rest,
            reference_tone,
            wind_seconds: 0.0,
        };
        scene.set_wind_time(0.0);
        scene.set_distance(10.0);
        // Let species, meshes and pipelines reach the GPU.
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
            scene.renderer.update()?;
        }
        Ok(scene)
    }

    /// The record drawn.
    pub fn record(&self) -> &LodRecord {
        &self.record
    }

    /// The paper's model of the record, which the `paper` method draws
    /// ([`crate::model::paper_model`]; `None` without that method).
    pub fn paper_record(&self) -> Option<&std::sync::Arc<LodRecord>> {
        self.paper_record.as_ref()
    }

    /// The methods drawn, in report order.
    pub fn methods(&self) -> &[Method] {
        &self.methods
    }

    /// The `bevy-lod` chain (empty without that method).
    pub fn lod_levels(&self) -> &[LodLevelInfo] {
        &self.levels
    }

    /// The picture settings.
    pub fn view(&self) -> &EvalView {
        &self.view
    }

    /// Where the cameras are: `distance` metres from the crown centre, on +Z
    /// ([`EvalView::elevation_deg`] above its level), looking at it.
    pub fn eye(&self, distance: f32) -> Vec3 {
        self.record.crown_center() + self.view.eye_direction(0.0) * distance
    }

    /// The scene's world (e.g. to change a tree's `ConiferLodOverride`).
    pub fn world_mut(&mut self) -> &mut World {
        self.renderer.world_mut()
    }

    /// Moves every camera to `distance` from the crown and updates the
    /// sampled lines for it.
    pub fn set_distance(&mut self, distance: f32) {
        let distance = if distance.is_finite() { distance.max(1e-3) } else { 1.0 };
        let crown = self.record.crown_center();
        let transform = Transform::from_translation(self.eye(distance)).looking_at(crown, Vec3::Y);
        self.set_camera(distance, transform);
    }

    /// The cameras' place at `step` of `steps` along `path`, `distance`
    /// from the crown (the dolly's front view at step 0 of an orbit and
    /// the middle step of a pan).
    pub fn path_transform(&self, path: CameraPath, distance: f32, step: usize, steps: usize) -> Transform {
        let crown = self.record.crown_center();
        match path {
            CameraPath::Orbit => {
                let angle = std::f32::consts::TAU * step as f32 / steps.max(1) as f32;
                let eye = crown + self.view.eye_direction(angle) * distance;
                Transform::from_translation(eye).looking_at(crown, Vec3::Y)
            }
            CameraPath::Pan => {
                // PAN_PIXELS_PER_STEP pixels at the crown's distance a step.
                let metres_per_pixel =
                    2.0 * distance * (self.view.fov_deg.to_radians() / 2.0).tan() / self.view.height.max(1) as f32;
                let offset = (step as f32 - steps as f32 / 2.0) * PAN_PIXELS_PER_STEP * metres_per_pixel;
                Transform::from_translation(self.eye(distance) + Vec3::X * offset)
            }
        }
    }

    /// The screen box of the tree seen by a camera at `transform`.
    pub fn rect_from(&self, transform: &Transform) -> super::measure::PixelRect {
        let (lo, hi) = self.record.bounds();
        let target = transform.translation
            + transform.forward() * self.record.crown_center().distance(transform.translation).max(1e-3);
        super::measure::screen_rect(
            lo,
            hi,
            transform.translation,
            target,
            self.view.fov_deg.to_radians(),
            self.view.width,
            self.view.height,
        )
    }

    /// Moves every camera to `transform`, with the sampled lines of a view
    /// `distance` from the crown.
    pub fn set_camera(&mut self, distance: f32, transform: Transform) {
        let distance = if distance.is_finite() { distance.max(1e-3) } else { 1.0 };
        for camera in self.cameras() {
            if let Some(mut t) = self.renderer.world_mut().get_mut::<Transform>(camera) {
                *t = transform;
            }
        }
        let e = self.view.params().spatial_error(distance);
        let keep = self.sampling_keep(distance);
        if let Some(sampling) = &mut self.sampling
            && sampling.built_for != Some(e)
        {
            sampling.built_for = Some(e);
            let sampled = sampled_meshes(&self.record, &sampling.order, keep, e, self.view.pixel_error);
            let rebuilt = [
                (sampling.prisms.id(), triangle_mesh(&sampled.prisms)),
                (sampling.wood.id(), triangle_mesh(&sampled.wood)),
                (sampling.lines.id(), sampled.lines),
            ];
            // In wind the new meshes sway at the clock's moment like the
            // others, and are kept as they are for the next moments.
            let mut shown = Vec::with_capacity(rebuilt.len());
            for (id, mesh) in rebuilt {
                match self.swayed(&mesh) {
                    Some(swayed) => {
                        self.wind_rest.insert(id, mesh);
                        shown.push((id, swayed));
                    }
                    None => shown.push((id, mesh)),
                }
            }
            let mut meshes = self.renderer.world_mut().resource_mut::<Assets<Mesh>>();
            for (id, mesh) in shown {
                if let Some(mut slot) = meshes.get_mut(id) {
                    *slot = mesh;
                }
            }
        }
    }

    /// Sets the wind's clock to `seconds`: the plugin's trees take it, and
    /// every mesh of the scene moves by the CPU reference of the same field
    /// (the tree stands at the origin, as the plugin's do). Nothing in calm.
    pub fn set_wind_time(&mut self, seconds: f64) {
        let Some(mut wind) = self.wind else {
            return;
        };
        self.wind_seconds = seconds;
        wind.time = Some(seconds);
        self.renderer.world_mut().insert_resource(wind);
        let shown: Vec<(AssetId<Mesh>, Mesh)> = self
            .wind_rest
            .iter()
            .filter_map(|(&id, rest)| Some((id, self.swayed(rest)?)))
            .collect();
        let mut meshes = self.renderer.world_mut().resource_mut::<Assets<Mesh>>();
        for (id, mesh) in shown {
            if let Some(mut slot) = meshes.get_mut(id) {
                *slot = mesh;
            }
        }
    }

    /// `rest` moved by the CPU reference of the wind at the clock's moment
    /// (the tree stands at the origin, as the plugin's do); `None` in calm
    /// or for a mesh without positions.
    fn swayed(&self, rest: &Mesh) -> Option<Mesh> {
        let sway = sway_at(&self.wind?.model(), &self.wind_shape, self.wind_seconds);
        let positions = rest.attribute(Mesh::ATTRIBUTE_POSITION)?.as_float3()?;
        let moved: Vec<[f32; 3]> = positions.iter().map(|&p| sway(Vec3::from(p)).to_array()).collect();
        let mut mesh = rest.clone();
        mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, moved);
        Some(mesh)
    }

    /// Needles the `sampling` method keeps at `distance`: the fraction of
    /// `ours`' needle lines over the needles that are lines there.
    fn sampling_keep(&self, distance: f32) -> usize {
        let e = self.view.params().spatial_error(distance);
        let Some(sampling) = &self.sampling else {
            return 0;
        };
        let candidates = sampling.line_errors.partition_point(|&err| err <= e);
        let budget = self.counter.count(e).lines() as usize;
        let needles = self.record.needle_count();
        if candidates == 0 || budget >= candidates {
            return needles;
        }
        ((needles as f64 * budget as f64 / candidates as f64).round() as usize).clamp(1, needles)
    }

    /// Primitives `method` draws at `distance` (the reference draws the raw
    /// geometry).
    pub fn counts(&self, method: Method, distance: f32) -> DrawCounts {
        let e = self.view.params().spatial_error(distance);
        let (wood_triangles, wood_lines) = wood_counts(&self.record, e);
        match method {
            Method::Paper | Method::Ours => {
                // `ours` fades into the crown impostor far away: its quad
                // is two triangles, and once it is opaque nothing else is
                // drawn (the cull pass's rule, `impostor_fade`).
                let fade = match (method, self.impostor_texel) {
                    // The camera looks at the crown centre from the
                    // view's elevation, under the band the plugin draws with.
                    (Method::Ours, Some(texel)) if self.view.ours_impostor => {
                        let steep = self
                            .renderer
                            .world()
                            .resource::<ConiferLodSettings>()
                            .impostor_steep_fade();
                        impostor_fade(e, texel, elevation_tangent(self.view.eye_direction(0.0)), steep)
                    }
                    _ => 0.0,
                };
                let impostor = if fade > 0.0 { 2 } else { 0 };
                if fade >= 1.0 {
                    return DrawCounts {
                        triangles: impostor,
                        lines: 0,
                        needle_primitives: impostor,
                    };
                }
                let cut = self.counter.count(e);
                DrawCounts {
                    triangles: cut.triangles + wood_triangles + impostor,
                    lines: cut.lines() + wood_lines,
                    needle_primitives: cut.primitives() + impostor,
                }
            }
            Method::Raw => self.raw_counts,
            Method::BevyLod => {
                let to_origin = |d: f32| (self.record.crown_center() + Vec3::Z * d).length();
                let here = to_origin(distance);
                let mut counts = DrawCounts::default();
                for (k, level) in self.levels.iter().enumerate() {
                    let start = if k == 0 {
                        0.0
                    } else {
                        to_origin(level.enters_at * (1.0 - CROSSFADE_MARGIN))
                    };
                    let end = self.levels.get(k + 1).map_or(f32::INFINITY, |next| {
                        to_origin(next.enters_at * (1.0 + CROSSFADE_MARGIN))
                    });
                    if here >= start && here < end {
                        counts.triangles += level.triangles;
                        counts.needle_primitives += level.needle_triangles;
                    }
                }
                counts
            }
            Method::Sampling => {
                let cut = self.counter.count(e);
                let keep = self.sampling_keep(distance);
                let sampled = self.sampling.as_ref().map_or(0, |s| {
                    self.record
                        .needles
                        .iter()
                        .zip(&s.order)
                        .filter(|(n, rank)| (**rank as usize) < keep && line_error(n.radius) <= e)
                        .count() as u64
                });
                DrawCounts {
                    triangles: cut.triangles + wood_triangles,
                    lines: sampled + wood_lines,
                    needle_primitives: cut.triangles + sampled,
                }
            }
        }
    }

    /// The tree's screen rectangle at `distance` on the methods' pictures.
    pub fn screen_rect(&self, distance: f32) -> super::measure::PixelRect {
        let (lo, hi) = self.record.bounds();
        self.box_rect(lo, hi, distance)
    }

    /// The screen box of the needles alone at `distance` (the crown, without
    /// the bare trunk below it): where [`crate::model::look::crown_see_through`]
    /// looks.
    pub fn crown_rect(&self, distance: f32) -> super::measure::PixelRect {
        match crate::model::needle::bounds(self.record.needles.iter().flat_map(|n| [n.base, n.tip])) {
            Some((lo, hi)) => self.box_rect(lo, hi, distance),
            None => self.screen_rect(distance),
        }
    }

    /// The screen rectangle of the box `[lo, hi]` seen from the eye at `distance`.
    fn box_rect(&self, lo: Vec3, hi: Vec3, distance: f32) -> super::measure::PixelRect {
        super::measure::screen_rect(
            lo,
            hi,
            self.eye(distance),
            self.record.crown_center(),
            self.view.fov_deg.to_radians(),
            self.view.width,
            self.view.height,
        )
    }

    /// Every camera: the methods' and the reference's.
    fn cameras(&self) -> Vec<Entity> {
        self.views
            .iter()
            .map(|(_, v)| v.camera)
            .chain([self.reference.camera])
            .collect()
    }

    fn set_active(&mut self, only: Option<Entity>) {
        for camera in self.cameras() {
            if let Some(mut c) = self.renderer.world_mut().get_mut::<Camera>(camera) {
                c.is_active = only.is_none_or(|o| o == camera);
            }
        }
    }

    /// Renders one frame with every camera and returns the pictures.
    pub fn capture(&mut self) -> Result<EvalFrame, EvalError> {
        self.set_active(None);
        // The frame that takes the screenshot also runs the LOD selection
        // and uploads the sampled lines for the cameras' new place.
        let mut targets: Vec<Handle<Image>> = self.views.iter().map(|(_, v)| v.target.clone()).collect();
        targets.push(self.reference.target.clone());
        let images = self.renderer.capture_all(&targets, 10)?;
        Ok(self.frame(images))
    }

    /// A frame of the captured `images` (each method's, then the
    /// reference's): the reference resolved, the methods' pictures
    /// tone-mapped where they were drawn in linear light
    /// ([`EvalView::methods_tone_map_on_cpu`]).
    fn frame(&self, mut images: Vec<RgbaImage>) -> EvalFrame {
        let reference = resolve_reference(
            &images.pop().expect("reference"),
            self.view.supersampling.max(1),
            self.reference_tone.as_ref(),
        );
        self.view.tone_map_methods(self.reference_tone.as_ref(), &mut images);
        EvalFrame {
            reference,
            methods: self.methods.iter().copied().zip(images).collect(),
        }
    }

    /// Pictures at each of `distances` in turn (a dolly), one frame each:
    /// the screenshot of a step is read back while the next renders.
    /// `on_frame` gets each step's index and pictures, in order.
    pub fn capture_sequence(
        &mut self,
        distances: &[f32],
        on_frame: impl FnMut(usize, EvalFrame),
    ) -> Result<(), EvalError> {
        let crown = self.record.crown_center();
        let places: Vec<(f32, Transform)> = distances
            .iter()
            .map(|&d| (d, Transform::from_translation(self.eye(d)).looking_at(crown, Vec3::Y)))
            .collect();
        self.capture_path(&places, on_frame)
    }

    /// Pictures with the cameras at each of `places` (distance from the
    /// crown for the sampled lines, transform) in turn, one frame each,
    /// the wind's clock [`DOLLY_STEP_SECONDS`] on a step; `on_frame` gets
    /// each step's index and pictures, in order.
    pub fn capture_path(
        &mut self,
        places: &[(f32, Transform)],
        mut on_frame: impl FnMut(usize, EvalFrame),
    ) -> Result<(), EvalError> {
        self.set_active(None);
        let mut targets: Vec<Handle<Image>> = self.views.iter().map(|(_, v)| v.target.clone()).collect();
        targets.push(self.reference.target.clone());
        let mut pending = std::collections::VecDeque::new();
        let mut deliver =
            |scene: &Self, pending: &mut std::collections::VecDeque<(usize, _)>| -> Result<(), EvalError> {
                while let Some((step, request)) = pending.front() {
                    let request: &crate::plugin::headless::PendingScreenshots = request;
                    let Some(images) = request.take()? else {
                        break;
                    };
                    on_frame(*step, scene.frame(images));
                    pending.pop_front();
                }
                Ok(())
            };
        for (step, &(distance, transform)) in places.iter().enumerate() {
            self.set_camera(distance, transform);
            self.set_wind_time(step as f64 * DOLLY_STEP_SECONDS);
            pending.push_back((step, self.renderer.request_screenshots(&targets)));
            self.renderer.update()?;
            deliver(self, &mut pending)?;
        }
        for _ in 0..10 {
            if pending.is_empty() {
                break;
            }
            self.renderer.update()?;
            deliver(self, &mut pending)?;
        }
        if pending.is_empty() {
            Ok(())
        } else {
            Err(EvalError::Render(HeadlessError::NoScreenshot(10)))
        }
    }

    /// Median wall time of `frames` frames with only `method`'s camera
    /// active (`None`: the reference's), milliseconds.
    pub fn frame_ms(&mut self, method: Option<Method>, frames: usize) -> Result<f64, EvalError> {
        let camera = match method {
            Some(m) => self.views.iter().find(|(v, _)| *v == m).map(|(_, v)| v.camera),
            None => Some(self.reference.camera),
        };
        self.set_active(camera);
        // A warm-up frame after switching cameras.
        self.renderer.update()?;
        let mut times = Vec::new();
        for _ in 0..frames.max(1) {
            let started = Instant::now();
            self.renderer.update()?;
            times.push(started.elapsed().as_secs_f64() * 1e3);
        }
        self.set_active(None);
        Ok(super::measure::median(&times))
    }
}

/// A tree's raw geometry: every needle an `Lmax`-sided prism, the wood
/// segments cones of `Lmax` sides (plus imported wood triangles).
pub struct RawTree {
    /// The needles.
    pub needles: TriangleMesh,
    /// The wood.
    pub wood: TriangleMesh,
}

impl RawTree {
    /// The raw geometry of `record`: each prism the polygon inscribed in
    /// its circle, as a mesh exporter writes it.
    pub fn new(record: &LodRecord) -> Self {
        Self::with_corners_at(record, 1.0)
    }

    /// The reference's geometry of `record`: as [`Self::new`], the same
    /// triangles, but each needle's prism and wood segment's cone with its
    /// corners [`round_silhouette_scale`] radii from the axis (1.026 at 8
    /// sides), so that its silhouette is on average as wide as the round
    /// needle or branch it stands for (`2R`, the width lines and the line
    /// calibration take; the inscribed octagon is 2.55 % narrower). The
    /// shadow reference (`super::shadow::reference_darkening`) is round
    /// already. With each needle vertex's needle group (a flattened tree's
    /// placement), in vertex order.
    pub fn reference(record: &LodRecord) -> (Self, Vec<u32>) {
        let scale = round_silhouette_scale(record.max_sides);
        let (needles, groups) = super::decimate::needle_mesh_and_groups(record, scale);
        (
            Self {
                needles,
                wood: Self::wood_with_corners_at(record, scale),
            },
            groups,
        )
    }

    /// Every needle's prism and wood segment's cone of `Lmax` sides with
    /// its corners `scale` radii from the axis (imported wood triangles as
    /// they are).
    fn with_corners_at(record: &LodRecord, scale: f32) -> Self {
        Self {
            needles: needle_mesh_with_corners_at(record, scale),
            wood: Self::wood_with_corners_at(record, scale),
        }
    }

    /// The wood of [`Self::with_corners_at`]: each segment's cone with its
    /// corners `scale` radii from the axis, after the imported triangles.
    fn wood_with_corners_at(record: &LodRecord, scale: f32) -> TriangleMesh {
        let mut wood = record.wood_mesh.clone();
        for segment in &record.wood {
            let scaled = WoodSegment {
                start_radius: segment.start_radius * scale,
                end_radius: segment.end_radius * scale,
                ..*segment
            };
            append_wood_segment(&mut wood, &scaled, u32::from(record.max_sides));
        }
        wood
    }
}

/// One level of the `bevy-lod` chain: needles and wood simplified alike.
pub struct ChainLevel {
    /// The needles.
    pub needles: DecimatedLevel,
    /// The wood.
    pub wood: DecimatedLevel,
}

impl ChainLevel {
    /// The level's geometric error, metres (the larger of its two meshes').
    pub fn error(&self) -> f32 {
        self.needles.error.max(self.wood.error)
    }
}

/// Triangle ratios of the `bevy-lod` levels after the raw one.
pub const BEVY_LOD_RATIOS: [f32; 4] = [0.5, 0.25, 0.12, 0.06];

/// The `bevy-lod` chain of `raw`: itself, then [`BEVY_LOD_RATIOS`] of it
/// by meshoptimizer.
pub fn bevy_lod_chain(raw: &RawTree) -> Vec<ChainLevel> {
    let unchanged = |mesh: &TriangleMesh| DecimatedLevel {
        mesh: mesh.clone(),
        ratio: 1.0,
        error: 0.0,
        sloppy: false,
    };
    let mut chain = vec![ChainLevel {
        needles: unchanged(&raw.needles),
        wood: unchanged(&raw.wood),
    }];
    for ratio in BEVY_LOD_RATIOS {
        chain.push(ChainLevel {
            needles: decimate(&raw.needles, ratio),
            wood: decimate(&raw.wood, ratio),
        });
    }
    chain
}

/// Distance at which each level of `chain` enters: where its error reaches
/// the pixel error (`error / error_per_distance`), never before the level
/// above it.
pub fn enter_distances(chain: &[ChainLevel], error_per_distance: f32) -> Vec<f32> {
    let mut enters: Vec<f32> = Vec::with_capacity(chain.len());
    for level in chain {
        let previous = enters.last().copied().unwrap_or(0.0);
        enters.push((level.error() / error_per_distance.max(1e-12)).max(previous));
    }
    enters
}

/// The `VisibilityRange` of level `k` for levels entering at `enters`,
/// with a dithered crossfade of ±10 % around each switch; `to_range` maps
/// a crown distance to the distance Bevy measures (camera to the entity's
/// origin).
pub fn visibility_range(enters: &[f32], k: usize, to_range: impl Fn(f32) -> f32) -> VisibilityRange {
    let start = enters[k];
    let end = enters.get(k + 1).copied().unwrap_or(f32::INFINITY);
    VisibilityRange {
        start_margin: if k == 0 {
            0.0..0.0
        } else {
            to_range(start * (1.0 - CROSSFADE_MARGIN))..to_range(start * (1.0 + CROSSFADE_MARGIN))
        },
        end_margin: if end.is_finite() {
            to_range(end * (1.0 - CROSSFADE_MARGIN))..to_range(end * (1.0 + CROSSFADE_MARGIN))
        } else {
            f32::MAX..f32::MAX
        },
        use_aabb: false,
    }
}

/// The surfaces of a raw tree, needles and wood: the record's colours, the
/// needles' roughness and the bark's ([`crate::model::needle::BARK_ROUGHNESS`]),
/// the material's reflectance, as the plugin's own materials use them; the
/// needles' underside colour (for needles coloured by shoot) and the
/// bark's turn by height. The raw methods' `StandardMaterial`s
/// ([`raw_materials`]: the base colours only) and the reference's
/// materials ([`super::reference::spawn_reference_tree`]) are made of them.
pub fn raw_surfaces(record: &LodRecord) -> [ReferenceSurface; 2] {
    let m = &record.material;
    let linear = |[r, g, b, _]: [f32; 4]| Vec4::new(r, g, b, 1.0);
    let needles = ReferenceSurface {
        underside_color: linear(m.needle_underside_color),
        ..ReferenceSurface::plain(linear(m.needle_color), m.roughness, m.reflectance)
    };
    let wood = ReferenceSurface {
        upper_bark_color: linear(m.upper_wood_color),
        bark_heights: Vec2::from(m.upper_wood_heights),
        bark_by_height: 1,
        ..ReferenceSurface::plain(
            linear(m.wood_color),
            crate::model::needle::BARK_ROUGHNESS,
            m.reflectance,
        )
    };
    [needles, wood]
}

/// The `StandardMaterial`s of a raw tree's [`raw_surfaces`]: needles, wood.
pub fn raw_materials(world: &mut World, record: &LodRecord) -> (Handle<StandardMaterial>, Handle<StandardMaterial>) {
    let mut materials = world.resource_mut::<Assets<StandardMaterial>>();
    let [needles, wood] = raw_surfaces(record).map(|surface| {
        materials.add(StandardMaterial {
            base_color: LinearRgba::from_vec4(surface.base_color).into(),
            perceptual_roughness: surface.perceptual_roughness,
            reflectance: surface.reflectance,
            ..default()
        })
    });
    (needles, wood)
}

/// A random order of `count` items (a permutation of `0..count` from a
/// seeded stream): item `i` is kept by a sample of `k` when `order[i] < k`,
/// so samples of growing size are nested and a dolly does not reshuffle.
pub fn sampling_order(count: usize, seed: u64) -> Vec<u32> {
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    let mut ranks: Vec<u32> = (0..count as u32).collect();
    let mut stream = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    ranks.shuffle(&mut stream);
    ranks
}

/// The `sampling` method at spatial error `e` (pixel error `pixel_error`):
/// the prisms of the record's cut and the wood prisms as `ours` draws them,
/// and as lines the needles with `order[i] < keep` that are lines at `e`
/// (`2R ≤ e`), never merged, each as opaque as `needles / keep` of them
/// would be (`min(2R · scale · ε / e, 1)`, the area-preserving opacity of a
/// line `scale` times as wide), plus the wood lines (`2r̄ · ε / e` until
/// [`WOOD_LINE_FADE`] times their error). `keep` is clamped to
/// `1..=needles`; `order` has one entry per needle ([`sampling_order`]).
pub fn sampled_meshes(record: &LodRecord, order: &[u32], keep: usize, e: f32, pixel_error: f32) -> SampledMeshes {
    let needles = record.needle_count();
    let keep = keep.clamp(1, needles.max(1));
    let scale = needles as f32 / keep as f32;
    let (mut prisms, mut wood) = (TriangleMesh::default(), TriangleMesh::default());
    for (needle, sides) in record.cut(e).prisms {
        append_prism(&mut prisms, &record.needles[needle as usize], sides);
    }
    let [nr, ng, nb, _] = record.material.needle_color;
    let [wr, wg, wb, _] = record.material.wood_color;
    let opacity = |width: f32| (width * pixel_error / e.max(1e-12)).min(1.0);
    let (mut positions, mut normals, mut colors) = (Vec::new(), Vec::new(), Vec::new());
    let mut line = |[a, b]: [Vec3; 2], normal: Vec3, color: [f32; 4]| {
        positions.extend([a.to_array(), b.to_array()]);
        normals.extend([normal.to_array(); 2]);
        colors.extend([color; 2]);
    };
    for (needle, &rank) in record.needles.iter().zip(order) {
        let error = line_error(needle.radius);
        if (rank as usize) < keep && error <= e {
            line(
                [needle.base, needle.tip],
                needle.normal,
                [nr, ng, nb, opacity(error * scale)],
            );
        }
    }
    for segment in &record.wood {
        let error = wood_segment_error(segment);
        if error.is_nan() || error <= 0.0 || segment.start == segment.end {
            continue;
        }
        let radius = segment.start_radius.max(segment.end_radius);
        if e < error {
            append_wood_segment(&mut wood, segment, u32::from(prism_sides(e / radius, record.max_sides)));
        } else if e < error * WOOD_LINE_FADE {
            let normal = (segment.end - segment.start)
                .normalize_or_zero()
                .any_orthonormal_vector();
            let width = segment.start_radius + segment.end_radius;
            line([segment.start, segment.end], normal, [wr, wg, wb, opacity(width)]);
        }
    }
    let lines = if positions.is_empty() {
        empty_lines()
    } else {
        line_mesh(positions, normals, colors)
    };
    SampledMeshes { prisms, wood, lines }.never_empty()
}

/// What the `sampling` method draws at one error ([`sampled_meshes`]);
/// a piece with nothing to draw holds one primitive of no size.
pub struct SampledMeshes {
    /// Needle prisms (the record's cut).
    pub prisms: TriangleMesh,
    /// Wood segment prisms.
    pub wood: TriangleMesh,
    /// Sampled needle lines and wood lines, opacity in the vertex alpha.
    pub lines: Mesh,
}

impl SampledMeshes {
    fn never_empty(mut self) -> Self {
        never_empty(&mut self.prisms);
        never_empty(&mut self.wood);
        self
    }
}

/// A line mesh that draws nothing: one transparent line of no length
/// (Bevy's mesh allocator holds no empty mesh).
fn empty_lines() -> Mesh {
    line_mesh(vec![[0.0; 3]; 2], vec![[0.0, 1.0, 0.0]; 2], vec![[0.0; 4]; 2])
}

/// A `LineList` mesh of positions, normals and colours (two per line).
fn line_mesh(positions: Vec<[f32; 3]>, normals: Vec<[f32; 3]>, colors: Vec<[f32; 4]>) -> Mesh {
    Mesh::new(PrimitiveTopology::LineList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
        .with_inserted_attribute(Mesh::ATTRIBUTE_COLOR, colors)
}

/// Gives an empty mesh one triangle of no area, which draws nothing (Bevy's
/// mesh allocator holds no empty mesh).
fn never_empty(mesh: &mut TriangleMesh) {
    if mesh.indices.is_empty() {
        *mesh = TriangleMesh::default();
        mesh.positions = vec![Vec3::ZERO; 3];
        mesh.normals = vec![Vec3::Y; 3];
        mesh.indices = vec![0, 1, 2];
    }
}

/// Wood triangles and lines the plugin draws at spatial error `e`: a
/// segment is a prism of `prism_sides(e / r_max)` sides while `e < 2·r_max`,
/// then a line until `WOOD_LINE_FADE` times that.
pub fn wood_counts(record: &LodRecord, e: f32) -> (u64, u64) {
    wood_counts_by(record, |_| e)
}

/// [`wood_counts`] with each segment at its own spatial error
/// `error_of(segment)` (view-dependent detail: `eval::inside`).
pub fn wood_counts_by(record: &LodRecord, error_of: impl Fn(&crate::model::WoodSegment) -> f32) -> (u64, u64) {
    let (mut triangles, mut lines) = (0u64, 0u64);
    for segment in &record.wood {
        let e = error_of(segment);
        let error = wood_segment_error(segment);
        if error.is_nan() || error <= 0.0 {
            continue;
        }
        if e < error {
            let radius = segment.start_radius.max(segment.end_radius);
            triangles += u64::from(prism_triangle_count(prism_sides(e / radius, record.max_sides)));
        } else if e < error * WOOD_LINE_FADE {
            lines += 1;
        }
    }
    (triangles, lines)
}

/// Where a point of a tree standing at the origin (its wind shape `shape`)
/// is at `seconds` on the wind's clock: the CPU reference of the field the
/// plugin's vertex shader applies ([`wind_offset`]).
pub(crate) fn sway_at(model: &Wind, shape: &WindShape, seconds: f64) -> impl Fn(Vec3) -> Vec3 + use<> {
    let clock = WindClock::at(seconds, shape);
    let phase = TreeWindPhase::of_root(Vec2::ZERO, model);
    let direction = model.unit_direction();
    let (model, shape) = (*model, *shape);
    move |p| p + wind_offset(&model, &shape, &clock, &phase, p).world(direction, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--lights sun` leaves the sun and darkens the ambient light;
    /// `--lights ambient` the other way round; `both` touches neither.
    #[test]
    fn lights_turn_off_what_does_not_shine() {
        for lights in EvalLights::ALL {
            let mut world = World::new();
            let sun = HeadlessRenderer::spawn_lights(&mut world);
            lights.apply(&mut world, sun);
            let ambient = world.resource::<GlobalAmbientLight>().brightness;
            let illuminance = world.get::<DirectionalLight>(sun).unwrap().illuminance;
            assert_eq!(
                (ambient > 0.0, illuminance > 0.0),
                match lights {
                    EvalLights::Both => (true, true),
                    EvalLights::Sun => (false, true),
                    EvalLights::Ambient => (true, false),
                },
                "{}",
                lights.name()
            );
        }
    }

    /// The cameras' direction from the crown is a unit vector at the
    /// view's elevation and the asked azimuth; level and on +Z by default,
    /// and never NaN or past straight up.
    #[test]
    fn the_eye_stands_at_the_views_elevation() {
        let level = EvalView::square(64, 45.0);
        assert_eq!(level.eye_direction(0.0), Vec3::Z);
        for (elevation_deg, azimuth) in [(27.0f32, 0.0f32), (-15.0, 1.0), (60.0, 4.0)] {
            let view = EvalView { elevation_deg, ..level };
            let d = view.eye_direction(azimuth);
            assert!((d.length() - 1.0).abs() < 1e-6);
            assert!((d.y.asin().to_degrees() - elevation_deg).abs() < 1e-3, "{d}");
            let across_the_ground = Vec2::new(d.x, d.z).normalize();
            assert!(
                across_the_ground.distance(Vec2::new(azimuth.sin(), azimuth.cos())) < 1e-5,
                "{d}"
            );
        }
        for elevation_deg in [f32::NAN, f32::INFINITY, 90.0, 1e9] {
            let d = EvalView { elevation_deg, ..level }.eye_direction(0.0);
            assert!(
                d.is_finite() && d.z > 0.0 && (d.length() - 1.0).abs() < 1e-6,
                "{elevation_deg}: {d}"
            );
        }
    }
}
