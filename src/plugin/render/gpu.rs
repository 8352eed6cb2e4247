//! The compact render path's GPU structs, mirrors of
//! `compact_types.wgsl` (plain `#[repr(C)]`, uploaded as bytes).

use crate::model::compact::{CompactPlacement, CompactPrototype, CompactSpecies, PLACED_BANDS};
use bytemuck::{Pod, Zeroable};

/// Parts of a species, each drawn by one multi-draw-indirect from its own
/// block of indirect arguments: one draw per tree for the tree's own
/// parts, one instanced draw per prototype and band for the placed ones.
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
    /// The far tree's crown impostor: one camera-facing quad (blended).
    Impostor,
    /// Expanded placements' needles as prisms (opaque).
    PlacedPrisms,
    /// Expanded placements' original lines (blended).
    PlacedOriginalLines,
    /// Expanded placements' level-1 merged lines (blended).
    PlacedMergedLines,
}

impl PartKind {
    /// Every part, in the order of the indirect-argument blocks.
    pub const ALL: [PartKind; 10] = [
        PartKind::Prisms,
        PartKind::OriginalLines,
        PartKind::MergedLines,
        PartKind::WoodPrisms,
        PartKind::WoodLines,
        PartKind::WoodMesh,
        PartKind::Impostor,
        PartKind::PlacedPrisms,
        PartKind::PlacedOriginalLines,
        PartKind::PlacedMergedLines,
    ];

    /// Index of the part in [`PartKind::ALL`]; for the tree's own parts,
    /// of its block of per-tree indirect arguments (`KIND_*` in WGSL).
    pub fn index(self) -> usize {
        self as usize
    }

    /// For a placed part, the index of its block of per-draw arguments
    /// (`PLACED_*` in WGSL).
    pub fn placed_index(self) -> Option<usize> {
        self.index().checked_sub(TREE_PART_KINDS)
    }

    /// Whether the part is drawn as blended lines.
    pub fn is_lines(self) -> bool {
        matches!(
            self,
            PartKind::OriginalLines
                | PartKind::MergedLines
                | PartKind::WoodLines
                | PartKind::PlacedOriginalLines
                | PartKind::PlacedMergedLines
        )
    }

    /// Whether the part is blended (drawn in the transparent phase): the
    /// lines and the impostor.
    pub fn is_blended(self) -> bool {
        self.is_lines() || self == PartKind::Impostor
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
            PartKind::Impostor => "CONIFER_IMPOSTOR",
            PartKind::PlacedPrisms => "CONIFER_PRISMS",
            PartKind::PlacedOriginalLines => "CONIFER_ORIGINAL_LINES",
            PartKind::PlacedMergedLines => "CONIFER_MERGED_LINES",
        }
    }

    /// Whether `species` has anything this part could draw.
    pub fn present_in(self, species: &CompactSpecies) -> bool {
        match self {
            PartKind::Prisms => species.tree_counts[0] > 0 && species.prototypes.is_empty(),
            PartKind::OriginalLines => species.tree_counts[1] > 0,
            PartKind::MergedLines => species.tree_counts[2] > 0,
            PartKind::WoodPrisms | PartKind::WoodLines => !species.wood_segments.is_empty(),
            PartKind::WoodMesh => !species.wood_indices.is_empty(),
            // Whether the species has an impostor is the caller's to check
            // (it is not part of the compact arrays).
            PartKind::Impostor => true,
            PartKind::PlacedPrisms => !species.placements.is_empty(),
            PartKind::PlacedOriginalLines => species.prototypes.iter().any(|p| p.needles[1] > 1),
            PartKind::PlacedMergedLines => species.prototypes.iter().any(|p| p.merged_lines[1] > 0),
        }
    }
}

/// Every part (the phase keys of a species).
pub const PART_KINDS: usize = PartKind::ALL.len();

/// The tree's own parts, drawn once per tree (`KIND_COUNT` in WGSL).
pub const TREE_PART_KINDS: usize = 7;

/// The placed parts, drawn once per prototype and band (`PLACED_KINDS` in WGSL).
pub const PLACED_PART_KINDS: usize = PART_KINDS - TREE_PART_KINDS;

/// Instance flag: drawn at all (the tree's inherited visibility).
pub const FLAG_VISIBLE: u32 = 1;
/// Shift of the instance's opacity-rule override (0 none, 1 paper, 2 area).
pub const OPACITY_OVERRIDE_SHIFT: u32 = 1;
/// Instance flag: `pixel_error` overrides the global setting.
pub const FLAG_PIXEL_ERROR_OVERRIDE: u32 = 8;
/// Instance flag: `transition` overrides the global setting.
pub const FLAG_TRANSITION_OVERRIDE: u32 = 16;
/// Instance flag: the tree's own choice of the far impostor overrides the
/// global setting ...
pub const FLAG_IMPOSTOR_OVERRIDE: u32 = 32;
/// ... and it is to draw it.
pub const FLAG_IMPOSTOR_ON: u32 = 64;

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

