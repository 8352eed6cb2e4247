// Shared by the compact render path's compute pass (`conifer_cull.wgsl`)
// and its vertex and fragment shaders (`conifer_compact.wgsl`); the eval's
// reference (`src/eval/reference.wgsl`) takes the colour rules. The Rust
// mirrors are in `src/plugin/render/gpu.rs`.

#define_import_path bevy_conifer_lod::compact_types

// `model::compact::LOG_CODE_LN_MIN`, `LOG_CODE_LN_STEP`, `MAX_THRESHOLD_CODE`.
const LOG_LN_MIN: f32 = -20.723267;
const LOG_LN_STEP: f32 = 4.9190025e-4;
const MAX_THRESHOLD_CODE: u32 = 65534u;

// The parts of a species, each drawn by one multi-draw of its own
// indirect arguments (one per instance).
const KIND_COUNT: u32 = 7u;
const KIND_PRISMS: u32 = 0u;
const KIND_ORIGINAL_LINES: u32 = 1u;
const KIND_MERGED_LINES: u32 = 2u;
const KIND_WOOD_PRISMS: u32 = 3u;
const KIND_WOOD_LINES: u32 = 4u;
const KIND_WOOD_MESH: u32 = 5u;
const KIND_IMPOSTOR: u32 = 6u;

// Equal sections a wood segment is drawn in while the wind blows, one in
// calm (`model::wind::WOOD_SECTIONS`): each is straight between its ends
// as the field moves them, so a branch bends along its length.
const WOOD_SECTIONS: u32 = 4u;

fn wood_sections(wind_strength: f32) -> u32 {
    return select(1u, WOOD_SECTIONS, wind_strength > 0.0);
}

// Instance flags.
const FLAG_VISIBLE: u32 = 1u;
// Bits 1–2: 0 no override, 1 paper, 2 area-preserving.
const OPACITY_OVERRIDE_SHIFT: u32 = 1u;
// The instance's pixel error and transition override the global settings.
const FLAG_PIXEL_ERROR_OVERRIDE: u32 = 8u;
const FLAG_TRANSITION_OVERRIDE: u32 = 16u;
// The tree's own choice of the far impostor (`gpu::FLAG_IMPOSTOR_*`).
const FLAG_IMPOSTOR_OVERRIDE: u32 = 32u;
const FLAG_IMPOSTOR_ON: u32 = 64u;

// InstanceLod.code: the threshold code (16 bits), then flags.
const LOD_CODE_MASK: u32 = 0xffffu;
const LOD_ORIGINAL_FROM_NEEDLES: u32 = 0x10000u;
const LOD_OPACITY_SHIFT: u32 = 20u;
// Bits 24–31: how far the tree has faded into its impostor, 0–255.
const LOD_FADE_SHIFT: u32 = 24u;
// `model::impostor::FADE_START`, `FADE_END`: spatial errors, in texels,
// where the fade into the impostor starts and ends.
const IMPOSTOR_FADE_START: f32 = 0.8;
const IMPOSTOR_FADE_END: f32 = 1.6;
// CullView.perspective: bit 0 a perspective view, bit 1 a camera.
const VIEW_PERSPECTIVE: u32 = 1u;
const VIEW_CAMERA: u32 = 2u;
// The view's line draws are quads (`model::raster`), six vertices a line.
const VIEW_LINE_QUADS: u32 = 4u;
// The view draws each expanded placement's lines on their own, back to
// front (`ordered_args`).
const VIEW_DEPTH_ORDERED: u32 = 8u;

