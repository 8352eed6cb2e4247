// Per view and species: every tree's spatial error, frustum and layer
// culling, and the indirect draw arguments of each part: the prefix of each
// sorted array the tree's cut can use (binary searches). CPU reference:
// `model::compact::CompactSpecies::prefixes`, `shader_threshold_code`.
//
// A species of shared prototypes also expands, per view, the placements
// whose detail a tree's cut needs (a prefix of the placements sorted by
// their root's parent code), and draws them instanced, one draw per
// prototype and band (`budget_demand` → `budget_cutoff` → `cull` →
// `prepare_dispatch` → `count_placements` → `scan_placements` →
// `scatter_placements`). CPU reference:
// `model::compact::CompactSpecies::placed_view`.
//
// A camera also draws each expanded placement's lines on their own, back
// to front by depth bucket, its merged and original lines in one draw
// (`ordered_args`; CPU reference: `model::compact::back_to_front`,
// `model::compact::CompactSpecies::entry_lines`): blended lines drawn a
// prototype at a time mix a crown's whole depth in a pixel.

#import bevy_conifer_lod::compact_types::{
    Instance, InstanceLod, SpeciesParams, CullView, DrawArgs,
    LOG_LN_MIN, LOG_LN_STEP, MAX_THRESHOLD_CODE, KIND_COUNT,
    Prototype, Placement, PLACED_BANDS, PLACED_PRISMS, PLACED_ORIGINAL_LINES, PLACED_MERGED_LINES,
    ENTRY_FROM_NEEDLES, ENTRY_MERGED_BY_OWN, ENTRY_INVALID, COUNTER_TOTAL, COUNTER_ENTRIES, COUNTER_HEADER,
    COUNTER_CUTOFF, COUNTER_CUTOFF_BASE, COUNTER_CUTOFF_TOTAL, COUNTER_DEMAND, BUDGET_BUCKETS, BUDGET_BUCKET_SHIFT,
    ARRAY_COUNT, ARRAY_CURSOR, ARRAY_PRISMS, ARRAY_AFTER_PRISMS, ARRAY_BY_PARENT, ARRAY_MERGED, ARRAY_OFFSET, ARRAY_FLAGS,
    ARRAY_MERGED_BY_OWN, DEPTH_ARRAY_COUNT, DEPTH_ARRAY_OFFSET, DEPTH_ARRAY_CURSOR, DEPTH_BUCKETS, depth_bucket,
    placement_band, placement_matrix,
    KIND_PRISMS, KIND_ORIGINAL_LINES, KIND_MERGED_LINES, KIND_WOOD_PRISMS, KIND_WOOD_LINES, KIND_WOOD_MESH, KIND_IMPOSTOR,
    LOD_FADE_SHIFT, FLAG_IMPOSTOR_OVERRIDE, FLAG_IMPOSTOR_ON, IMPOSTOR_FADE_START, IMPOSTOR_FADE_END, VIEW_PERSPECTIVE, VIEW_CAMERA, VIEW_LINE_QUADS, VIEW_DEPTH_ORDERED,
    FLAG_VISIBLE, FLAG_PIXEL_ERROR_OVERRIDE, FLAG_TRANSITION_OVERRIDE, OPACITY_OVERRIDE_SHIFT, LOD_ORIGINAL_FROM_NEEDLES, LOD_OPACITY_SHIFT,
    instance_world_from_local, instance_scale, tree_local_point,
    threshold_code, sphere_distance, sphere_error, placement_error, NO_SPHERE, VIEW_RANGE,
    wood_segment_radius, wood_sections,
}

@group(0) @binding(0) var<uniform> cull_view: CullView;
@group(0) @binding(1) var<uniform> species: SpeciesParams;
@group(0) @binding(2) var<storage, read> instances: array<Instance>;
@group(0) @binding(3) var<storage, read> needles: array<vec4<u32>>;
// The original-line order, then the prototypes' merged lines by own code.
@group(0) @binding(4) var<storage, read> line_orders: array<u32>;
@group(0) @binding(5) var<storage, read> merged_lines: array<u32>;
@group(0) @binding(6) var<storage, read> wood_segments: array<vec4<u32>>;
@group(0) @binding(7) var<storage, read_write> instance_lods: array<InstanceLod>;
@group(0) @binding(8) var<storage, read_write> draw_args: array<DrawArgs>;