/// A species' constants (`SpeciesParams` in WGSL), 5,152 bytes.
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct SpeciesParams {
    /// Crown centre (xyz) and the radius round it that holds the tree (w).
    pub crown_center: [f32; 4],
    /// Needle grid: origin, step.
    pub grid: [f32; 4],
    /// Wood grid (segment ends and mesh vertices): origin, step.
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
    /// `prism::WOOD_LINE_FADE`.
    pub wood_line_fade: f32,
    /// Perceptual roughness.
    pub roughness: f32,
    /// Reflectance.
    pub reflectance: f32,
    /// Placements (0 for a flat species).
    pub placement_count: u32,
    /// Prototypes (0 for a flat species).
    pub prototype_count: u32,
    /// Needles of the tree's own section and the prototypes'.
    pub total_needle_count: u32,
    /// 1: view-dependent detail ([`crate::plugin::ErrorScope::Placement`]).
    pub error_scope: u32,
    /// Wind seconds from the previous frame's clocks to these: the motion
    /// vector pass winds the oscillators back by it (each runs at a fixed
    /// rate, [`crate::model::wind::WindClock::at`]).
    pub wind_step: f32,
    /// The widest of `crown_radii` (tree metres): the upright cylinder
    /// the crown's shade on itself is looked for in
    /// ([`crate::model::crown_shade::CrownShade::widest_radius`]).
    pub crown_widest_radius: f32,
    /// A sphere holding every node's sphere and the wood (tree-local centre, radius).
    pub tree_sphere: [f32; 4],
    /// The crown impostor's axis (tree-local x, z), half width and texel
    /// side, metres.
    pub impostor_box: [f32; 4],
    /// Its bottom and top heights, its views, and 0 without an impostor,
    /// 1 with one off by default, 2 with one on by default.
    pub impostor_span: [f32; 4],
    /// The tangents of the camera elevations across which the impostor
    /// gives way to the lines ([`crate::model::impostor::SteepFade`]:
    /// start, end); z, w unused.
    pub impostor_steep: [f32; 4],
    /// Linear colour of this year's needles
    /// ([`crate::model::FoliageMaterial::young_needle_color`]).
    pub young_needle_color: [f32; 4],
    /// Linear colour of a shoot's lower side.
    pub needle_underside_color: [f32; 4],
    /// Linear colour of the upper bark.
    pub upper_wood_color: [f32; 4],
    /// Linear colour of needles without a placement's age
    /// ([`crate::model::compact::CompactSpecies::far_needle_color`]).
    pub far_needle_color: [f32; 4],
    /// Where the bark turns (tree-local heights, x to y); z, w unused.
    pub wood_heights: [f32; 4],
    /// The wind ([`crate::model::wind::Wind`]): unit direction (world x,
    /// z), strength (0: calm, nothing moves), gustiness.
    pub wind: [f32; 4],
    /// Turbulence, the reach ([`crate::model::wind::wind_reach`], tree
    /// metres) that culling and error spheres grow by, the trunk and
    /// branch oscillators (radians, [`crate::model::wind::WindClock`]).
    pub wind_motion: [f32; 4],
    /// The flutter and two gust oscillators (radians), the crown radius.
    pub wind_clock: [f32; 4],
    /// The trunk axis (tree-local x, z), the tree's base height and height
    /// ([`crate::model::wind::WindShape`]).
    pub wind_shape: [f32; 4],
    /// A sphere's mean diffuse by the angle between the viewer and the
    /// light ([`crate::model::shading::SphereLight::diffuse`], four
    /// angles a row).
    pub sphere_diffuse: [[f32; 4]; SPHERE_LIGHT_ROWS],
    /// Its mean specular ([`crate::model::shading::SphereLight::specular`]).
    pub sphere_specular: [[f32; 4]; SPHERE_LIGHT_ROWS],
    /// The impostor's crown radius (tree metres) at
    /// [`crate::model::impostor::CROWN_PROFILE_STEPS`] heights, four a
    /// row ([`crate::model::impostor::CrownImpostor::crown_radii`]): where
    /// a texel's ray enters the crown, for its shadow samples.
    pub crown_radii: [[f32; 4]; CROWN_RADII_ROWS],
    /// The extinction (per tree metre) of the crown's
    /// [`crate::model::crown_shade::CROWN_SHADE_CLASSES`] media at the same
    /// heights, a row a height
    /// ([`crate::model::impostor::CrownImpostor::crown_extinction`]): the
    /// crown's shade on itself past the shadow maps
    /// ([`crate::model::crown_shade`]).
    pub crown_extinction:
        [[f32; crate::model::crown_shade::CROWN_SHADE_CLASSES]; crate::model::impostor::CROWN_PROFILE_STEPS],
    /// The lines' opacity scales by pixel size
    /// ([`crate::model::calibration::LineCalibration::scales`], four a
    /// row; all 1 without a calibration).
    pub line_scales: [[f32; 4]; LINE_SCALE_ROWS],
    /// Where a pixel size falls in them
    /// ([`crate::model::calibration::LineCalibration::log_range`]); z, w
    /// unused.
    pub line_scale_range: [f32; 4],
    /// The share of the wood the needles leave in sight where they cover
    /// the picture, by height and nearness, four a row
    /// ([`crate::model::impostor::WoodVisibility::shares`], heights
    /// major): the opacity of the wood lines' second draw, after the
    /// foliage lines.
    pub wood_visibility: [[f32; 4]; WOOD_VISIBILITY_ROWS],
    /// The wood lines' opacity scales at the pixel sizes of
    /// `line_scales` (rows) and
    /// [`crate::model::calibration::WOOD_OPACITY_NODES`] opacities
    /// ([`crate::model::calibration::LineCalibration::wood_scales`]; all 1
    /// without a calibration).
    pub wood_line_scales:
        [[f32; crate::model::calibration::WOOD_OPACITY_NODES]; crate::model::calibration::CALIBRATION_STEPS],
    /// The share of the sky each point of the crown sees through it, by
    /// height (rows) and distance from the axis (lanes)
    /// ([`crate::model::crown_shade::SkyVisibility`]): what the ambient
    /// light is scaled by. All 1 (nothing occluded) unless
    /// [`crate::plugin::ConiferLodSettings::sky_occlusion`] is on.
    pub sky_visibility:
        [[f32; crate::model::crown_shade::SKY_VISIBILITY_RINGS]; crate::model::impostor::CROWN_PROFILE_STEPS],
    /// How densely the needles fill the crown, by height and ring, four a
    /// row ([`crate::model::impostor::CrownDensity::rings`], heights
    /// major): where an impostor texel's shadow samples go
    /// ([`crate::model::impostor::shadow_sample_depths`]).
    pub crown_density: [[f32; 4]; CROWN_DENSITY_ROWS],
    /// The trunk at the crown profile's heights: its centre (tree-local
    /// x, z) and radius (0: none there), w unused
    /// ([`crate::model::impostor::TrunkProfile`]): where the impostor
    /// lights its wood as the round stem.
    pub trunk: [[f32; 4]; crate::model::impostor::CROWN_PROFILE_STEPS],
    /// What the impostor's direct light is scaled by, by the light's
    /// direction in the view's frame, angle major, four a row
    /// ([`crate::model::impostor::ViewLightScale`]; all 1 for an older
    /// record): its texels lit as the needles its views show.
    pub view_light_scale: [[f32; 4]; VIEW_LIGHT_SCALE_ROWS],
}