struct SpeciesParams {
    // tree-local crown centre (xyz) and the radius of a sphere round it
    // holding the whole tree (w)
    crown_center: vec4<f32>,
    // needle grid: origin (xyz), step (w)
    grid: vec4<f32>,
    // wood grid (segment ends and mesh vertices): origin (xyz), step (w)
    wood_grid: vec4<f32>,
    needle_color: vec4<f32>,
    wood_color: vec4<f32>,
    needle_count: u32,
    original_line_count: u32,
    merged_line_count: u32,
    wood_segment_count: u32,
    wood_index_count: u32,
    instance_count: u32,
    max_sides: u32,
    // vertices of one Lmax-slot prism: 6·Lmax sides, 6·(Lmax − 2) caps
    prism_vertices: u32,
    merged_code_min: u32,
    merged_code_max: u32,
    lod_enabled: u32,
    debug_colors: u32,
    pixel_error: f32,
    transition: f32,
    // 0: the paper's; 1: area-preserving
    opacity_rule: u32,
    wood_line_fade: f32,
    roughness: f32,
    reflectance: f32,
    // 0 for a flat species
    placement_count: u32,
    prototype_count: u32,
    // needles of the tree's section and the prototypes'
    total_needle_count: u32,
    // 1: each placement and level-2 line takes its own sphere's error
    // (`ErrorScope::Placement`); 0: one error per tree
    error_scope: u32,
    // wind seconds since the previous frame's clocks (the motion vector
    // pass winds the oscillators back by it)
    wind_step: f32,
    // the widest of `crown_radii`: the cylinder the crown's shade on
    // itself is looked for in (`CrownShade::widest_radius`)
    crown_widest_radius: f32,
    // a sphere holding every node's sphere and the wood (tree-local xyz, w radius)
    tree_sphere: vec4<f32>,
    // the crown impostor (`model::impostor`): axis (tree-local x, z), half
    // width, texel side (metres)
    impostor_box: vec4<f32>,
    // its bottom and top heights, its views, and 0 without an impostor, 1
    // with one off by default, 2 with one on by default
    impostor_span: vec4<f32>,
    // the tangents of the camera's elevation over the crown where the
    // impostor starts giving way to lines and where it is gone
    // (`model::impostor::SteepFade`: x start, y end; z, w unused)
    impostor_steep: vec4<f32>,
    // colours by age, side and height (`model::color`)
    young_needle_color: vec4<f32>,
    needle_underside_color: vec4<f32>,
    upper_wood_color: vec4<f32>,
    // needles without a placement's age (tree lines, flat species, impostor)
    far_needle_color: vec4<f32>,
    // where the bark turns (tree-local heights x to y)
    wood_heights: vec4<f32>,
    // the wind (`model::wind`): unit direction (world x, z), strength (0:
    // calm), gustiness
    wind: vec4<f32>,
    // turbulence, reach (tree metres: what culling and error spheres grow
    // by), trunk and branch oscillators (radians)
    wind_motion: vec4<f32>,
    // flutter and the two gust oscillators (radians), crown radius
    wind_clock: vec4<f32>,
    // trunk axis (tree-local x, z), base height, height
    wind_shape: vec4<f32>,
    // a sphere's mean diffuse and specular at SPHERE_LIGHT_STEPS angles
    // between the viewer and the light, four a row
    // (`model::shading::SphereLight`)
    sphere_diffuse: array<vec4<f32>, 16>,
    sphere_specular: array<vec4<f32>, 16>,
    // the impostor's crown radius (tree metres) at CROWN_PROFILE_STEPS
    // heights from its bottom to its top, four a row
    // (`model::impostor::CrownImpostor::crown_radii`)
    crown_radii: array<vec4<f32>, 8>,
    // the extinction (per tree metre) of the crown's CROWN_SHADE_CLASSES
    // media (lanes) at the same heights (rows)
    // (`model::impostor::CrownImpostor::crown_extinction`)
    crown_extinction: array<vec4<f32>, 32>,
    // the lines' opacity scales by pixel size, four a row
    // (`model::calibration::LineCalibration`; all 1 without one)
    line_scales: array<vec4<f32>, 2>,
    // log2 of the first pixel size (x) and entries per doubling (y)
    line_scale_range: vec4<f32>,
    // the share of the wood the needles leave in sight where they cover
    // the picture, by height (CROWN_PROFILE_STEPS) and nearness
    // (WOOD_NEARNESS_BINS), four a row (`model::impostor::WoodVisibility`)
    wood_visibility: array<vec4<f32>, 64>,
    // the wood lines' opacity scales at the pixel sizes of `line_scales`
    // (rows) and WOOD_OPACITY_NODES opacities (lanes)
    // (`model::calibration::LineCalibration::wood_scales`)
    wood_line_scales: array<vec4<f32>, 8>,
    // the share of the sky each point of the crown sees through it, by
    // height (CROWN_PROFILE_STEPS rows) and distance from the axis
    // (SKY_VISIBILITY_RINGS lanes; `model::crown_shade::SkyVisibility`;
    // all 1 with `ConiferLodSettings::sky_occlusion` off)
    sky_visibility: array<vec4<f32>, 32>,
    // how densely the needles fill the crown, by height
    // (CROWN_PROFILE_STEPS) and ring (CROWN_DENSITY_RINGS, even shares of
    // the radius from the axis), four a row, two rows a height
    // (`model::impostor::CrownDensity`): where an impostor texel's shadow
    // samples go
    crown_density: array<vec4<f32>, 64>,
    // the trunk at the crown profile's CROWN_PROFILE_STEPS heights: its
    // centre (tree-local x, z) and radius (0: none there)
    // (`model::impostor::TrunkProfile`): where the impostor lights its
    // wood as the round stem
    trunk: array<vec4<f32>, 32>,
    // what the impostor's direct light is scaled by, by the light's
    // direction in the view's frame: VIEW_LIGHT_ANGLES angles from the
    // direction toward the camera (rows of the table) by VIEW_LIGHT_ROLLS
    // rolls from above, angle major, four a row
    // (`model::impostor::ViewLightScale`; all 1 for an older record)
    view_light_scale: array<vec4<f32>, 23>,
}

