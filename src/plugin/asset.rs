//! The species asset: a `.conifer` record and its compact GPU layout.

use crate::model::calibration::LineCalibration;
use crate::model::compact::{CompactError, CompactSpecies};
use crate::model::impostor::{CrownImpostor, ImpostorOptions, TrunkProfile};
use crate::model::metric::line_error;
use crate::model::prism::{TriangleMesh, append_wood_segment, wood_segment_error};
use crate::model::wind::WindShape;
use crate::model::{
    FoliageMaterial, LodRecord, PrototypeRecord, RecordError, WoodSegment, bake_impostor, decode_prototype_record,
};
use bevy::asset::io::{AssetReaderError, Reader};
use bevy::asset::{AssetLoadError, AssetLoadFailedEvent, AssetLoader, LoadContext, RenderAssetUsages};
use bevy::camera::primitives::Aabb;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use std::sync::{Arc, OnceLock};

/// One tree species, loaded from a `.conifer` record: the record itself
/// and its compact GPU layout, which every tree of the species shares.
///
/// A tree of shared prototypes is kept as prototypes: drawing it never
/// needs the flattened tree (millions of needles), which
/// [`ConiferSpecies::record`] builds on first use only.
#[derive(Asset, TypePath, Debug, Clone)]
pub struct ConiferSpecies {
    /// The tree of shared prototypes it was loaded from, if any.
    prototypes: Option<Arc<PrototypeRecord>>,
    /// The flattened record: set at load for a flat record, on first use
    /// for prototypes (shared by clones).
    flat: Arc<OnceLock<Arc<LodRecord>>>,
    /// Appearance of the needles and wood.
    pub material: FoliageMaterial,
    /// Needles of the tree (placed, for prototypes).
    pub needle_count: u64,
    /// Largest wood segment error `2·r_max`: no wood prism is drawn at or
    /// above it.
    pub max_wood_error: f32,
    /// Tree-local bounds of needles and wood, widened by the largest needle radius.
    pub aabb: Aabb,
    /// Tree-local centre of the crown (where the viewing distance is measured to).
    pub crown_center: Vec3,
    /// Largest line error `2R`: no prism is drawn at or above it.
    pub max_line_error: f32,
    /// Smallest line error `2R`: no line is drawn below it.
    pub min_line_error: f32,
    /// The record in the compact GPU layout the render path draws
    /// ([`crate::model::compact`]); a tree of shared prototypes keeps them
    /// shared.
    pub compact: Arc<CompactSpecies>,
    /// The far representation ([`crate::model::impostor`]): the one the
    /// record was baked with ([`crate::model::BakeOptions::impostor`]),
    /// else baked from the needles and wood when the record loads (`None`
    /// when they have no extent).
    pub impostor: Option<Arc<CrownImpostor>>,
    /// The trunk over the impostor's height ([`TrunkProfile`]): where its
    /// pictures show the trunk, the impostor lights it as the round stem's
    /// band under each pixel. No trunk without an impostor.
    pub trunk: TrunkProfile,
    /// The lines' opacity scales by pixel size the record was calibrated
    /// with ([`crate::model::calibration`]; `None` for a record baked
    /// without or before format 9: every line keeps its opacity). The
    /// plugin applies them to lines drawn by their area
    /// ([`super::LineRaster::Area`]) under the area-preserving opacity.
    pub line_calibration: Option<LineCalibration>,
    /// The tree as the wind sees it ([`crate::model::wind::WindShape`]):
    /// its box; its trunk stands where its lowest wood starts, or under the
    /// crown centre for a tree without wood.
    pub wind_shape: WindShape,
}