impl Default for SpeciesParams {
    /// Every field zero (the tables are too long to derive it).
    fn default() -> Self {
        Zeroable::zeroed()
    }
}

/// Rows of four shares that hold a
/// [`crate::model::impostor::WoodVisibility`].
pub const WOOD_VISIBILITY_ROWS: usize =
    crate::model::impostor::CROWN_PROFILE_STEPS * crate::model::impostor::WOOD_NEARNESS_BINS / 4;

/// Rows of four densities that hold a
/// [`crate::model::impostor::CrownDensity`].
pub const CROWN_DENSITY_ROWS: usize =
    crate::model::impostor::CROWN_PROFILE_STEPS * crate::model::impostor::CROWN_DENSITY_RINGS / 4;

/// Rows of four scales that hold a
/// [`crate::model::calibration::LineCalibration`].
pub const LINE_SCALE_ROWS: usize = crate::model::calibration::CALIBRATION_STEPS / 4;

/// Rows of four heights that hold a
/// [`crate::model::impostor::CrownImpostor::crown_radii`] profile.
pub const CROWN_RADII_ROWS: usize = crate::model::impostor::CROWN_PROFILE_STEPS / 4;

/// Rows of four scales that hold a
/// [`crate::model::impostor::ViewLightScale`].
pub const VIEW_LIGHT_SCALE_ROWS: usize = crate::model::impostor::ViewLightScale::LEN.div_ceil(4);

/// Rows of four angles that hold a [`crate::model::shading::SphereLight`]
/// table.
pub const SPHERE_LIGHT_ROWS: usize = crate::model::shading::SPHERE_LIGHT_STEPS / 4;