const CROWN_DENSITY_RINGS: u32 = 8u;

const SHADOW_DEPTH_STEPS: u32 = 16u;

const SKY_VISIBILITY_RINGS: u32 = 4u;

const LINE_SCALE_STEPS: u32 = 8u;

const WOOD_OPACITY_NODES: u32 = 4u;

const CROWN_PROFILE_STEPS: u32 = 32u;

const CROWN_SHADE_STEPS: u32 = 8u;

const CROWN_SHADE_CLASSES: u32 = 4u;

const WOOD_NEARNESS_BINS: u32 = 8u;

const SPHERE_LIGHT_STEPS: u32 = 64u;

const VIEW_LIGHT_ANGLES: u32 = 13u;

const VIEW_LIGHT_ROLLS: u32 = 7u;

struct CullView {
    // frustum planes (xyz normal pointing inside, w offset)
    planes: array<vec4<f32>, 6>,
    // xyz the view's position; w the factor its trees' pixel error is
    // multiplied by (1 in a camera, the shadow error scale in a shadow view)
    world_position: vec4<f32>,
    // spatial error per metre of distance per unit pixel error: 2/(P₁₁·H)
    error_slope: f32,
    // VIEW_PERSPECTIVE | VIEW_CAMERA | VIEW_LINE_QUADS | VIEW_DEPTH_ORDERED
    perspective: u32,
    layers: u32,
    // expanded placements the view's entry buffers hold
    entry_capacity: u32,
    // where the budget is ranked from: a cascade's camera (xyz, w its
    // error slope); w = 0: the view's own spatial error
    budget_origin: vec4<f32>,
}

struct Instance {
    // world_from_local, rows of the affine part
    row_x: vec4<f32>,
    row_y: vec4<f32>,
    row_z: vec4<f32>,
    // overrides (with FLAG_PIXEL_ERROR_OVERRIDE, FLAG_TRANSITION_OVERRIDE)
    pixel_error: f32,
    transition: f32,
    flags: u32,
    // render layers 0–31
    layers: u32,
}

struct InstanceLod {
    // threshold code | LOD_ORIGINAL_FROM_NEEDLES | opacity rule << 20
    code: u32,
    spatial_error: f32,
    pixel_error: f32,
    transition: f32,
    // the camera in the tree's frame (xyz) and the spatial error per metre
    // of distance (w); w = 0: every node takes `spatial_error`
    view: vec4<f32>,
}

// A shared prototype of a placed species (`gpu::GpuPrototype`).
struct Prototype {
    // needle grid: origin (xyz), step (w)
    grid: vec4<f32>,
    needle_first: u32,
    needle_count: u32,
    original_first: u32,
    original_count: u32,
    merged_first: u32,
    merged_count: u32,
    // its needles' upper side (`model::color::upper_side`), pack4x8snorm
    upper_side: u32,
    // first entry of its merged lines by own code in `line_orders`
    merged_by_own_first: u32,
    // lower edges of bands 1…, two 16-bit codes a word
    band_edges: array<vec4<u32>, 2>,
    // bounding sphere, prototype metres (xyz centre, w radius)
    sphere: vec4<f32>,
}

