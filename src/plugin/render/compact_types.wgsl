// Shared by the compact render path's compute pass (`conifer_cull.wgsl`)
// and its vertex and fragment shaders (`conifer_compact.wgsl`). The Rust
// mirrors are in `src/plugin/render/gpu.rs`.

#define_import_path bevy_conifer_lod::compact_types

// `model::compact::LOG_CODE_LN_MIN`, `LOG_CODE_LN_STEP`, `MAX_THRESHOLD_CODE`.
const LOG_LN_MIN: f32 = -20.723267;
const LOG_LN_STEP: f32 = 4.9190025e-4;
const MAX_THRESHOLD_CODE: u32 = 65534u;

// The parts of a species, each drawn by one multi-draw of its own
// indirect arguments (one per instance).
const KIND_COUNT: u32 = 6u;
const KIND_PRISMS: u32 = 0u;
const KIND_ORIGINAL_LINES: u32 = 1u;
const KIND_MERGED_LINES: u32 = 2u;
const KIND_WOOD_PRISMS: u32 = 3u;
const KIND_WOOD_LINES: u32 = 4u;
const KIND_WOOD_MESH: u32 = 5u;

// Instance flags.
const FLAG_VISIBLE: u32 = 1u;
// Bits 1–2: 0 no override, 1 paper, 2 area-preserving.
const OPACITY_OVERRIDE_SHIFT: u32 = 1u;
// The instance's pixel error and transition override the global settings.
const FLAG_PIXEL_ERROR_OVERRIDE: u32 = 8u;
const FLAG_TRANSITION_OVERRIDE: u32 = 16u;

// InstanceLod.code: the threshold code (16 bits), then flags.
const LOD_CODE_MASK: u32 = 0xffffu;
const LOD_ORIGINAL_FROM_NEEDLES: u32 = 0x10000u;
const LOD_OPACITY_SHIFT: u32 = 20u;

struct SpeciesParams {
    // tree-local crown centre (xyz) and the radius of a sphere round it
    // holding the whole tree (w)
    crown_center: vec4<f32>,
    // needle grid: origin (xyz), step (w)
    grid: vec4<f32>,
    // wood mesh grid: origin (xyz), step (w)
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
    padding_a: u32,
    padding_b: u32,
}

struct CullView {
    // frustum planes (xyz normal pointing inside, w offset)
    planes: array<vec4<f32>, 6>,
    world_position: vec4<f32>,
    // spatial error per metre of distance per unit pixel error: 2/(P₁₁·H)
    error_slope: f32,
    perspective: u32,
    layers: u32,
    padding: u32,
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

// Mean length of the basis vectors: the instance's (uniform) scale.
fn instance_scale(instance: Instance) -> f32 {
    let x = vec3<f32>(instance.row_x.x, instance.row_y.x, instance.row_z.x);
    let y = vec3<f32>(instance.row_x.y, instance.row_y.y, instance.row_z.y);
    let z = vec3<f32>(instance.row_x.z, instance.row_y.z, instance.row_z.z);
    return (length(x) + length(y) + length(z)) / 3.0;
}

// A logarithmic code's value (`model::compact::shader_log_decode`).
fn log_decode(code: u32) -> f32 {
    if code == 0u {
        return 0.0;
    }
    return exp(LOG_LN_MIN + f32(code - 1u) * LOG_LN_STEP);
}
