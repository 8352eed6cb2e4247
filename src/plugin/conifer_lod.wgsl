// Continuous LOD of conifer foliage, chosen per vertex on the GPU.
//
// Every instance of a species shares one prism mesh and one line mesh; the
// vertex shader computes the instance's spatial error for the current view
// (paper: e = 2·ε·D·tan(θ/2)/W, with tan(θ/2) = 1/clip_from_view[1][1]) and
// keeps exactly the cut: a line whose [error, parent_error) holds e, a prism
// while e < 2R with ⌈π / arccos(1 − e/R)⌉ sides. Everything else is moved
// outside the clip volume. CPU reference: src/model/gpu_layout.rs.

#import bevy_pbr::{
    mesh_functions,
    mesh_view_bindings::view,
    view_transformations::position_world_to_clip,
}

#ifdef PREPASS_PIPELINE
#import bevy_pbr::prepass_io::VertexOutput
#else
#import bevy_pbr::forward_io::VertexOutput
#endif

const PI: f32 = 3.14159265358979;
const TAU: f32 = 6.28318530717959;

struct ConiferLod {
    // tree-local centre of the crown (xyz), w unused
    center: vec4<f32>,
    // pixel error ε
    pixel_error: f32,
    // transition coefficient δ, scaling original lines' opacity
    transition: f32,
    // Lmax of the record
    max_sides: u32,
    // 0: the paper's T = 2/ρ; 1: area-preserving coverage
    opacity_rule: u32,
    // 0: LOD off, every needle a prism of Lmax sides
    lod_enabled: u32,
    // 1: colour by representation (debug overlay)
    debug_colors: u32,
    // deepest merge level of the lines (debug colours)
    max_merge_depth: u32,
    _padding_b: u32,
    // wood colour over needle colour, for wood lines
    wood_tint: vec4<f32>,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(100) var<uniform> conifer: ConiferLod;
@group(#{MATERIAL_BIND_GROUP}) @binding(101) var<storage, read> needles: array<vec4<f32>>;

struct ConiferVertex {
    @builtin(instance_index) instance_index: u32,
    @builtin(vertex_index) vertex_index: u32,
#ifdef CONIFER_PRISMS
    @location(0) code: u32,
#else
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) lod: vec4<f32>,
#endif
}

// Spatial error of this instance for the current view, in tree-local metres.
fn instance_spatial_error(world_from_local: mat4x4<f32>) -> f32 {
    if conifer.lod_enabled == 0u {
        return 0.0;
    }
    let center = (world_from_local * vec4<f32>(conifer.center.xyz, 1.0)).xyz;
    let scale = (length(world_from_local[0].xyz) + length(world_from_local[1].xyz) + length(world_from_local[2].xyz)) / 3.0;
    var distance = 1.0;
    if view.clip_from_view[3][3] != 1.0 {
        distance = length(center - view.world_position);
    }
    let height = max(view.viewport.w, 1.0);
    let world_error = max(conifer.pixel_error, 0.0) * distance * 2.0 / (view.clip_from_view[1][1] * height);
    return world_error / max(scale, 1e-6);
}

// A position outside every clip plane: the primitive is not drawn.
fn culled() -> VertexOutput {
    var out: VertexOutput;
    out.position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    out.world_position = vec4<f32>(0.0, 0.0, 0.0, 1.0);
#ifdef PREPASS_PIPELINE
#ifdef NORMAL_PREPASS_OR_DEFERRED_PREPASS
    out.world_normal = vec3<f32>(0.0, 1.0, 0.0);
#endif
#ifdef MOTION_VECTOR_PREPASS
    out.previous_world_position = out.world_position;
#endif
#ifdef UNCLIPPED_DEPTH_ORTHO_EMULATION
    out.unclipped_depth = 2.0;
#endif
#else
    out.world_normal = vec3<f32>(0.0, 1.0, 0.0);
#endif
#ifdef VERTEX_COLORS
    out.color = vec4<f32>(0.0);
#endif
    return out;
}

fn finish(
    local_position: vec3<f32>,
    local_normal: vec3<f32>,
    instance_index: u32,
    world_from_local: mat4x4<f32>,
    color: vec4<f32>,
    face_viewer: bool,
) -> VertexOutput {
    var out: VertexOutput;
    out.world_position = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(local_position, 1.0));
    out.position = position_world_to_clip(out.world_position.xyz);
    var world_normal = mesh_functions::mesh_normal_local_to_world(local_normal, instance_index);
    if face_viewer && dot(world_normal, view.world_position - out.world_position.xyz) < 0.0 {
        world_normal = -world_normal;
    }
#ifdef PREPASS_PIPELINE
#ifdef UNCLIPPED_DEPTH_ORTHO_EMULATION
    out.unclipped_depth = out.position.z;
    out.position.z = min(out.position.z, 1.0);
#endif
#ifdef NORMAL_PREPASS_OR_DEFERRED_PREPASS
    out.world_normal = world_normal;
#endif
#ifdef MOTION_VECTOR_PREPASS
    let previous = mesh_functions::get_previous_world_from_local(instance_index);
    out.previous_world_position = mesh_functions::mesh_position_local_to_world(previous, vec4<f32>(local_position, 1.0));
#endif
#else
    out.world_normal = world_normal;
#endif
#ifdef VERTEX_COLORS
    out.color = color;
#endif
#ifdef VERTEX_OUTPUT_INSTANCE_INDEX
    out.instance_index = instance_index;
#endif
    return out;
}