// Where a prototype stands in the tree (`gpu::GpuPlacement`).
struct Placement {
    rotation: vec4<f32>,
    // translation (xyz), uniform scale (w)
    translation_scale: vec4<f32>,
    prototype: u32,
    // error code of its root line's level-2 parent
    parent_code: u32,
    // that parent's index in the tree's spheres (NO_SPHERE for a root)
    parent_sphere: u32,
    // age of its needles, years
    needle_age: u32,
}

// `model::compact::NO_SPHERE`.
const NO_SPHERE: u32 = 0xffffffffu;
// `model::view::VIEW_RANGE`.
const VIEW_RANGE: f32 = 256.0;

// `model::compact::PLACED_BANDS`; the placed parts, each a block of
// `prototype_count · PLACED_BANDS` draws.
const PLACED_BANDS: u32 = 16u;
const PLACED_KINDS: u32 = 3u;
const PLACED_PRISMS: u32 = 0u;
const PLACED_ORIGINAL_LINES: u32 = 1u;
const PLACED_MERGED_LINES: u32 = 2u;
// An expanded placement's entry: (tree | ENTRY_FROM_NEEDLES |
// ENTRY_MERGED_BY_OWN, placement | code << 16).
const ENTRY_PLACEMENT_MASK: u32 = 0xffffu;
const ENTRY_TREE_MASK: u32 = 0x3fffffffu;
const ENTRY_FROM_NEEDLES: u32 = 0x80000000u;
const ENTRY_MERGED_BY_OWN: u32 = 0x40000000u;
const ENTRY_INVALID: u32 = 0xffffffffu;
// The view's placement counters: a header, then per-draw arrays. The
// header: entries reserved below the budget's cutoff bucket, entries
// written, the cutoff bucket, the entries the buckets before it take,
// entries reserved in it, then the demand of each budget bucket.
const COUNTER_TOTAL: u32 = 0u;
const COUNTER_ENTRIES: u32 = 1u;
const COUNTER_CUTOFF: u32 = 2u;
const COUNTER_CUTOFF_BASE: u32 = 3u;
const COUNTER_CUTOFF_TOTAL: u32 = 4u;
const COUNTER_DEMAND: u32 = 8u;
// `model::compact::BUDGET_BUCKETS`, `BUDGET_BUCKET_SHIFT`.
const BUDGET_BUCKETS: u32 = 128u;
const BUDGET_BUCKET_SHIFT: u32 = 9u;
// `gpu::PLACED_COUNTER_HEADER`: COUNTER_DEMAND + BUDGET_BUCKETS.
const COUNTER_HEADER: u32 = 136u;
const ARRAY_COUNT: u32 = 0u;
const ARRAY_CURSOR: u32 = 1u;
const ARRAY_PRISMS: u32 = 2u;
const ARRAY_AFTER_PRISMS: u32 = 3u;
const ARRAY_BY_PARENT: u32 = 4u;
const ARRAY_MERGED: u32 = 5u;
const ARRAY_OFFSET: u32 = 6u;
const ARRAY_FLAGS: u32 = 7u;
const ARRAY_MERGED_BY_OWN: u32 = 8u;
// After the per-draw arrays, a camera's depth order: per depth bucket the
// expanded placements in it, the first rank of its lines' draws (back to
// front) and its cursor.
const DEPTH_ARRAY_COUNT: u32 = 0u;
const DEPTH_ARRAY_OFFSET: u32 = 1u;
const DEPTH_ARRAY_CURSOR: u32 = 2u;
// `model::compact::DEPTH_BUCKETS`, `DEPTH_BUCKETS_PER_OCTAVE`, `DEPTH_NEAREST`.
const DEPTH_BUCKETS: u32 = 4096u;
const DEPTH_BUCKETS_PER_OCTAVE: f32 = 192.0;
const DEPTH_NEAREST: f32 = 0.05;

// The depth bucket of what lies `distance` world metres from the camera
// (`model::compact::depth_bucket`).
fn depth_bucket(distance: f32) -> u32 {
    let octaves = log2(max(distance, DEPTH_NEAREST) / DEPTH_NEAREST);
    return u32(clamp(floor(octaves * DEPTH_BUCKETS_PER_OCTAVE), 0.0, f32(DEPTH_BUCKETS - 1u)));
}

// Colour within a tree (`model::color`), shared with the eval's reference
// (`eval/reference.wgsl`).

