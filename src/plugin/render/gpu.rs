//! The compact render path's GPU structs, mirrors of
//! `compact_types.wgsl` (plain `#[repr(C)]`, uploaded as bytes).

use crate::model::compact::CompactSpecies;
use bytemuck::{Pod, Zeroable};

/// Parts of a species, each drawn by one multi-draw-indirect (one draw per
/// tree) from its own block of indirect arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PartKind {
    /// Needles as prisms (opaque).
    Prisms,
    /// Original lines (blended).
    OriginalLines,
    /// Merged lines (blended).
    MergedLines,
    /// Wood segments as tapered prisms (opaque).
    WoodPrisms,
    /// Wood segments as fading lines (blended).
    WoodLines,
    /// The imported wood mesh (opaque).
    WoodMesh,
}

impl PartKind {
    /// Every part, in the order of the indirect-argument blocks.
    pub const ALL: [PartKind; 6] = [
        PartKind::Prisms,
        PartKind::OriginalLines,
        PartKind::MergedLines,
        PartKind::WoodPrisms,
        PartKind::WoodLines,
        PartKind::WoodMesh,
    ];

    /// Index of the part's block of indirect arguments (`KIND_*` in WGSL).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Whether the part is drawn as blended lines.
    pub fn is_lines(self) -> bool {
        matches!(
            self,
            PartKind::OriginalLines | PartKind::MergedLines | PartKind::WoodLines
        )
    }

    /// The shader definition that selects the part's vertex function.
    pub fn shader_def(self) -> &'static str {
        match self {
            PartKind::Prisms => "CONIFER_PRISMS",
            PartKind::OriginalLines => "CONIFER_ORIGINAL_LINES",
            PartKind::MergedLines => "CONIFER_MERGED_LINES",
            PartKind::WoodPrisms => "CONIFER_WOOD_PRISMS",
            PartKind::WoodLines => "CONIFER_WOOD_LINES",
            PartKind::WoodMesh => "CONIFER_WOOD_MESH",
        }
    }

    /// Whether `species` has anything this part could draw.
    pub fn present_in(self, species: &CompactSpecies) -> bool {
        match self {
            PartKind::Prisms => !species.needles.is_empty(),
            PartKind::OriginalLines => !species.original_lines.is_empty(),
            PartKind::MergedLines => !species.merged_lines.is_empty(),
            PartKind::WoodPrisms | PartKind::WoodLines => !species.wood_segments.is_empty(),
            PartKind::WoodMesh => !species.wood_indices.is_empty(),
        }
    }
}

/// `KIND_COUNT` in WGSL.
pub const PART_KINDS: usize = PartKind::ALL.len();

/// Instance flag: drawn at all (the tree's inherited visibility).
pub const FLAG_VISIBLE: u32 = 1;
/// Shift of the instance's opacity-rule override (0 none, 1 paper, 2 area).
pub const OPACITY_OVERRIDE_SHIFT: u32 = 1;
/// Instance flag: `pixel_error` overrides the global setting.
pub const FLAG_PIXEL_ERROR_OVERRIDE: u32 = 8;
/// Instance flag: `transition` overrides the global setting.
pub const FLAG_TRANSITION_OVERRIDE: u32 = 16;

/// One tree (`Instance` in WGSL), 64 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct GpuInstance {
    /// Rows of the affine part of `world_from_local`.
    pub rows: [[f32; 4]; 3],
    /// Pixel error override (with [`FLAG_PIXEL_ERROR_OVERRIDE`]).
    pub pixel_error: f32,
    /// Transition override (with [`FLAG_TRANSITION_OVERRIDE`]).
    pub transition: f32,
    /// [`FLAG_VISIBLE`], the overrides' flags and the opacity-rule override.
    pub flags: u32,
    /// Render layers 0–31 the tree is on.
    pub layers: u32,
}

/// A species' constants (`SpeciesParams` in WGSL), 176 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct SpeciesParams {
    /// Crown centre (xyz) and the radius round it that holds the tree (w).
    pub crown_center: [f32; 4],
    /// Needle grid: origin, step.
    pub grid: [f32; 4],
    /// Wood mesh grid: origin, step.
    pub wood_grid: [f32; 4],
    /// Linear needle colour.
    pub needle_color: [f32; 4],
    /// Linear wood colour.
    pub wood_color: [f32; 4],
    /// Needles.
    pub needle_count: u32,
    /// Entries of the original-line order.
    pub original_line_count: u32,
    /// Merged lines.
    pub merged_line_count: u32,
    /// Wood segments.
    pub wood_segment_count: u32,
    /// Wood mesh indices.
    pub wood_index_count: u32,
    /// Trees of the species.
    pub instance_count: u32,
    /// `Lmax`.
    pub max_sides: u32,
    /// Vertices of one `Lmax`-slot prism drawn without indices.
    pub prism_vertices: u32,
    /// Smallest merged-line error code.
    pub merged_code_min: u32,
    /// Largest merged-line error code.
    pub merged_code_max: u32,
    /// 0: LOD off.
    pub lod_enabled: u32,
    /// 1: colour by representation.
    pub debug_colors: u32,
    /// Global pixel error ε.
    pub pixel_error: f32,
    /// Global transition δ.
    pub transition: f32,
    /// Global opacity rule (0 paper, 1 area-preserving).
    pub opacity_rule: u32,
    /// `gpu_layout::WOOD_LINE_FADE`.
    pub wood_line_fade: f32,
    /// Perceptual roughness.
    pub roughness: f32,
    /// Reflectance.
    pub reflectance: f32,
    /// Padding to 16 bytes.
    pub padding: [u32; 2],
}

/// A view as the compute pass sees it (`CullView` in WGSL), 128 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct CullView {
    /// Frustum planes, normals pointing inside.
    pub planes: [[f32; 4]; 6],
    /// Position of the view (w unused).
    pub world_position: [f32; 4],
    /// `2 / (P₁₁ · H)`.
    pub error_slope: f32,
    /// 1 for a perspective view.
    pub perspective: u32,
    /// Render layers 0–31 the view sees.
    pub layers: u32,
    /// Padding.
    pub padding: u32,
}

/// What the compute pass writes per tree and view (`InstanceLod`), 16 bytes.
pub const INSTANCE_LOD_BYTES: u64 = 16;
/// One indirect draw (`DrawArgs`), 16 bytes.
pub const DRAW_ARGS_BYTES: u64 = 16;

/// Vertices of an `Lmax`-slot prism drawn without indices: `Lmax` side
/// quads and two `(Lmax − 2)`-triangle caps.
pub fn prism_vertices(max_sides: u8) -> u32 {
    let m = u32::from(max_sides.max(3));
    6 * m + 6 * (m - 2)
}