/// Why a `.conifer` file did not load as a [`ConiferSpecies`].
#[derive(Debug, thiserror::Error)]
pub enum ConiferLoadError {
    /// Reading the bytes failed.
    #[error("cannot read the record: {0}")]
    Io(#[from] std::io::Error),
    /// The bytes are not a valid record.
    #[error("invalid conifer record: {0}")]
    Record(#[from] RecordError),
    /// The record does not fit the GPU layout (more than 8,388,608
    /// needles, or errors or positions out of its range).
    #[error("the record cannot be drawn: {0}")]
    Layout(#[from] CompactError),
}

/// Logs, once per failed load of a species, what to do about it (Bevy has
/// logged the error itself): trees of a species that failed are simply not
/// drawn.
pub(crate) fn explain_failed_loads(mut failures: MessageReader<AssetLoadFailedEvent<ConiferSpecies>>) {
    for failure in failures.read() {
        let advice = match &failure.error {
            AssetLoadError::AssetReaderError(AssetReaderError::NotFound(_)) => format!(
                "`{}` does not exist: bake it with `conifer bake --preset NAME -o assets/{}` (or `conifer bake TREE.glb`), or grow a preset from code with `ConiferPresets`",
                failure.path, failure.path
            ),
            _ if failure.path.path().as_os_str().is_empty() => "see the error above".to_owned(),
            _ => format!("`{}` did not load (see the error above)", failure.path),
        };
        warn!("conifer trees of this species are not drawn: {advice}");
    }
}

/// Loads `.conifer` records as [`ConiferSpecies`].
#[derive(Default, TypePath)]
pub struct ConiferRecordLoader;

impl AssetLoader for ConiferRecordLoader {
    type Asset = ConiferSpecies;
    type Settings = ();
    type Error = ConiferLoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        _settings: &(),
        _load_context: &mut LoadContext<'_>,
    ) -> Result<ConiferSpecies, ConiferLoadError> {
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes).await?;
        // Shared prototypes stay shared on the GPU and are not flattened.
        let prototypes = decode_prototype_record(&bytes)?;
        ConiferSpecies::from_prototype_record(&prototypes)
    }

    fn extensions(&self) -> &[&str] {
        &["conifer"]
    }
}

impl ConiferSpecies {
    /// A species from a record made in code (e.g. baked at build time or
    /// at startup). Add it to `Assets<ConiferSpecies>` and spawn
    /// [`super::ConiferFoliage`] with the handle. A record without an
    /// impostor gets one baked here (seconds for a mature tree).
    pub fn from_record(record: LodRecord) -> Result<Self, ConiferLoadError> {
        Self::from_flat(record)
    }

    /// A species from a tree of shared prototypes made in code (e.g.
    /// [`crate::model::bake_prototypes`] of
    /// [`crate::generate::generate_prototypes`]), as
    /// [`ConiferSpecies::from_record`]; the GPU layout keeps its prototypes
    /// shared, and nothing here flattens the tree.
    pub fn from_prototype_record(record: &PrototypeRecord) -> Result<Self, ConiferLoadError> {
        let (min_radius, max_radius) = record.radius_range();
        let impostor = record
            .impostor
            .clone()
            .or_else(|| bake_impostor(record, ImpostorOptions::default()));
        Self::new(
            SpeciesParts {
                material: record.material,
                needle_count: record.needle_count(),
                wood: &record.wood,
                bounds: record.bounds(),
                crown_center: record.crown_center(),
                line_errors: (line_error(min_radius), line_error(max_radius)),
                compact: CompactSpecies::build_placed(record)?,
                impostor,
                line_calibration: record.line_calibration,
            },
            Some(Arc::new(record.clone())),
            OnceLock::new(),
        )
    }

    /// The flattened record (merge forest, needles, errors) the CPU-side
    /// cuts, the overlay's counts and `conifer eval` use. A tree of shared
    /// prototypes is flattened on the first call (a fraction of a second
    /// for millions of needles), then kept.
    pub fn record(&self) -> &Arc<LodRecord> {
        self.flat.get_or_init(|| {
            let prototypes = self
                .prototypes
                .as_ref()
                .expect("a species without prototypes has its flat record from the start");
            // `PrototypeRecord::from_parts` checks every invariant of the
            // flattened tree (placed needles valid, their count bounded,
            // the level-2 forest monotone); the `record_decode` fuzz target
            // asserts that every decoded record flattens.
            Arc::new(prototypes.flatten().expect("a valid tree of prototypes flattens"))
        })
    }

    /// The tree of shared prototypes the species was loaded from (`None`
    /// for a flat record).
    pub fn prototypes(&self) -> Option<&Arc<PrototypeRecord>> {
        self.prototypes.as_ref()
    }

    /// The species with its crown impostor baked again with `options`
    /// (the constructors take the record's own, else bake
    /// [`ImpostorOptions::default`]: 8 views, 10 cm texels): finer texels for a tree seen large from far away, coarser
    /// ones to save memory, or a tree that turns into its impostor at
    /// another pixel error (the fade follows the texel,
    /// [`crate::model::impostor::FADE_START`]).
    pub fn with_impostor(mut self, options: ImpostorOptions) -> Self {
        (self.impostor, self.trunk) = match &self.prototypes {
            Some(prototypes) => {
                let impostor = bake_impostor(prototypes, options);
                let trunk = trunk_profile(&prototypes.wood, impostor.as_deref());
                (impostor, trunk)
            }
            None => {
                let record = self.record();
                let impostor =
                    CrownImpostor::bake(&record.needles, &record.wood, &record.wood_mesh, options).map(Arc::new);
                let trunk = trunk_profile(&record.wood, impostor.as_deref());
                (impostor, trunk)
            }
        };
        self
    }