// How much of a shoot's lower side a viewer sees (`model::color::underside_weight`).
fn underside_weight(upper: vec3<f32>, to_viewer: vec3<f32>) -> f32 {
    let consistency = min(length(upper), 1.0);
    if consistency < 1e-6 {
        return 0.0;
    }
    let facing = dot(upper, to_viewer) / length(upper);
    return clamp(0.5 - 2.0 * facing, 0.0, 1.0) * consistency;
}

// A shoot's needles seen from `eye` (`model::color::ShootColor::seen_from`):
// `age_color` from above, `underside_color` from beneath; `upper_local`
// its upper side and `center_local` the point the viewer's direction is
// taken from, both in the frame `world_from_local` places.
fn shoot_needle_color(
    age_color: vec3<f32>,
    underside_color: vec3<f32>,
    upper_local: vec3<f32>,
    center_local: vec3<f32>,
    world_from_local: mat4x4<f32>,
    eye: vec3<f32>,
) -> vec3<f32> {
    let placed = (world_from_local * vec4<f32>(upper_local, 0.0)).xyz;
    var upper = vec3<f32>(0.0);
    if dot(placed, placed) > 1e-24 {
        upper = normalize(placed) * length(upper_local);
    }
    let center = (world_from_local * vec4<f32>(center_local, 1.0)).xyz;
    var to_viewer = eye - center;
    if dot(to_viewer, to_viewer) > 1e-24 {
        to_viewer = normalize(to_viewer);
    }
    return mix(age_color, underside_color, underside_weight(upper, to_viewer));
}

// Bark at `height` (`model::color::bark_color`): `lower` turning into
// `upper` between `heights.x` and `heights.y`.
fn bark_between(lower: vec3<f32>, upper: vec3<f32>, heights: vec2<f32>, height: f32) -> vec3<f32> {
    var t = select(0.0, 1.0, height >= heights.y);
    if heights.y > heights.x {
        t = clamp((height - heights.x) / (heights.y - heights.x), 0.0, 1.0);
    }
    return mix(lower, upper, t);
}

// The band of `prototype` a placement at threshold code `code` is drawn in
// (`model::compact::CompactSpecies::placement_band`).
fn placement_band(prototype: Prototype, code: u32) -> u32 {
    var band = 0u;
    for (var b = 0u; b < PLACED_BANDS - 1u; b += 1u) {
        let word = prototype.band_edges[b / 8u][(b / 2u) % 4u];
        let edge = (word >> (16u * (b % 2u))) & 0xffffu;
        band += select(0u, 1u, edge <= code);
    }
    return band;
}

// The tree-from-prototype matrix of a placement: rotation · (scale · p) + translation.
fn placement_matrix(placement: Placement) -> mat4x4<f32> {
    let q = placement.rotation;
    let s = placement.translation_scale.w;
    let x = q.x;
    let y = q.y;
    let z = q.z;
    let w = q.w;
    let col_x = vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)) * s;
    let col_y = vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)) * s;
    let col_z = vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)) * s;
    return mat4x4<f32>(
        vec4<f32>(col_x, 0.0),
        vec4<f32>(col_y, 0.0),
        vec4<f32>(col_z, 0.0),
        vec4<f32>(placement.translation_scale.xyz, 1.0),
    );
}

struct DrawArgs {
    vertex_count: u32,
    instance_count: u32,
    first_vertex: u32,
    first_instance: u32,
}

fn instance_world_from_local(instance: Instance) -> mat4x4<f32> {
    return mat4x4<f32>(
        vec4<f32>(instance.row_x.x, instance.row_y.x, instance.row_z.x, 0.0),
        vec4<f32>(instance.row_x.y, instance.row_y.y, instance.row_z.y, 0.0),
        vec4<f32>(instance.row_x.z, instance.row_y.z, instance.row_z.z, 0.0),
        vec4<f32>(instance.row_x.w, instance.row_y.w, instance.row_z.w, 1.0),
    );
}

// `world` in the frame of a tree whose `world_from_local` is a rotation, a
// uniform `scale` and a translation.
fn tree_local_point(world_from_local: mat4x4<f32>, scale: f32, world: vec3<f32>) -> vec3<f32> {
    let basis = mat3x3<f32>(world_from_local[0].xyz, world_from_local[1].xyz, world_from_local[2].xyz);
    return (transpose(basis) * (world - world_from_local[3].xyz)) / max(scale * scale, 1e-12);
}