/// `values` four a row, as the shader's `array<vec4<f32>, ROWS>` tables
/// hold them (entry `k` at row `k / 4`, lane `k % 4`); lanes past the end
/// of `values` stay 0.
fn four_a_row<const ROWS: usize>(values: &[f32]) -> [[f32; 4]; ROWS] {
    let mut rows = [[0.0; 4]; ROWS];
    for (k, &value) in values.iter().take(4 * ROWS).enumerate() {
        rows[k / 4][k % 4] = value;
    }
    rows
}

impl SpeciesParams {
    /// Sets the sphere light table: how the needles an impostor texel or a
    /// merged line lights as a sphere send each light toward the viewer.
    pub fn set_sphere_light(&mut self, table: &crate::model::shading::SphereLight) {
        self.sphere_diffuse = four_a_row(&table.diffuse);
        self.sphere_specular = four_a_row(&table.specular);
    }

    /// Sets the needle and the wood lines' opacity scales by pixel size
    /// (`None`: every scale 1).
    pub fn set_line_calibration(&mut self, calibration: Option<&crate::model::calibration::LineCalibration>) {
        use crate::model::calibration::{CALIBRATION_STEPS, WOOD_OPACITY_NODES};
        let (scales, wood_scales, range) = match calibration {
            Some(c) => (c.scales, c.wood_scales, c.log_range()),
            None => (
                [1.0; CALIBRATION_STEPS],
                [[1.0; WOOD_OPACITY_NODES]; CALIBRATION_STEPS],
                [0.0, 1.0],
            ),
        };
        self.line_scales = four_a_row(&scales);
        self.wood_line_scales = wood_scales;
        self.line_scale_range = [range[0], range[1], 0.0, 0.0];
    }

    /// Sets the impostor's crown radius and extinction by height
    /// ([`crate::model::crown_shade::CrownShade`]; its axis and span are
    /// the impostor's box and span).
    pub fn set_crown_shade(&mut self, shade: &crate::model::crown_shade::CrownShade) {
        self.crown_radii = four_a_row(&shade.radii);
        self.crown_widest_radius = shade.widest_radius();
        self.crown_extinction = shade.extinction;
    }

    /// Sets the share of the sky the crown lets each point see
    /// ([`crate::model::crown_shade::SkyVisibility`]).
    pub fn set_sky_visibility(&mut self, sky: &crate::model::crown_shade::SkyVisibility) {
        self.sky_visibility = sky.rows;
    }

    /// Sets the share of the wood the needles leave in sight where they
    /// cover the picture ([`crate::model::impostor::WoodVisibility`]).
    pub fn set_wood_visibility(&mut self, visibility: &crate::model::impostor::WoodVisibility) {
        self.wood_visibility = four_a_row(visibility.shares.as_flattened());
    }

    /// Sets the trunk the impostor lights as a round stem
    /// ([`crate::model::impostor::TrunkProfile`]).
    pub fn set_trunk(&mut self, trunk: &crate::model::impostor::TrunkProfile) {
        for (row, (centre, radius)) in self.trunk.iter_mut().zip(trunk.centres.iter().zip(trunk.radii)) {
            *row = [centre.x, centre.y, radius, 0.0];
        }
    }

    /// Sets what the impostor's direct light is scaled by (`None`: every
    /// scale 1, its texels lit as their shares say).
    pub fn set_view_light_scale(&mut self, scale: Option<&crate::model::impostor::ViewLightScale>) {
        let scale = scale.copied().unwrap_or_default();
        self.view_light_scale = four_a_row(&scale.to_vec());
    }

    /// Sets how densely the needles fill the crown
    /// ([`crate::model::impostor::CrownDensity`]).
    pub fn set_crown_density(&mut self, density: &crate::model::impostor::CrownDensity) {
        self.crown_density = four_a_row(density.rings.as_flattened());
    }

    /// Sets the wind fields: `wind` over a tree of `shape` at `seconds`,
    /// `step` seconds after the previous frame's (0 on the first frame; a
    /// non-finite step is 0).
    pub fn set_wind(
        &mut self,
        wind: &crate::model::wind::Wind,
        shape: &crate::model::wind::WindShape,
        seconds: f64,
        step: f64,
    ) {
        self.wind_step = if step.is_finite() { step as f32 } else { 0.0 };
        let w = wind.clamped();
        let clock = crate::model::wind::WindClock::at(seconds, shape);
        let reach = crate::model::wind::wind_reach(&w, shape);
        self.wind = [w.direction.x, w.direction.y, w.strength, w.gustiness];
        self.wind_motion = [w.turbulence, reach, clock.trunk, clock.branch];
        self.wind_clock = [clock.flutter, clock.gust[0], clock.gust[1], shape.crown_radius];
        self.wind_shape = [shape.axis.x, shape.axis.y, shape.base, shape.height];
    }
}

/// [`CullView::perspective`] flag: the view is a camera (a shadow view
/// never draws impostors).
pub const VIEW_CAMERA: u32 = 2;