@group(1) @binding(0) var<storage, read> placements: array<Placement>;
@group(1) @binding(1) var<storage, read> prototypes: array<Prototype>;
@group(1) @binding(2) var<storage, read_write> counters: array<atomic<u32>>;
@group(1) @binding(3) var<storage, read_write> entries: array<vec2<u32>>;
@group(1) @binding(4) var<storage, read_write> sorted_entries: array<vec2<u32>>;
@group(1) @binding(5) var<storage, read_write> placed_args: array<DrawArgs>;
@group(1) @binding(6) var<storage, read> tree_spheres: array<vec4<f32>>;
// A camera's line draws one expanded placement at a time, back to front,
// each its merged lines then its original lines; and per entry (by its
// index in `sorted_entries`) where its merged lines end and its original
// lines start (`conifer_compact.wgsl`'s `CONIFER_LINES_BY_ENTRY`). Other
// views bind stand-ins and write none.
@group(1) @binding(7) var<storage, read_write> ordered_args: array<DrawArgs>;
@group(1) @binding(8) var<storage, read_write> ordered_splits: array<vec2<u32>>;
// Only `prepare_dispatch` binds it: the other passes read it as their
// indirect dispatch.
@group(2) @binding(0) var<storage, read_write> dispatch: array<u32>;


// Needles of `[first, first + count)` whose line-error code is above
// `code` (they are prisms), counted from `first`.
fn prism_prefix_in(first: u32, count: u32, code: u32) -> u32 {
    var lo = first;
    var hi = first + count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (needles[mid].w & 0xffffu) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - first;
}

fn original_prefix_in(first: u32, count: u32, code: u32) -> u32 {
    var lo = first;
    var hi = first + count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (needles[line_orders[mid]].w >> 16u) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - first;
}

fn merged_prefix_in(first: u32, count: u32, code: u32) -> u32 {
    var lo = first;
    var hi = first + count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (merged_lines[3u * mid + 2u] >> 16u) > code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - first;
}