    fn from_flat(mut record: LodRecord) -> Result<Self, ConiferLoadError> {
        // The record's own impostor (baked with it), else one baked now.
        let impostor = record.impostor.take().or_else(|| {
            CrownImpostor::bake(
                &record.needles,
                &record.wood,
                &record.wood_mesh,
                ImpostorOptions::default(),
            )
            .map(Arc::new)
        });
        let ranges = record.part_ranges();
        let parts = SpeciesParts {
            material: record.material,
            needle_count: record.needle_count() as u64,
            wood: &record.wood,
            bounds: record.bounds(),
            crown_center: record.crown_center(),
            line_errors: (ranges.original_lines.min, ranges.original_lines.max),
            compact: CompactSpecies::build(&record)?,
            impostor,
            line_calibration: record.line_calibration,
        };
        let species = Self::new(parts, None, OnceLock::new())?;
        let _ = species.flat.set(Arc::new(record));
        Ok(species)
    }

    fn new(
        parts: SpeciesParts<'_>,
        prototypes: Option<Arc<PrototypeRecord>>,
        flat: OnceLock<Arc<LodRecord>>,
    ) -> Result<Self, ConiferLoadError> {
        let (lo, hi) = parts.bounds;
        let margin = Vec3::splat(parts.line_errors.1 * 0.5);
        let (lo, hi) = (lo - margin, hi + margin);
        let crown_center = parts.crown_center;
        let foot = parts
            .wood
            .iter()
            .map(|w| w.start)
            .filter(|p| p.is_finite())
            .min_by(|a, b| a.y.total_cmp(&b.y))
            .unwrap_or(crown_center);
        Ok(Self {
            prototypes,
            flat: Arc::new(flat),
            material: parts.material,
            needle_count: parts.needle_count,
            max_wood_error: parts.wood.iter().map(wood_segment_error).fold(0.0, f32::max),
            aabb: Aabb::from_min_max(lo, hi),
            crown_center,
            wind_shape: WindShape::from_bounds(lo, hi, Vec2::new(foot.x, foot.z)),
            max_line_error: parts.line_errors.1,
            min_line_error: parts.line_errors.0,
            compact: Arc::new(parts.compact),
            trunk: trunk_profile(parts.wood, parts.impostor.as_deref()),
            impostor: parts.impostor,
            line_calibration: parts.line_calibration,
        })
    }
}

/// The trunk of `wood` over `impostor`'s height (none without one).
fn trunk_profile(wood: &[WoodSegment], impostor: Option<&CrownImpostor>) -> TrunkProfile {
    impostor.map_or_else(TrunkProfile::default, |impostor| {
        TrunkProfile::of(wood, impostor.bottom, impostor.top())
    })
}

/// What a species needs of its record, flat or of prototypes.
struct SpeciesParts<'a> {
    material: FoliageMaterial,
    needle_count: u64,
    wood: &'a [WoodSegment],
    /// Bounds of needles and wood.
    bounds: (Vec3, Vec3),
    crown_center: Vec3,
    /// Smallest and largest original-line error `2R`.
    line_errors: (f32, f32),
    compact: CompactSpecies,
    impostor: Option<Arc<CrownImpostor>>,
    line_calibration: Option<LineCalibration>,
}

/// Trunk and branches as one ordinary mesh: the wood segments as open
/// truncated cones of `sides` sides with smooth normals, plus imported wood
/// triangles (the plugin draws segments as LOD prisms and uses this only
/// for imported triangles).
pub fn wood_mesh(segments: &[WoodSegment], triangles: &TriangleMesh, sides: u32) -> Mesh {
    let mut mesh = triangles.clone();
    for segment in segments {
        append_wood_segment(&mut mesh, segment, sides);
    }
    triangle_mesh(&mesh)
}

/// A model [`TriangleMesh`] as a Bevy triangle-list mesh (positions,
/// normals, `u32` indices), for the render world only.
pub fn triangle_mesh(mesh: &TriangleMesh) -> Mesh {
    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = mesh.normals.iter().map(|n| n.to_array()).collect();
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
        .with_inserted_indices(Indices::U32(mesh.indices.clone()))
}