/// [`CullView::perspective`] flag: the view draws its lines as quads, six
/// vertices a line ([`crate::plugin::LineRaster::Area`]; cameras only).
pub const VIEW_LINE_QUADS: u32 = 4;

/// [`CullView::perspective`] flag: the view draws each expanded
/// placement's lines on their own, back to front (a camera under
/// [`crate::plugin::LineOrder::BackToFront`] with room for placements).
pub const VIEW_DEPTH_ORDERED: u32 = 8;

/// A view as the compute pass sees it (`CullView` in WGSL), 144 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct CullView {
    /// Frustum planes, normals pointing inside.
    pub planes: [[f32; 4]; 6],
    /// Position of the view; w the factor its trees' pixel error is
    /// multiplied by (1 in a camera; in a shadow view
    /// [`crate::plugin::ConiferLodSettings::shadow_error_factor`], so its
    /// cut is that much coarser and its lines' opacities still take the
    /// view's own texel as their pixel).
    pub world_position: [f32; 4],
    /// `2 / (P₁₁ · H)`.
    pub error_slope: f32,
    /// 1 for a perspective view, plus [`VIEW_CAMERA`] for a camera, plus
    /// [`VIEW_LINE_QUADS`] where it draws lines as quads, plus
    /// [`VIEW_DEPTH_ORDERED`] where it draws its lines back to front.
    pub perspective: u32,
    /// Render layers 0–31 the view sees.
    pub layers: u32,
    /// Expanded placements the view's entry buffers hold.
    pub entry_capacity: u32,
    /// Where the view's expansion budget is ranked from: a directional
    /// light's cascade gives it to the trees nearest the camera it serves
    /// (xyz that camera's position, w its `2 / (P₁₁ · H)`); w = 0 ranks by
    /// the view's own spatial error.
    pub budget_origin: [f32; 4],
}

/// What the compute pass writes per tree and view (`InstanceLod`), 32
/// bytes: code, spatial error, pixel error, transition, and the view point
/// (the camera in the tree's frame and the error per metre of distance).
pub const INSTANCE_LOD_BYTES: u64 = 32;
/// One indirect draw (`DrawArgs`), 16 bytes.
pub const DRAW_ARGS_BYTES: u64 = 16;

/// Bytes of one entry's split of its back-to-front line draw (where its
/// merged lines end, where its original lines start).
pub const ORDERED_SPLIT_BYTES: u64 = 8;

/// A prototype of a placed species (`Prototype` in WGSL), 96 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct GpuPrototype {
    /// Its needle grid: origin, step.
    pub grid: [f32; 4],
    /// First entry and length of its needles, original-line order and
    /// merged lines.
    pub sections: [u32; 6],
    /// Its needles' upper side ([`crate::model::color::upper_side`]), x, y,
    /// z as signed normalized bytes (WGSL's `unpack4x8snorm`).
    pub upper_side: u32,
    /// First entry of its merged lines by own code in the line-order
    /// buffer (the original-line order, then
    /// [`CompactSpecies::merged_by_own`]).
    pub merged_by_own_first: u32,
    /// Band edges, two 16-bit codes a word (the last half-word unused).
    pub band_edges: [u32; PLACED_BANDS as usize / 2],
    /// Bounding sphere, prototype metres (centre, radius).
    pub sphere: [f32; 4],
}

impl GpuPrototype {
    /// The GPU form of `prototype` of `species`.
    pub fn new(species: &CompactSpecies, prototype: &CompactPrototype) -> Self {
        let mut band_edges = [u32::from(u16::MAX) << 16; PLACED_BANDS as usize / 2];
        for (b, &edge) in prototype.band_edges.iter().enumerate() {
            let word = &mut band_edges[b / 2];
            let shift = 16 * (b % 2);
            *word = (*word & !(0xffff << shift)) | u32::from(edge) << shift;
        }
        let [n0, n1] = prototype.needles;
        let [o0, o1] = prototype.original_lines;
        let [m0, m1] = prototype.merged_lines;
        Self {
            grid: prototype.grid.origin.extend(prototype.grid.step).to_array(),
            sections: [n0, n1, o0, o1, m0, m1],
            upper_side: pack_snorm8(prototype.upper_side.extend(0.0).to_array()),
            merged_by_own_first: species.original_lines.len() as u32 + prototype.merged_by_own,
            band_edges,
            sphere: prototype.sphere.to_array(),
        }
    }
}

/// A placement (`Placement` in WGSL), 48 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct GpuPlacement {
    /// Rotation quaternion (x, y, z, w).
    pub rotation: [f32; 4],
    /// Translation (xyz), uniform scale (w).
    pub translation_scale: [f32; 4],
    /// Prototype index.
    pub prototype: u32,
    /// Parent error code of its root line.
    pub parent_code: u32,
    /// Index of that parent's sphere in the tree's spheres
    /// ([`crate::model::compact::NO_SPHERE`] for a root).
    pub parent_sphere: u32,
    /// Age of its needles, years ([`crate::model::Placement::needle_age`]).
    pub needle_age: u32,
}