// Mean length of the basis vectors: the instance's (uniform) scale.
fn instance_scale(instance: Instance) -> f32 {
    let x = vec3<f32>(instance.row_x.x, instance.row_y.x, instance.row_z.x);
    let y = vec3<f32>(instance.row_x.y, instance.row_y.y, instance.row_z.y);
    let z = vec3<f32>(instance.row_x.z, instance.row_y.z, instance.row_z.z);
    return (length(x) + length(y) + length(z)) / 3.0;
}

// The largest code whose value is at most `e` (`model::compact::shader_threshold_code`).
fn threshold_code(e: f32) -> u32 {
    if !(e >= 1e-9) {
        return 0u;
    }
    let steps = floor((log(e) - LOG_LN_MIN) / LOG_LN_STEP) + 1.0;
    return u32(clamp(steps, 0.0, f32(MAX_THRESHOLD_CODE)));
}

// Distance from `point` to the nearest point of `sphere` (xyz, w radius),
// 0 inside (`model::view::Sphere::distance_from`).
fn sphere_distance(sphere: vec4<f32>, point: vec3<f32>) -> f32 {
    return max(length(point - sphere.xyz) - sphere.w, 0.0);
}

// Spatial error (tree metres) a view gives what `sphere` bounds, grown by
// the wind's `reach` (tree metres; 0 in calm): its own nearest point's, or
// the tree's error when the view has no view point
// (`model::compact::CompactSpecies::sphere_error`, which is calm).
fn sphere_error(lod: InstanceLod, sphere: vec4<f32>, reach: f32) -> f32 {
    if lod.view.w > 0.0 {
        return lod.view.w * sphere_distance(vec4<f32>(sphere.xyz, sphere.w + reach), lod.view.xyz);
    }
    return lod.spatial_error;
}

// Spatial error (tree metres) of a placement of a prototype with bounding
// sphere `prototype_sphere`, grown by the wind's `reach`
// (`model::compact::CompactSpecies::placement_error`).
fn placement_error(lod: InstanceLod, placement: Placement, prototype_sphere: vec4<f32>, reach: f32) -> f32 {
    let center = (placement_matrix(placement) * vec4<f32>(prototype_sphere.xyz, 1.0)).xyz;
    return sphere_error(lod, vec4<f32>(center, prototype_sphere.w * placement.translation_scale.w), reach);
}

// A logarithmic code's value (`model::compact::shader_log_decode`).
fn log_decode(code: u32) -> f32 {
    if code == 0u {
        return 0.0;
    }
    return exp(LOG_LN_MIN + f32(code - 1u) * LOG_LN_STEP);
}

// A compact wood segment's two ends as (tree-local centre, radius): ends
// on the wood grid, radii as logarithmic codes
// (`model::compact::CompactSpecies::wood_segment`).
struct WoodEnds {
    start: vec4<f32>,
    end: vec4<f32>,
}

// `model::compact::WOOD_JOINED_START`, `WOOD_JOINED_END`,
// `WOOD_RADIUS_CODE_MASK`: a wood segment's radius codes are even, their
// low bits whether its start and end run on into another segment.
const WOOD_JOINED_START: u32 = 1u;
const WOOD_JOINED_END: u32 = 65536u;
const WOOD_RADIUS_CODE_MASK: u32 = 65534u;

fn decode_wood_segment(w: vec4<u32>, grid: vec4<f32>) -> WoodEnds {
    let start = grid.xyz + vec3<f32>(f32(w.x & 0xffffu), f32(w.x >> 16u), f32(w.y & 0xffffu)) * grid.w;
    let end = grid.xyz + vec3<f32>(f32(w.y >> 16u), f32(w.z & 0xffffu), f32(w.z >> 16u)) * grid.w;
    var ends: WoodEnds;
    ends.start = vec4<f32>(start, log_decode(w.w & WOOD_RADIUS_CODE_MASK));
    ends.end = vec4<f32>(end, log_decode((w.w >> 16u) & WOOD_RADIUS_CODE_MASK));
    return ends;
}

// The larger radius of a compact wood segment (what its order sorts by).
fn wood_segment_radius(w: vec4<u32>) -> f32 {
    return log_decode(max(w.w & WOOD_RADIUS_CODE_MASK, (w.w >> 16u) & WOOD_RADIUS_CODE_MASK));
}