// Debug colours: prisms blue → cyan by side count, original lines green,
// merged lines yellow → red by merge depth.
fn debug_color(kind: f32, amount: f32) -> vec4<f32> {
    if kind < 0.0 {
        return vec4<f32>(0.1, 0.3 + 0.7 * amount, 1.0, 1.0);
    }
    if kind < 0.5 {
        return vec4<f32>(0.1, 0.9, 0.1, 1.0);
    }
    return vec4<f32>(1.0, 1.0 - amount, 0.05, 1.0);
}

@vertex
fn vertex(vertex: ConiferVertex) -> VertexOutput {
    let world_from_local = mesh_functions::get_world_from_local(vertex.instance_index);
    let e = instance_spatial_error(world_from_local);

#ifdef CONIFER_PRISMS
    let code = vertex.code;
    let needle = code >> 8u;
    let slot = code & 63u;
    let at_tip = (code & 64u) != 0u;
    let cap = (code & 128u) != 0u;
    let base_radius = needles[needle * 3u];
    let needle_normal = needles[needle * 3u + 2u].xyz;
    let tip_data = needles[needle * 3u + 1u];
    // Needles are cylinders (tip radius = base radius); wood segments taper.
    let tip = tip_data.xyz;
    let radius = max(base_radius.w, tip_data.w);
    if e >= 2.0 * radius {
        return culled();
    }
    let max_sides = max(conifer.max_sides, 3u);
    var sides = max_sides;
    let rho = e / radius;
    if rho >= 1.0 {
        sides = 3u;
    } else if rho > 0.0 {
        sides = clamp(u32(ceil(PI / acos(1.0 - rho))), 3u, max_sides);
    }
    let corner = slot * sides / max_sides;
    let angle = TAU * f32(corner) / f32(sides);
    let axis = normalize(tip - base_radius.xyz);
    var u = needle_normal - axis * dot(needle_normal, axis);
    if dot(u, u) < 1e-12 {
        u = select(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), abs(axis.x) > 0.9);
        u = u - axis * dot(u, axis);
    }
    u = normalize(u);
    let v = cross(axis, u);
    let radial = u * cos(angle) + v * sin(angle);
    var end = base_radius.xyz;
    if at_tip {
        end = tip;
    }
    var normal = radial;
    if cap {
        normal = select(-axis, axis, at_tip);
    }
    var color = vec4<f32>(1.0);
    if conifer.debug_colors != 0u {
        color = debug_color(-1.0, f32(max_sides - sides) / max(f32(max_sides - 3u), 1.0));
    }
    let end_radius = select(base_radius.w, tip_data.w, at_tip);
    return finish(end + radial * end_radius, normal, vertex.instance_index, world_from_local, color, false);
#else
    let lod = vertex.lod;
    if conifer.lod_enabled == 0u || !(lod.x <= e && e < lod.y) {
        return culled();
    }
    // Width of the needles over the width of the line (one pixel).
    var coverage = 0.0;
    if conifer.opacity_rule == 0u {
        // The paper: T = 2/ρ = 2R/e for an original line; a merged line read
        // as a cylinder of radius e(X)/2 gives e(X)/e.
        coverage = select(lod.z, lod.x, lod.w > 0.5) / max(e, 1e-12);
    } else {
        let pixel = e / max(conifer.pixel_error, 1e-6);
        coverage = lod.z / max(pixel, 1e-12);
    }
    var alpha = min(coverage, 1.0);
    if lod.w < 0.5 {
        alpha = alpha * conifer.transition;
    }
    var color = vec4<f32>(1.0, 1.0, 1.0, alpha);
    if lod.w < -0.5 {
        // A wood line (kind −1): the wood's colour over the needles' base colour.
        color = vec4<f32>(conifer.wood_tint.rgb, alpha);
    }
    if conifer.debug_colors != 0u {
        // kind: 0 for an original line, the merge depth (≥ 1) for a merged one.
        let depth = (lod.w - 1.0) / max(f32(conifer.max_merge_depth) - 1.0, 1.0);
        color = debug_color(lod.w, clamp(depth, 0.0, 1.0));
        if lod.w < -0.5 {
            color = vec4<f32>(0.45, 0.3, 0.15, 1.0);
        }
        color.a = alpha;
    }
#ifdef PREPASS_PIPELINE
    // Depth passes (shadows) keep a fraction `alpha` of the line's texels,
    // hashed by the line and the tree (conifer_line_shadow.wgsl), which
    // travel as the colour: two vertices a line.
    color = vec4<f32>(f32(vertex.vertex_index / 2u), f32(vertex.instance_index), 0.0, alpha);
#endif
    return finish(vertex.position, vertex.normal, vertex.instance_index, world_from_local, color, true);
#endif
}