// Merged lines of a prototype whose own code is at most `code`: a binary
// search of its own-code order (`first`: its entry in `line_orders`).
fn merged_by_own_prefix_in(first: u32, count: u32, code: u32) -> u32 {
    var lo = first;
    var hi = first + count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if (merged_lines[3u * line_orders[mid] + 2u] & 0xffffu) <= code {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - first;
}

fn prism_prefix(code: u32) -> u32 {
    return prism_prefix_in(0u, species.needle_count, code);
}

fn original_prefix(code: u32) -> u32 {
    return original_prefix_in(0u, species.original_line_count, code);
}

fn merged_prefix(code: u32) -> u32 {
    return merged_prefix_in(0u, species.merged_line_count, code);
}

// Placements whose root's parent code is above `code`: the ones a tree at
// `code` expands.
fn expanded_prefix(code: u32) -> u32 {
    var lo = 0u;
    var hi = species.placement_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if placements[mid].parent_code > code {
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
        let r = wood_segment_radius(wood_segments[mid]);
        if e < factor * 2.0 * r {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// Vertices a line takes in this view's draws: a quad of two triangles
// where the view draws lines by their strip's area (`VIEW_LINE_QUADS`),
// else a hardware line's two.
fn line_vertices() -> u32 {
    return select(2u, 6u, (cull_view.perspective & VIEW_LINE_QUADS) != 0u);
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
    instance_lods[instance].view = vec4<f32>(0.0);
}

// What a view makes of tree `i` before its placements are expanded: whether
// it is seen, its spatial error and threshold code, its fade into the
// impostor, its view point and its overrides (`cull` and `budget_demand`
// decide alike).
struct TreeView {
    seen: bool,
    e: f32,
    code: u32,
    // The code the expansion budget ranks the tree by: `code`, or in a
    // directional cascade the code its camera sees it at.
    budget_code: u32,
    // 255: the impostor alone
    fade: u32,
    // Whether the view may draw the tree as its impostor at all (a camera,
    // a tree with one, not looked at from steeply above or below).
    impostor_allowed: bool,
    view_point: vec4<f32>,
    pixel_error: f32,
    transition: f32,
    opacity_rule: u32,
}

// The spatial error (tree metres) of a tree of `scale` whose crown centre
// stands at `center`, seen from `eye` with `slope` metres of error a metre
// and its `pixel_error`, nearer by the wind's `reach` (world metres). CPU
// reference: `model::compact::budget_error`.
fn error_from(eye: vec3<f32>, center: vec3<f32>, reach: f32, slope: f32, pixel_error: f32, scale: f32) -> f32 {
    let distance = max(length(center - eye) - reach, 0.0);
    return max(pixel_error, 0.0) * distance * slope / max(scale, 1e-6);
}

fn view_tree(i: u32) -> TreeView {
    var tree: TreeView;
    tree.seen = false;
    let instance = instances[i];
    if (instance.flags & FLAG_VISIBLE) == 0u || (instance.layers & cull_view.layers) == 0u {
        return tree;
    }
    let world_from_local = instance_world_from_local(instance);
    let scale = instance_scale(instance);
    let center = (world_from_local * vec4<f32>(species.crown_center.xyz, 1.0)).xyz;
    // The wind moves nothing farther than its reach (`model::wind::wind_reach`,
    // 0 in calm): a swaying tree is culled and detailed as if it could
    // stand that much nearer.
    let reach = species.wind_motion.y;
    let radius = (species.crown_center.w + reach) * scale;
    for (var p = 0u; p < 6u; p += 1u) {
        if dot(cull_view.planes[p].xyz, center) + cull_view.planes[p].w < -radius {
            return tree;
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
    // A shadow view's cut may be coarser than its texel's
    // (`ConiferLodSettings::shadow_error_scale`): its pixel error is
    // multiplied, so the lines' opacities still take its texel as their
    // pixel (their pixel is the spatial error over the pixel error).
    let budget_pixel_error = pixel_error;
    pixel_error *= max(cull_view.world_position.w, 1.0);
    var opacity_rule = species.opacity_rule;
    let rule_override = (instance.flags >> OPACITY_OVERRIDE_SHIFT) & 3u;
    if rule_override != 0u {
        opacity_rule = rule_override - 1u;
    }
    // An orthographic view has one error everywhere (its texel's).
    var e = max(pixel_error, 0.0) * cull_view.error_slope / max(scale, 1e-6);
    if (cull_view.perspective & VIEW_PERSPECTIVE) != 0u {
        e = error_from(cull_view.world_position.xyz, center, reach * scale, cull_view.error_slope, pixel_error, scale);
    }
    if species.lod_enabled == 0u {
        e = 0.0;
    }
    // View-dependent detail (`model::view`): the tree's error from the
    // nearest point of its sphere (a lower bound of every node's), each
    // node's from its own sphere, unless the camera is beyond range.
    var view_point = vec4<f32>(0.0);
    // The camera in the tree's frame (view points, the impostor's elevation).
    let camera = tree_local_point(world_from_local, scale, cull_view.world_position.xyz);
    if species.error_scope != 0u && species.placement_count > 0u && species.lod_enabled != 0u
        && (cull_view.perspective & VIEW_PERSPECTIVE) != 0u {
        let slope = max(pixel_error, 0.0) * cull_view.error_slope;
        let d = sphere_distance(vec4<f32>(species.tree_sphere.xyz, species.tree_sphere.w + reach), camera);
        e = slope * d;
        if d <= VIEW_RANGE * species.tree_sphere.w {
            view_point = vec4<f32>(camera, slope);
        }
    }
    // The far representation (`model::impostor`): a camera fades the
    // tree's cut into its impostor while the spatial error grows from
    // IMPOSTOR_FADE_START to IMPOSTOR_FADE_END texels, then draws only the
    // impostor (and expands no placement). CPU reference:
    // `model::impostor::impostor_fade`.
    var fade = 0u;
    var impostor = species.impostor_span.w > 1.5;
    if (instance.flags & FLAG_IMPOSTOR_OVERRIDE) != 0u {
        impostor = (instance.flags & FLAG_IMPOSTOR_ON) != 0u;
    }
    if impostor && species.impostor_span.w > 0.5 && species.lod_enabled != 0u
        && (cull_view.perspective & VIEW_CAMERA) != 0u {
        let texels = e / max(species.impostor_box.w, 1e-9);
        let t = clamp((texels - IMPOSTOR_FADE_START) / (IMPOSTOR_FADE_END - IMPOSTOR_FADE_START), 0.0, 1.0);
        // Side views: a camera looking down on the tree keeps its lines.
        let above = camera - species.crown_center.xyz;
        let elevation = abs(above.y) / max(length(above.xz), 1e-9);
        let band = species.impostor_steep;
        let steep = clamp((elevation - band.x) / (band.y - band.x), 0.0, 1.0);
        fade = u32(round(t * (1.0 - steep) * 255.0));
        tree.impostor_allowed = steep < 1.0;
    }
    // A shadow view never fades a tree into its impostor, but casts it for
    // a tree past its budget: its level-2 lines, far wider than the view's
    // texels, would each cast one texel's width, a fraction of the crown's
    // shadow (a cascade's budget goes to the trees nearest its camera; the
    // farther ones' shadows would differ by far).
    if impostor && species.impostor_span.w > 0.5 && species.lod_enabled != 0u
        && (cull_view.perspective & VIEW_CAMERA) == 0u {
        tree.impostor_allowed = true;
    }
    tree.seen = true;
    tree.e = e;
    tree.code = threshold_code(e);
    // Every tree of a directional cascade has the same error: its budget
    // goes to the trees nearest the camera the cascade serves, whose
    // shadows that camera sees closest (`model::compact::budget_error`).
    tree.budget_code = tree.code;
    if cull_view.budget_origin.w > 0.0 {
        let origin = cull_view.budget_origin;
        tree.budget_code = threshold_code(error_from(origin.xyz, center, reach * scale, origin.w, budget_pixel_error, scale));
    }
    tree.fade = fade;
    tree.view_point = view_point;
    tree.pixel_error = pixel_error;
    tree.transition = transition;
    tree.opacity_rule = opacity_rule;
    return tree;
}

// Per tree: the placements its cut would expand, added to its budget
// bucket's demand (`model::compact::budget_expands`).
@compute @workgroup_size(64)
fn budget_demand(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= species.instance_count {
        return;
    }
    let tree = view_tree(i);
    if !tree.seen || tree.fade >= 255u {
        return;
    }
    let expanded = expanded_prefix(tree.code);
    if expanded > 0u {
        atomicAdd(&counters[COUNTER_DEMAND + (tree.budget_code >> BUDGET_BUCKET_SHIFT)], expanded);
    }
}

// One thread: the first bucket whose trees no longer fit after the
// buckets before it, and the entries those take
// (`model::compact::budget_cutoff`).
@compute @workgroup_size(1)
fn budget_cutoff() {
    var taken = 0u;
    var cutoff = BUDGET_BUCKETS;
    for (var b = 0u; b < BUDGET_BUCKETS; b += 1u) {
        let sum = taken + atomicLoad(&counters[COUNTER_DEMAND + b]);
        if sum > cull_view.entry_capacity || sum < taken {
            cutoff = b;
            break;
        }
        taken = sum;
    }
    atomicStore(&counters[COUNTER_CUTOFF], cutoff);
    atomicStore(&counters[COUNTER_CUTOFF_BASE], taken);
}

// Tree `i` drawn as its impostor alone (one quad, nothing expanded).
fn draw_impostor_alone(i: u32, tree: TreeView) {
    for (var kind = 0u; kind < KIND_COUNT; kind += 1u) {
        write_args(kind, i, 0u, 0u);
    }
    write_args(KIND_IMPOSTOR, i, 6u, 0u);
    instance_lods[i].code = (255u << LOD_FADE_SHIFT) | (tree.opacity_rule << LOD_OPACITY_SHIFT);
    instance_lods[i].spatial_error = tree.e;
    instance_lods[i].pixel_error = max(tree.pixel_error, 1e-6);
    instance_lods[i].transition = clamp(tree.transition, 0.0, 1.0);
    instance_lods[i].view = vec4<f32>(0.0);
}

@compute @workgroup_size(64)
fn cull(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= species.instance_count {
        return;
    }
    let tree = view_tree(i);
    if !tree.seen {
        hide(i);
        return;
    }
    let e = tree.e;
    let fade = tree.fade;
    let pixel_error = tree.pixel_error;
    let transition = tree.transition;
    let opacity_rule = tree.opacity_rule;
    var view_point = tree.view_point;
    if fade >= 255u {
        draw_impostor_alone(i, tree);
        return;
    }
    var code = tree.code;
    if species.placement_count > 0u {
        let expanded = expand_placements(i, code, tree.budget_code);
        if expanded != code {
            // Past the budget: its impostor where the view may draw one
            // (its level-2 lines alone read as bare branches near the
            // camera, and cast a fraction of the crown's shadow), else its
            // coarser cut at one error.
            if tree.impostor_allowed {
                draw_impostor_alone(i, tree);
                return;
            }
            view_point = vec4<f32>(0.0);
        }
        code = expanded;
    }
    let prisms = prism_prefix(code);
    let by_parent = original_prefix(code);
    let after_prisms = species.needle_count - prisms;
    var lod_flags = 0u;
    var original = by_parent;
    var original_first = 0u;
    if after_prisms < by_parent {
        original = after_prisms;
        original_first = line_vertices() * prisms;
        lod_flags = LOD_ORIGINAL_FROM_NEEDLES;
    }
    if species.lod_enabled == 0u {
        original = 0u;
    }
    let merged = select(0u, merged_prefix(code), species.lod_enabled != 0u);
    let wood_prisms = wood_prefix(e, 1.0);
    let wood_lines = select(0u, wood_prefix(e, species.wood_line_fade), species.lod_enabled != 0u);
    instance_lods[i].code = code | lod_flags | (opacity_rule << LOD_OPACITY_SHIFT) | (fade << LOD_FADE_SHIFT);
    instance_lods[i].spatial_error = e;
    instance_lods[i].pixel_error = max(pixel_error, 1e-6);
    instance_lods[i].transition = clamp(transition, 0.0, 1.0);
    instance_lods[i].view = view_point;
    write_args(KIND_PRISMS, i, prisms * species.prism_vertices, 0u);
    write_args(KIND_ORIGINAL_LINES, i, line_vertices() * original, original_first);
    write_args(KIND_MERGED_LINES, i, line_vertices() * merged, 0u);
    // In wind a wood segment is drawn in sections (`wood_sections`).
    let sections = wood_sections(species.wind.z);
    write_args(KIND_WOOD_PRISMS, i, wood_prisms * species.prism_vertices * sections, 0u);
    // Wood lines: the segments after the prisms, up to the fade; seen from
    // a view point, every segment up to the fade (each decides by its own
    // sphere's error).
    var wood_lines_first = min(wood_prisms, wood_lines);
    if view_point.w > 0.0 {
        wood_lines_first = 0u;
    }
    write_args(KIND_WOOD_LINES, i, line_vertices() * sections * (wood_lines - wood_lines_first), line_vertices() * sections * wood_lines_first);
    write_args(KIND_WOOD_MESH, i, species.wood_index_count, 0u);
    write_args(KIND_IMPOSTOR, i, select(0u, 6u, fade > 0u), 0u);
}

// Reserves tree `tree`'s expanded placements in the view's entry list and
// writes them; returns the tree's threshold code. The budget goes to the
// nearest trees by `budget_code` (`budget_cutoff`): a tree below the cutoff bucket always
// fits; one in it fits if what is left holds it; one past it, or one in it
// that does not fit, gets the code that expands none (`cull` draws it as
// its impostor, or its coarser cut from the level-2 lines), the latter
// marking the part of its range that fits invalid. CPU reference:
// `model::compact::budget_expands`.
fn expand_placements(tree: u32, code: u32, budget_code: u32) -> u32 {
    let expanded = expanded_prefix(code);
    if expanded == 0u {
        return code;
    }
    let fallback = max(code, min(placements[0].parent_code, MAX_THRESHOLD_CODE));
    let bucket = budget_code >> BUDGET_BUCKET_SHIFT;
    let cutoff = atomicLoad(&counters[COUNTER_CUTOFF]);
    if bucket > cutoff {
        return fallback;
    }
    var base = 0u;
    if bucket < cutoff {
        base = atomicAdd(&counters[COUNTER_TOTAL], expanded);
    } else {
        base = atomicLoad(&counters[COUNTER_CUTOFF_BASE]) + atomicAdd(&counters[COUNTER_CUTOFF_TOTAL], expanded);
    }
    let capacity = cull_view.entry_capacity;
    if base + expanded > capacity || base + expanded < base {
        for (var j = base; j < min(base + expanded, capacity); j += 1u) {
            entries[j] = vec2<u32>(ENTRY_INVALID, ENTRY_INVALID);
        }
        return fallback;
    }
    for (var j = 0u; j < expanded; j += 1u) {
        entries[base + j] = vec2<u32>(tree, j);
    }
    return code;
}

fn counter_index(array_index: u32, draw: u32) -> u32 {
    return COUNTER_HEADER + array_index * species.prototype_count * PLACED_BANDS + draw;
}

fn depth_counter_index(array_index: u32, bucket: u32) -> u32 {
    return counter_index(ARRAY_MERGED_BY_OWN + 1u, 0u) + array_index * DEPTH_BUCKETS + bucket;
}

// Whether this view draws its expanded placements' lines back to front
// (a camera, whose buffers hold a draw and a split per entry).
fn depth_ordered() -> bool {
    return (cull_view.perspective & VIEW_DEPTH_ORDERED) != 0u;
}

// The depth bucket of expanded placement `placement` of tree `tree`: its
// prototype's sphere centre's distance from the camera.
fn entry_depth_bucket(tree: u32, placement: Placement) -> u32 {
    let sphere = prototypes[placement.prototype].sphere;
    let world_from_local = instance_world_from_local(instances[tree]) * placement_matrix(placement);
    let center = (world_from_local * vec4<f32>(sphere.xyz, 1.0)).xyz;
    return depth_bucket(length(center - cull_view.world_position.xyz));
}

// One thread: the entry count and the indirect dispatch over the entries.
@compute @workgroup_size(1)
fn prepare_dispatch() {
    // Below the cutoff the entries fill [0, base) exactly; the cutoff
    // bucket's follow from base.
    let reserved = atomicLoad(&counters[COUNTER_TOTAL]) + atomicLoad(&counters[COUNTER_CUTOFF_TOTAL]);
    let entries_written = min(reserved, cull_view.entry_capacity);
    atomicStore(&counters[COUNTER_ENTRIES], entries_written);
    dispatch[0] = (entries_written + 63u) / 64u;
    dispatch[1] = 1u;
    dispatch[2] = 1u;
}

// The draw (prototype · PLACED_BANDS + band) of an entry whose placement
// has threshold code `code`.
fn entry_draw(placement: Placement, code: u32) -> u32 {
    return placement.prototype * PLACED_BANDS + placement_band(prototypes[placement.prototype], code);
}

// Entry `i` of this frame's expanded placements; invalid past the last
// one written or in the range of a tree that did not fit.
fn written_entry(i: u32) -> vec2<u32> {
    if i >= atomicLoad(&counters[COUNTER_ENTRIES]) {
        return vec2<u32>(ENTRY_INVALID, ENTRY_INVALID);
    }
    return entries[i];
}

// Per entry: its placement's threshold code (the tree's error, or its own
// sphere's seen from the tree's view point, over the placement's scale),
// its draw's count and longest prefixes. Seen from a view point, an entry
// whose parent line is in reach of its own sphere's error is dropped.
// CPU reference: `model::compact::CompactSpecies::placed_view`.
@compute @workgroup_size(64)
fn count_placements(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    let entry = written_entry(i);
    if entry.x == ENTRY_INVALID {
        return;
    }
    let placement = placements[entry.y];
    let lod = instance_lods[entry.x];
    if lod.view.w > 0.0 && placement.parent_sphere != NO_SPHERE {
        let parent = threshold_code(sphere_error(lod, tree_spheres[placement.parent_sphere], species.wind_motion.y));
        if parent >= placement.parent_code {
            entries[i] = vec2<u32>(ENTRY_INVALID, ENTRY_INVALID);
            return;
        }
    }
    let prototype = prototypes[placement.prototype];
    let e = placement_error(lod, placement, prototype.sphere, species.wind_motion.y) / placement.translation_scale.w;
    let code = threshold_code(e);
    let draw = entry_draw(placement, code);
    let prisms = prism_prefix_in(prototype.needle_first, prototype.needle_count, code);
    atomicAdd(&counters[counter_index(ARRAY_COUNT, draw)], 1u);
    atomicMax(&counters[counter_index(ARRAY_PRISMS, draw)], prisms);
    atomicMax(&counters[counter_index(ARRAY_AFTER_PRISMS, draw)], prototype.needle_count - prisms);
    atomicMax(
        &counters[counter_index(ARRAY_BY_PARENT, draw)],
        original_prefix_in(prototype.original_first, prototype.original_count, code),
    );
    atomicMax(
        &counters[counter_index(ARRAY_MERGED, draw)],
        merged_prefix_in(prototype.merged_first, prototype.merged_count, code),
    );
    atomicMax(
        &counters[counter_index(ARRAY_MERGED_BY_OWN, draw)],
        merged_by_own_prefix_in(prototype.merged_by_own_first, prototype.merged_count, code),
    );
    entries[i] = vec2<u32>(entry.x, entry.y | (code << 16u));
    if depth_ordered() {
        atomicAdd(&counters[depth_counter_index(DEPTH_ARRAY_COUNT, entry_depth_bucket(entry.x, placement))], 1u);
    }
}

fn write_placed(kind: u32, draw: u32, vertex_count: u32, instance_count: u32, first_vertex: u32, first_instance: u32) {
    let slot = kind * species.prototype_count * PLACED_BANDS + draw;
    let drawn = vertex_count > 0u && instance_count > 0u;
    placed_args[slot].vertex_count = select(0u, vertex_count, drawn);
    placed_args[slot].instance_count = select(0u, instance_count, drawn);
    placed_args[slot].first_vertex = first_vertex;
    placed_args[slot].first_instance = first_instance;
}

// One thread: each draw's first entry (a running sum of the counts) and its
// indirect arguments; original lines come from the needles after the
// fewest prisms or from the parent-sorted order, merged lines from the
// parent-sorted order or the own-code order, whichever is shorter.
@compute @workgroup_size(1)
fn scan_placements() {
    var offset = 0u;
    let draws = species.prototype_count * PLACED_BANDS;
    for (var draw = 0u; draw < draws; draw += 1u) {
        let prototype = prototypes[draw / PLACED_BANDS];
        let count = atomicLoad(&counters[counter_index(ARRAY_COUNT, draw)]);
        let prisms = atomicLoad(&counters[counter_index(ARRAY_PRISMS, draw)]);
        let after_prisms = atomicLoad(&counters[counter_index(ARRAY_AFTER_PRISMS, draw)]);
        let by_parent = atomicLoad(&counters[counter_index(ARRAY_BY_PARENT, draw)]);
        let merged = atomicLoad(&counters[counter_index(ARRAY_MERGED, draw)]);
        let merged_by_own = atomicLoad(&counters[counter_index(ARRAY_MERGED_BY_OWN, draw)]);
        atomicStore(&counters[counter_index(ARRAY_OFFSET, draw)], offset);
        var flags = 0u;
        write_placed(
            PLACED_PRISMS, draw, prisms * species.prism_vertices, count,
            prototype.needle_first * species.prism_vertices, offset,
        );
        if after_prisms < by_parent {
            flags |= ENTRY_FROM_NEEDLES;
            let first = prototype.needle_first + prototype.needle_count - after_prisms;
            write_placed(PLACED_ORIGINAL_LINES, draw, line_vertices() * after_prisms, count, line_vertices() * first, offset);
        } else {
            write_placed(PLACED_ORIGINAL_LINES, draw, line_vertices() * by_parent, count, line_vertices() * prototype.original_first, offset);
        }
        if merged_by_own < merged {
            flags |= ENTRY_MERGED_BY_OWN;
            write_placed(PLACED_MERGED_LINES, draw, line_vertices() * merged_by_own, count, line_vertices() * prototype.merged_by_own_first, offset);
        } else {
            write_placed(PLACED_MERGED_LINES, draw, line_vertices() * merged, count, line_vertices() * prototype.merged_first, offset);
        }
        atomicStore(&counters[counter_index(ARRAY_FLAGS, draw)], flags);
        offset += count;
    }
    // A camera's depth ranks: the farthest bucket first.
    if depth_ordered() {
        var rank = 0u;
        for (var b = DEPTH_BUCKETS; b > 0u; b -= 1u) {
            atomicStore(&counters[depth_counter_index(DEPTH_ARRAY_OFFSET, b - 1u)], rank);
            rank += atomicLoad(&counters[depth_counter_index(DEPTH_ARRAY_COUNT, b - 1u)]);
        }
    }
}

// The draw of one expanded placement's lines of one part: `lines` lines
// from line `first`, instance `slot` (the entry in the draws' sorted list).
fn ordered_draw(lines: u32, first: u32, slot: u32) -> DrawArgs {
    var args: DrawArgs;
    args.vertex_count = line_vertices() * lines;
    args.instance_count = select(0u, 1u, lines > 0u);
    args.first_vertex = line_vertices() * first;
    args.first_instance = slot;
    return args;
}

// Per entry: its slot in its draw's range of the sorted list.
@compute @workgroup_size(64)
fn scatter_placements(@builtin(global_invocation_id) id: vec3<u32>) {
    let entry = written_entry(id.x);
    if entry.x == ENTRY_INVALID {
        return;
    }
    let placement = placements[entry.y & 0xffffu];
    let draw = entry_draw(placement, entry.y >> 16u);
    let slot = atomicLoad(&counters[counter_index(ARRAY_OFFSET, draw)])
        + atomicAdd(&counters[counter_index(ARRAY_CURSOR, draw)], 1u);
    let flags = atomicLoad(&counters[counter_index(ARRAY_FLAGS, draw)]);
    sorted_entries[slot] = vec2<u32>(entry.x | flags, entry.y);
    if !depth_ordered() {
        return;
    }
    // Its lines' draw at its depth rank: its merged lines, then its
    // original lines, each as its draw's lines (the same order and first
    // line), as many as its own code takes (CPU reference:
    // `model::compact::CompactSpecies::entry_lines`).
    let bucket = entry_depth_bucket(entry.x, placement);
    let rank = atomicLoad(&counters[depth_counter_index(DEPTH_ARRAY_OFFSET, bucket)])
        + atomicAdd(&counters[depth_counter_index(DEPTH_ARRAY_CURSOR, bucket)], 1u);
    let prototype = prototypes[placement.prototype];
    let code = entry.y >> 16u;
    var original_first: u32;
    var original: u32;
    if (flags & ENTRY_FROM_NEEDLES) != 0u {
        let prisms = prism_prefix_in(prototype.needle_first, prototype.needle_count, code);
        original_first = prototype.needle_first + prisms;
        original = prototype.needle_count - prisms;
    } else {
        original_first = prototype.original_first;
        original = original_prefix_in(prototype.original_first, prototype.original_count, code);
    }
    var merged_first: u32;
    var merged: u32;
    if (flags & ENTRY_MERGED_BY_OWN) != 0u {
        merged_first = prototype.merged_by_own_first;
        merged = merged_by_own_prefix_in(prototype.merged_by_own_first, prototype.merged_count, code);
    } else {
        merged_first = prototype.merged_first;
        merged = merged_prefix_in(prototype.merged_first, prototype.merged_count, code);
    }
    ordered_args[rank] = ordered_draw(merged + original, merged_first, slot);
    ordered_splits[slot] = vec2<u32>(merged_first + merged, original_first);
}
