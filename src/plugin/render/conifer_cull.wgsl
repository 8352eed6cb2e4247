// Per view and species: every tree's spatial error, frustum and layer
// culling, and the indirect draw arguments of each part: the prefix of each
// sorted array the tree's cut can use (binary searches). CPU reference:
// `model::compact::CompactSpecies::prefixes`, `shader_threshold_code`.

#import bevy_conifer_lod::compact_types::{
    Instance, InstanceLod, SpeciesParams, CullView, DrawArgs,
    LOG_LN_MIN, LOG_LN_STEP, MAX_THRESHOLD_CODE, KIND_COUNT,
    KIND_PRISMS, KIND_ORIGINAL_LINES, KIND_MERGED_LINES, KIND_WOOD_PRISMS, KIND_WOOD_LINES, KIND_WOOD_MESH,
    FLAG_VISIBLE, FLAG_PIXEL_ERROR_OVERRIDE, FLAG_TRANSITION_OVERRIDE, OPACITY_OVERRIDE_SHIFT, LOD_ORIGINAL_FROM_NEEDLES, LOD_OPACITY_SHIFT,
    instance_world_from_local, instance_scale,
}

@group(0) @binding(0) var<uniform> cull_view: CullView;
@group(0) @binding(1) var<uniform> species: SpeciesParams;
@group(0) @binding(2) var<storage, read> instances: array<Instance>;
@group(0) @binding(3) var<storage, read> needles: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> original_lines: array<u32>;
@group(0) @binding(5) var<storage, read> merged_lines: array<u32>;
@group(0) @binding(6) var<storage, read> wood_segments: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> instance_lods: array<InstanceLod>;
@group(0) @binding(8) var<storage, read_write> draw_args: array<DrawArgs>;

fn threshold_code(e: f32) -> u32 {
    if !(e >= 1e-9) {
        return 0u;
    }
    let steps = floor((log(e) - LOG_LN_MIN) / LOG_LN_STEP) + 1.0;
    return u32(clamp(steps, 0.0, f32(MAX_THRESHOLD_CODE)));
}

// Needles whose line-error code is above `code` (they are prisms).
fn prism_prefix(code: u32) -> u32 {
    var lo = 0u;
    var hi = species.needle_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (needles[mid].w & 0xffffu) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

fn original_prefix(code: u32) -> u32 {
    var lo = 0u;
    var hi = species.original_line_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (needles[original_lines[mid]].w >> 16u) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

fn merged_prefix(code: u32) -> u32 {
    var lo = 0u;
    var hi = species.merged_line_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (merged_lines[3u * mid + 2u] >> 16u) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// Wood segments with `e < factor · 2·r_max`.
fn wood_prefix(e: f32, factor: f32) -> u32 {
    var lo = 0u;
    var hi = species.wood_segment_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        let r = max(wood_segments[2u * mid].w, wood_segments[2u * mid + 1u].w);
        if e < factor * 2.0 * r {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

fn write_args(kind: u32, instance: u32, vertex_count: u32, first_vertex: u32) {
    let slot = kind * species.instance_count + instance;
    draw_args[slot].vertex_count = vertex_count;
    draw_args[slot].instance_count = select(0u, 1u, vertex_count > 0u);
    draw_args[slot].first_vertex = first_vertex;
    draw_args[slot].first_instance = instance;
}

fn hide(instance: u32) {
    for (var kind = 0u; kind < KIND_COUNT; kind += 1u) {
        write_args(kind, instance, 0u, 0u);
    }
    instance_lods[instance].code = 0u;
    instance_lods[instance].spatial_error = 0.0;
}

@compute @workgroup_size(64)
fn cull(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= species.instance_count {
        return;
    }
    let instance = instances[i];
    if (instance.flags & FLAG_VISIBLE) == 0u || (instance.layers & cull_view.layers) == 0u {
        hide(i);
        return;
    }
    let world_from_local = instance_world_from_local(instance);
    let scale = instance_scale(instance);
    let center = (world_from_local * vec4<f32>(species.crown_center.xyz, 1.0)).xyz;
    let radius = species.crown_center.w * scale;
    for (var p = 0u; p < 6u; p += 1u) {
        if dot(cull_view.planes[p].xyz, center) + cull_view.planes[p].w < -radius {
            hide(i);
            return;
        }
    }
    // Per-tree overrides.
    var pixel_error = species.pixel_error;
    if (instance.flags & FLAG_PIXEL_ERROR_OVERRIDE) != 0u {
        pixel_error = instance.pixel_error;
    }
    var transition = species.transition;
    if (instance.flags & FLAG_TRANSITION_OVERRIDE) != 0u {
        transition = instance.transition;
    }
    var opacity_rule = species.opacity_rule;
    let rule_override = (instance.flags >> OPACITY_OVERRIDE_SHIFT) & 3u;
    if rule_override != 0u {
        opacity_rule = rule_override - 1u;
    }
    var distance = 1.0;
    if cull_view.perspective != 0u {
        distance = length(center - cull_view.world_position.xyz);
    }
    var e = max(pixel_error, 0.0) * distance * cull_view.error_slope / max(scale, 1e-6);
    if species.lod_enabled == 0u {
        e = 0.0;
    }
    let code = threshold_code(e);
    let prisms = prism_prefix(code);
    let by_parent = original_prefix(code);
    let after_prisms = species.needle_count - prisms;
    var lod_flags = 0u;
    var original = by_parent;
    var original_first = 0u;
    if after_prisms < by_parent {
        original = after_prisms;
        original_first = 2u * prisms;
        lod_flags = LOD_ORIGINAL_FROM_NEEDLES;
    }
    if species.lod_enabled == 0u {
        original = 0u;
    }
    let merged = select(0u, merged_prefix(code), species.lod_enabled != 0u);
    let wood_prisms = wood_prefix(e, 1.0);
    let wood_lines = select(0u, wood_prefix(e, species.wood_line_fade), species.lod_enabled != 0u);
    instance_lods[i].code = code | lod_flags | (opacity_rule << LOD_OPACITY_SHIFT);
    instance_lods[i].spatial_error = e;
    instance_lods[i].pixel_error = max(pixel_error, 1e-6);
    instance_lods[i].transition = clamp(transition, 0.0, 1.0);
    write_args(KIND_PRISMS, i, prisms * species.prism_vertices, 0u);
    write_args(KIND_ORIGINAL_LINES, i, 2u * original, original_first);
    write_args(KIND_MERGED_LINES, i, 2u * merged, 0u);
    write_args(KIND_WOOD_PRISMS, i, wood_prisms * species.prism_vertices, 0u);
    // Wood lines: the segments after the prisms, up to the fade.
    write_args(KIND_WOOD_LINES, i, 2u * (wood_lines - min(wood_prisms, wood_lines)), 2u * min(wood_prisms, wood_lines));
    write_args(KIND_WOOD_MESH, i, species.wood_index_count, 0u);
}