impl GpuPlacement {
    /// The GPU form of `placement`.
    pub fn new(placement: &CompactPlacement) -> Self {
        let t = &placement.transform;
        Self {
            rotation: t.rotation.to_array(),
            translation_scale: t.translation.extend(t.scale).to_array(),
            prototype: placement.prototype,
            parent_code: u32::from(placement.parent_code),
            parent_sphere: placement.parent_sphere,
            needle_age: u32::from(placement.transform.needle_age),
        }
    }
}

/// Four numbers in `[−1, 1]` as signed normalized bytes, the first in the
/// lowest byte (WGSL's `pack4x8snorm`).
pub fn pack_snorm8(values: [f32; 4]) -> u32 {
    values.iter().enumerate().fold(0u32, |word, (k, &v)| {
        let byte = (v.clamp(-1.0, 1.0) * 127.0).round() as i8 as u8;
        word | u32::from(byte) << (8 * k)
    })
}

/// One expanded placement of one view (`vec2<u32>` in WGSL), 8 bytes: its
/// tree (30 bits), the merged-lines-by-own-code flag (bit 30) and the
/// original-lines-from-needles flag (bit 31), then
/// the placement index (16 bits) and its threshold code (16 bits).
pub const PLACED_ENTRY_BYTES: u64 = 8;

/// Words of a view's placement counters before the per-draw arrays: five
/// counters of the expansion budget, three spare, and the demand of each
/// of its [`crate::model::compact::BUDGET_BUCKETS`] buckets
/// (`conifer_cull.wgsl`'s `budget_demand`, `budget_cutoff`).
pub const PLACED_COUNTER_HEADER: u64 = 8 + crate::model::compact::BUDGET_BUCKETS as u64;

/// Per-draw arrays of a view's placement counters (count, cursor, four
/// longest prefixes, offset, flags, longest merged prefix by own code).
pub const PLACED_COUNTER_ARRAYS: u64 = 9;

/// Words of a view's placement counters after the per-draw arrays: per
/// depth bucket ([`crate::model::compact::DEPTH_BUCKETS`]) its expanded
/// placements, its first rank and its cursor (a camera's back-to-front
/// order of the placements' lines, `conifer_cull.wgsl`).
pub const PLACED_DEPTH_COUNTERS: u64 = 3 * crate::model::compact::DEPTH_BUCKETS as u64;

#[cfg(test)]
mod tests {
    use crate::model::wind;

    /// The shader's copies of `model::wind`'s constants, the bark's, the
    /// depth buckets' and the view flags.
    #[test]
    fn the_shader_has_the_models_constants() {
        let shader = include_str!("conifer_compact.wgsl");
        let scalars = [
            ("WIND_TRUNK_LEAN", wind::TRUNK_LEAN),
            ("WIND_TRUNK_SWAY", wind::TRUNK_SWAY),
            ("WIND_BRANCH_SWAY", wind::BRANCH_SWAY),
            ("WIND_FLUTTER", wind::FLUTTER),
            ("WIND_GUST_WAVELENGTH", wind::GUST_WAVELENGTH),
            ("WIND_MAX_REACH_RATIO", wind::MAX_REACH_RATIO),
            ("WIND_NORMAL_STEP", wind::NORMAL_STEP),
            ("BARK_ROUGHNESS", crate::model::needle::BARK_ROUGHNESS),
        ];
        for (name, value) in scalars {
            let line = format!("const {name}: f32 = {value:?};");
            assert!(shader.contains(&line), "{line}");
        }
        let types = include_str!("compact_types.wgsl");
        for (name, value) in [
            (
                "DEPTH_BUCKETS_PER_OCTAVE",
                crate::model::compact::DEPTH_BUCKETS_PER_OCTAVE,
            ),
            ("DEPTH_NEAREST", crate::model::compact::DEPTH_NEAREST),
        ] {
            let line = format!("const {name}: f32 = {value:?};");
            assert!(types.contains(&line), "{line}");
        }
        let buckets = crate::model::compact::DEPTH_BUCKETS;
        assert!(types.contains(&format!("const DEPTH_BUCKETS: u32 = {buckets}u;")));
        for (name, value) in [
            ("VIEW_CAMERA", super::VIEW_CAMERA),
            ("VIEW_LINE_QUADS", super::VIEW_LINE_QUADS),
            ("VIEW_DEPTH_ORDERED", super::VIEW_DEPTH_ORDERED),
        ] {
            let line = format!("const {name}: u32 = {value}u;");
            assert!(types.contains(&line), "{line}");
        }
        for (name, v) in [
            ("WIND_BRANCH_WAVES", wind::BRANCH_WAVES),
            ("WIND_FLUTTER_WAVES", wind::FLUTTER_WAVES),
        ] {
            let line = format!("const {name}: vec3<f32> = vec3<f32>({:?}, {:?}, {:?});", v.x, v.y, v.z);
            assert!(shader.contains(&line), "{line}");
        }
    }

    /// The shader's view cosines and weights for indirect light are
    /// `model::shading::indirect_nodes`.
    #[test]
    fn the_shader_has_the_indirect_nodes() {
        let shader = include_str!("conifer_compact.wgsl");
        let nodes = crate::model::shading::indirect_nodes();
        let row = |column: fn(&(f32, f32, f32)) -> f32| {
            let values: Vec<String> = nodes.iter().map(|n| format!("{:.8}", column(n))).collect();
            format!("array<f32, 4>({})", values.join(", "))
        };
        for (name, column) in [
            ("cosines", (|n| n.0) as fn(&(f32, f32, f32)) -> f32),
            ("cylinder", |n| n.1),
            ("sphere", |n| n.2),
        ] {
            let line = format!("var {name} = {};", row(column));
            assert!(shader.contains(&line), "{line}");
        }
    }

    /// The shader's table is as long as `model::shading`'s.
    #[test]
    fn the_shader_has_the_sphere_tables_length() {
        let types = include_str!("compact_types.wgsl");
        let steps = crate::model::shading::SPHERE_LIGHT_STEPS;
        assert!(types.contains(&format!("const SPHERE_LIGHT_STEPS: u32 = {steps}u;")));
        let rows = super::SPHERE_LIGHT_ROWS;
        assert_eq!(types.matches(&format!("array<vec4<f32>, {rows}>")).count(), 2);
    }

    /// The Rust mirror is as long as the WGSL struct (16-byte rows).
    #[test]
    fn species_params_is_5152_bytes() {
        assert_eq!(size_of::<super::SpeciesParams>(), 5152);
    }

    /// The shader declares `constant` as `steps` and `field` as `rows`
    /// rows of four.
    fn assert_shader_table(constant: &str, steps: usize, field: &str, rows: usize) {
        let types = include_str!("compact_types.wgsl");
        assert!(types.contains(&format!("const {constant}: u32 = {steps}u;")));
        assert!(types.contains(&format!("{field}: array<vec4<f32>, {rows}>")));
    }

    /// The shader's line scale table is as long as `model::calibration`'s.
    #[test]
    fn the_shader_has_the_line_calibrations_length() {
        let steps = crate::model::calibration::CALIBRATION_STEPS;
        assert_shader_table("LINE_SCALE_STEPS", steps, "line_scales", super::LINE_SCALE_ROWS);
        assert_shader_table("LINE_SCALE_STEPS", steps, "wood_line_scales", steps);
        let nodes = crate::model::calibration::WOOD_OPACITY_NODES;
        assert_eq!(nodes, 4, "a row of the wood table is one vec4");
        assert!(include_str!("compact_types.wgsl").contains(&format!("const WOOD_OPACITY_NODES: u32 = {nodes}u;")));
    }

    /// The shader's view light scale is as long as `model::impostor`'s.
    #[test]
    fn the_shader_has_the_view_light_scales_length() {
        use crate::model::impostor::{VIEW_LIGHT_ANGLES, VIEW_LIGHT_ROLLS};
        assert_shader_table(
            "VIEW_LIGHT_ANGLES",
            VIEW_LIGHT_ANGLES,
            "view_light_scale",
            super::VIEW_LIGHT_SCALE_ROWS,
        );
        let types = include_str!("compact_types.wgsl");
        assert!(types.contains(&format!("const VIEW_LIGHT_ROLLS: u32 = {VIEW_LIGHT_ROLLS}u;")));
    }

    /// The shader's crown profile is as long as `model::impostor`'s.
    #[test]
    fn the_shader_has_the_crown_profiles_length() {
        let steps = crate::model::impostor::CROWN_PROFILE_STEPS;
        assert_shader_table("CROWN_PROFILE_STEPS", steps, "crown_radii", super::CROWN_RADII_ROWS);
        assert_shader_table("CROWN_PROFILE_STEPS", steps, "crown_extinction", steps);
        assert_shader_table("CROWN_PROFILE_STEPS", steps, "crown_density", super::CROWN_DENSITY_ROWS);
        assert_shader_table("CROWN_PROFILE_STEPS", steps, "trunk", steps);
        let types = include_str!("compact_types.wgsl");
        for (constant, value) in [
            ("CROWN_DENSITY_RINGS", crate::model::impostor::CROWN_DENSITY_RINGS),
            ("SHADOW_DEPTH_STEPS", crate::model::impostor::SHADOW_DEPTH_STEPS),
        ] {
            assert!(
                types.contains(&format!("const {constant}: u32 = {value}u;")),
                "{constant}"
            );
        }
        let shade_steps = crate::model::crown_shade::CROWN_SHADE_STEPS;
        assert!(types.contains(&format!("const CROWN_SHADE_STEPS: u32 = {shade_steps}u;")));
        let classes = crate::model::crown_shade::CROWN_SHADE_CLASSES;
        assert_eq!(classes, 4, "a height's media are one vec4");
        assert!(types.contains(&format!("const CROWN_SHADE_CLASSES: u32 = {classes}u;")));
    }

    /// The shader's sky visibility table is as long as `model::crown_shade`'s.
    #[test]
    fn the_shader_has_the_sky_visibilitys_length() {
        let rings = crate::model::crown_shade::SKY_VISIBILITY_RINGS;
        assert_eq!(rings, 4, "a height's rings are one vec4");
        assert!(include_str!("compact_types.wgsl").contains(&format!("const SKY_VISIBILITY_RINGS: u32 = {rings}u;")));
        let steps = crate::model::impostor::CROWN_PROFILE_STEPS;
        assert_shader_table("CROWN_PROFILE_STEPS", steps, "sky_visibility", steps);
    }

    /// The shader draws strips up to `model::raster`'s widest.
    #[test]
    fn the_shader_has_the_widest_strip() {
        let strip = crate::model::raster::MAX_STRIP_WIDTH;
        assert!(include_str!("conifer_compact.wgsl").contains(&format!("const MAX_STRIP_WIDTH: f32 = {strip:.1};")));
        let reach = crate::model::raster::JOINT_REACH;
        assert!(include_str!("conifer_compact.wgsl").contains(&format!("const JOINT_REACH: f32 = {reach:.1};")));
    }

    /// The shaders read a wood segment's joints and radii with the bits
    /// `model::compact` writes.
    #[test]
    fn the_shaders_know_the_wood_joints_bits() {
        use crate::model::compact::{WOOD_JOINED_END, WOOD_JOINED_START, WOOD_RADIUS_CODE_MASK};
        let types = include_str!("compact_types.wgsl");
        for (name, value) in [
            ("WOOD_JOINED_START", WOOD_JOINED_START),
            ("WOOD_JOINED_END", WOOD_JOINED_END),
            ("WOOD_RADIUS_CODE_MASK", WOOD_RADIUS_CODE_MASK),
        ] {
            assert!(types.contains(&format!("const {name}: u32 = {value}u;")), "{name}");
        }
    }

    /// The camera passes' cross-fade dithers by `model::impostor`'s
    /// threshold maps: the pixels' a row a word, a column a byte; the
    /// samples' a byte a pixel, row by row.
    #[test]
    fn the_shaders_dither_the_crossfade_by_the_cpus_map() {
        let shader = include_str!("conifer_compact.wgsl");
        let words: Vec<String> = crate::model::impostor::CROSSFADE_THRESHOLDS
            .iter()
            .map(|row| {
                let word = row.iter().enumerate().fold(0u32, |word, (x, t)| word | (t << (8 * x)));
                format!("0x{word:08x}u")
            })
            .collect();
        let declared = format!(
            "const CROSSFADE_THRESHOLDS: vec4<u32> = vec4<u32>({});",
            words.join(", ")
        );
        assert!(shader.contains(&declared), "{declared}");
        let samples = crate::model::impostor::CROSSFADE_SAMPLE_THRESHOLDS
            .iter()
            .flatten()
            .enumerate()
            .fold(0u32, |word, (k, t)| word | (t << (8 * k)));
        assert!(shader.contains(&format!("const CROSSFADE_SAMPLE_THRESHOLDS: u32 = 0x{samples:08x}u;")));
    }

    /// The shader's wood visibility table is as long as `model::impostor`'s.
    #[test]
    fn the_shader_has_the_wood_visibilitys_length() {
        let types = include_str!("compact_types.wgsl");
        let bins = crate::model::impostor::WOOD_NEARNESS_BINS;
        assert!(types.contains(&format!("const WOOD_NEARNESS_BINS: u32 = {bins}u;")));
        assert_shader_table(
            "CROWN_PROFILE_STEPS",
            crate::model::impostor::CROWN_PROFILE_STEPS,
            "wood_visibility",
            super::WOOD_VISIBILITY_ROWS,
        );
    }

    /// Tables go into the shader's rows four a row, entry `k` at row
    /// `k / 4`, lane `k % 4`.
    #[test]
    fn tables_are_packed_four_a_row() {
        let values: Vec<f32> = (0..8).map(|k| k as f32).collect();
        assert_eq!(
            super::four_a_row::<2>(&values),
            [[0.0, 1.0, 2.0, 3.0], [4.0, 5.0, 6.0, 7.0]]
        );
    }
}
