// The compact render path's draw: every part of every tree of a species
// pulls its vertices from the species' storage arrays (no vertex or index
// buffers), keeps the primitives of its indirect-draw prefix whose own
// error interval holds the tree's threshold code (written per view by
// `conifer_cull.wgsl`), and is lit by Bevy's PBR functions (lights,
// shadows, fog, tonemapping as for any mesh). CPU reference:
// `model::compact::CompactSpecies::drawn`.

#import bevy_pbr::{
    mesh_view_bindings::view,
    view_transformations::position_world_to_clip,
}
#ifdef CONIFER_MOTION_VECTORS
#import bevy_pbr::prepass_bindings::previous_view_uniforms
#endif
#ifndef CONIFER_SHADOW
#import bevy_pbr::{
    pbr_types,
    pbr_functions,
    mesh_types::MESH_FLAGS_SHADOW_RECEIVER_BIT,
}
#endif
#ifdef CONIFER_LINES
#ifndef CONIFER_SHADOW
#ifndef CONIFER_FACING_STRIP
#import bevy_pbr::{
    mesh_view_bindings as view_bindings,
    mesh_view_types,
    lighting,
    clustered_forward as clustering,
    shadows,
    ambient,
}
#ifdef ENVIRONMENT_MAP
#import bevy_pbr::environment_map
#endif
#endif
#endif
#endif
#import bevy_conifer_lod::compact_types::{
    Instance, InstanceLod, SpeciesParams, Placement, Prototype,
    LOD_CODE_MASK, LOD_ORIGINAL_FROM_NEEDLES, LOD_OPACITY_SHIFT, LOD_FADE_SHIFT,
    ENTRY_PLACEMENT_MASK, ENTRY_TREE_MASK, ENTRY_FROM_NEEDLES, ENTRY_MERGED_BY_OWN, NO_SPHERE,
    SPHERE_LIGHT_STEPS, CROWN_PROFILE_STEPS, CROWN_SHADE_STEPS, CROWN_SHADE_CLASSES, LINE_SCALE_STEPS, WOOD_NEARNESS_BINS, WOOD_OPACITY_NODES,
    SKY_VISIBILITY_RINGS, CROWN_DENSITY_RINGS, SHADOW_DEPTH_STEPS, WOOD_JOINED_START, WOOD_JOINED_END, VIEW_LIGHT_ANGLES, VIEW_LIGHT_ROLLS,
    instance_world_from_local, log_decode, placement_matrix, shoot_needle_color, bark_between,
    threshold_code, sphere_error, placement_error, tree_local_point, decode_wood_segment, wood_sections,
}

@group(2) @binding(0) var<uniform> species: SpeciesParams;
@group(2) @binding(1) var<storage, read> instances: array<Instance>;
@group(2) @binding(2) var<storage, read> instance_lods: array<InstanceLod>;
@group(2) @binding(3) var<storage, read> needles: array<vec4<u32>>;
// The original-line order, then the prototypes' merged lines by own code.
@group(2) @binding(4) var<storage, read> line_orders: array<u32>;
@group(2) @binding(5) var<storage, read> merged_lines: array<u32>;
@group(2) @binding(6) var<storage, read> wood_segments: array<vec4<u32>>;
@group(2) @binding(7) var<storage, read> wood_mesh: array<u32>;
@group(2) @binding(8) var<storage, read> placements: array<Placement>;
@group(2) @binding(9) var<storage, read> prototypes: array<Prototype>;
@group(2) @binding(10) var<storage, read> placed_entries: array<vec2<u32>>;
@group(2) @binding(11) var<storage, read> tree_spheres: array<vec4<f32>>;
@group(2) @binding(12) var<storage, read> tree_line_parents: array<u32>;
// The crown impostor's views (`model::impostor`), one layer each.
@group(2) @binding(13) var impostor_texture: texture_2d_array<f32>;
@group(2) @binding(14) var impostor_sampler: sampler;
// A camera's back-to-front line draws, one per expanded placement (by its
// index in `placed_entries`): where its merged lines end (the draw's first
// lines) and its first original line after them (CPU reference:
// `model::compact::CompactSpecies::entry_lines`). Other views bind a
// stand-in.
@group(2) @binding(15) var<storage, read> ordered_splits: array<vec2<u32>>;

const PI: f32 = 3.14159265358979;
// A line blends its motion into a pixel's where it covers at least this
// much of it (a line under 1/64 of a pixel hardly moves it).
const MOTION_MIN_OPACITY: f32 = 0.015625;
const TAU: f32 = 6.28318530717959;
// The line number an impostor's shadow hashes with (no line has it).
const IMPOSTOR_SHADOW_LINE: u32 = 0xfffffffeu;
// `model::shading::BUNDLE_SLOPE` and `ALIGNMENT_STEPS`.
const BUNDLE_SLOPE: f32 = 1.45;
const ALIGNMENT_STEPS: f32 = 15.0;
// `model::needle::BARK_ROUGHNESS`.
const BARK_ROUGHNESS: f32 = 0.9;
// `model::wind`'s constants.
const WOOD_LINE_SECTION_PIXELS: f32 = 2.0;
const WIND_TRUNK_LEAN: f32 = 0.008;
const WIND_TRUNK_SWAY: f32 = 0.005;
const WIND_BRANCH_SWAY: f32 = 0.015;
const WIND_FLUTTER: f32 = 0.015;
const WIND_GUST_WAVELENGTH: f32 = 60.0;
const WIND_BRANCH_WAVES: vec3<f32> = vec3<f32>(0.7, 1.1, 0.9);
const WIND_FLUTTER_WAVES: vec3<f32> = vec3<f32>(4.1, 3.3, 4.7);
const WIND_MAX_REACH_RATIO: f32 = 1.5;
const WIND_NORMAL_STEP: f32 = 0.01;
const WIND_BRANCH_HZ_OVER_TRUNK: f32 = 3.1;
const WIND_FLUTTER_HZ: f32 = 3.7;
const WIND_GUST_HZ: vec2<f32> = vec2<f32>(0.071, 0.173);
// A line's vertices: a quad of two triangles around its strip, covering
// each pixel by the strip's area there (`model::raster`), or a hardware
// line (`LineRaster::Hardware`, and shadow views unless
// `ConiferLodSettings::shadow_line_quads`).
#ifdef CONIFER_LINE_QUADS
const LINE_VERTICES: u32 = 6u;
// `model::raster::LINE_QUAD_MARGIN`.
const LINE_QUAD_MARGIN: f32 = 1.25;
// `model::raster::MAX_STRIP_WIDTH`.
const MAX_STRIP_WIDTH: f32 = 8.0;
// `model::raster::JOINT_REACH`.
const JOINT_REACH: f32 = 1.0;
#else
const LINE_VERTICES: u32 = 2u;
#endif

struct VertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) world_position: vec4<f32>,
    // A prism's normal; a line's direction (the axis of what it stands for).
    // Taken at the centroid of the pixel's covered samples: with MSAA a
    // fragment runs at the pixel's centre, and a prism's edge covering only
    // samples near it would have its normal extrapolated past the ring,
    // sideways, where a light from behind lights the rim.
    @location(1) @interpolate(perspective, centroid) world_normal: vec3<f32>,
#ifdef CONIFER_SHADOW
    @location(2) @interpolate(flat) color: vec4<f32>,
#else
    @location(2) color: vec4<f32>,
#endif
#ifdef CONIFER_IMPOSTOR
    // Where on the impostor's pictures (u right, v down) the calm card
    // point lies (outside [0, 1] on the margin the wind's sway needs).
    @location(3) uv: vec2<f32>,
    // The card's point (tree-local, calm) and its unit axes across and up.
    @location(7) card_point: vec3<f32>,
    @location(8) @interpolate(flat) card_right: vec3<f32>,
    @location(9) @interpolate(flat) card_up: vec3<f32>,
#endif
#ifdef CONIFER_BARK
    // Height in the tree's frame, for the bark's colour.
    @location(3) local_height: f32,
#endif
    // The tree's index in `instances` (its frame, for the crown's shade on
    // itself past the shadow maps and the impostor's picture).
    @location(4) @interpolate(flat) tree: u32,
#ifdef CONIFER_MOTION_VECTORS
    // Where the point stood the frame before (last frame's wind).
    @location(5) previous_world_position: vec4<f32>,
#endif
    // How well the needles a line stands for lie along it (1 for a
    // needle's own line and wood; `model::shading::AxisSpread::alignment`).
    @location(6) @interpolate(flat) alignment: f32,
#ifdef CONIFER_ROUND_PRISMS
    // A prism's ring frame (world, unit): across the view, its normals'
    // component along it the offset across the cylinder's width, and the
    // normal facing the view its ring was turned to.
    @location(10) @interpolate(flat) prism_side: vec3<f32>,
    @location(11) @interpolate(flat) prism_toward: vec3<f32>,
#endif
#ifdef CONIFER_LINE_QUADS
    // A line's ends in framebuffer pixels (start xy, end xy), as the
    // vertex stage placed them: the fragment covers its pixel by the
    // strip's area there.
    @location(12) @interpolate(flat) line_ends: vec4<f32>,
    // How wide (pixels) what the line stands for is, where that is over a
    // pixel (its strip is then that wide, each pixel covered by the
    // strip's area times the line's opacity); else 0 (the strip is the
    // opacity wide).
    @location(13) @interpolate(flat) line_width: f32,
    // Which of the line's ends run on into the next piece of one strip
    // (bit 0 the start, bit 1 the end: a branch's next segment, a bent
    // segment's next section): a wide line then covers only the pixels
    // whose centres lie between its joined ends, by its strip extended
    // past them (`line_coverage`).
    @location(14) @interpolate(flat) line_joints: u32,
#ifdef CONIFER_WOOD_LAYERS
    // A layered wood line's share in sight where the needles cover the
    // pixel (`model::impostor::WoodVisibility`): the fragment splits its
    // pixel's coverage between the two layers (`pixel_line_coverage`).
    @location(15) @interpolate(flat) wood_in_sight: f32,
#endif
#endif
}

// A position outside every clip plane: the primitive is not drawn.
fn culled() -> VertexOutput {
    var out: VertexOutput;
    out.position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    out.world_position = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    out.world_normal = vec3<f32>(0.0, 1.0, 0.0);
    out.color = vec4<f32>(0.0);
    return out;
}

// The world_from_local of the tree the vertex belongs to, set first thing
// by `vertex`: the frame of the tree's own parts, of its placements, and
// of the wind.
var<private> wind_tree: mat4x4<f32>;
// The index in `instances` of the tree the vertex belongs to (`finish`
// passes it on to the fragment).
var<private> vertex_tree: u32;
// The impostor's quad leans with the trunk only (its fragments move the
// picture by the rest of the field, `impostor_swayed_uv`).
var<private> wind_trunk_only: bool;
// Set while `finish` places a vertex where the wind held it the frame
// before.
var<private> wind_previous: bool;

// The wind's oscillators (radians; `model::wind::WindClock`).
struct WindClocks {
    trunk: f32,
    branch: f32,
    flutter: f32,
    gust: vec2<f32>,
}

// This frame's oscillators, or the previous frame's: each runs at a fixed
// rate (`model::wind::WindClock::at`), so `wind_step` seconds back is a
// known turn.
fn wind_clocks() -> WindClocks {
    var clocks = WindClocks(species.wind_motion.z, species.wind_motion.w, species.wind_clock.x, species.wind_clock.yz);
    if wind_previous {
        let turn = TAU * species.wind_step;
        let trunk_hz = clamp(0.3 * sqrt(20.0 / max(species.wind_shape.w, 1e-3)), 0.15, 1.0);
        clocks.trunk -= turn * trunk_hz;
        clocks.branch -= turn * trunk_hz * WIND_BRANCH_HZ_OVER_TRUNK;
        clocks.flutter -= turn * WIND_FLUTTER_HZ;
        clocks.gust -= turn * WIND_GUST_HZ;
    }
    return clocks;
}

// PCG hash (Jarzynski and Olano, "Hash Functions for GPU Rendering", JCGT 2020).
fn pcg(value: u32) -> u32 {
    let state = value * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// The world displacement of the tree's point at `world` (where it stands
// in calm): one field for every representation, so a needle's prism, its
// line and the merged lines that stand for it move together. CPU
// reference: `model::wind::wind_offset` and `WindOffset::world`.
fn wind_displacement(world: vec3<f32>) -> vec3<f32> {
    let strength = species.wind.z;
    if !(strength > 0.0) {
        return vec3<f32>(0.0);
    }
    let scale = length(wind_tree[0].xyz);
    let p = tree_local_point(wind_tree, scale, world);
    let direction = species.wind.xy;
    // The tree's own phases (`model::wind::TreeWindPhase::of_root`).
    let root = wind_tree[3].xyz;
    let cell_x = bitcast<u32>(i32(floor(root.x * 100.0)));
    let cell_z = bitcast<u32>(i32(floor(root.z * 100.0)));
    let sway_phase = f32(pcg(cell_x ^ pcg(cell_z)) >> 8u) / 16777216.0 * TAU;
    let gust_phase = -TAU * fract(dot(root.xz, direction) / WIND_GUST_WAVELENGTH);
    let clocks = wind_clocks();
    let gust = 0.6 * sin(clocks.gust.x + gust_phase) + 0.4 * sin(clocks.gust.y + 1.7 * gust_phase);
    let force = strength * (1.0 + species.wind.w * gust);
    let shape = species.wind_shape;
    let crown_radius = species.wind_clock.w;
    let h = clamp((p.y - shape.z) / shape.w, 0.0, 1.0);
    let r = min(length(p.xz - shape.xy) / crown_radius, WIND_MAX_REACH_RATIO);
    let trunk = force * shape.w * h * h * (WIND_TRUNK_LEAN + WIND_TRUNK_SWAY * sin(clocks.trunk + sway_phase));
    var along = trunk;
    var across = 0.0;
    var up = 0.0;
    if !wind_trunk_only {
        let branch_amplitude = force * WIND_BRANCH_SWAY * crown_radius * r * sqrt(r);
        let branch = clocks.branch + sway_phase + dot(p, WIND_BRANCH_WAVES);
        let flutter_amplitude = force * species.wind_motion.x * WIND_FLUTTER * r;
        let flutter = clocks.flutter + sway_phase + dot(p, WIND_FLUTTER_WAVES);
        along += 0.5 * branch_amplitude * sin(branch + 1.0);
        across = flutter_amplitude * sin(flutter);
        up = branch_amplitude * sin(branch) + 0.5 * flutter_amplitude * sin(flutter + 2.1);
    }
    let along_axis = vec3<f32>(direction.x, 0.0, direction.y);
    let across_axis = vec3<f32>(direction.y, 0.0, -direction.x);
    return (along_axis * along + across_axis * across + vec3<f32>(0.0, up, 0.0)) * scale;
}

// The world direction of the segment from `a` to `b` (in the frame of
// `world_from_local`) once the wind has moved both ends: a line is drawn
// between the moved ends and lit along this, and a prism's ring turns
// with it.
fn swayed_segment(a: vec3<f32>, b: vec3<f32>, world_from_local: mat4x4<f32>) -> vec3<f32> {
    let wa = (world_from_local * vec4<f32>(a, 1.0)).xyz;
    let wb = (world_from_local * vec4<f32>(b, 1.0)).xyz;
    return (wb + wind_displacement(wb)) - (wa + wind_displacement(wa));
}

// `normal` turned by the rotation taking the direction of `calm` to that
// of `swayed` (Rodrigues; CPU reference: `model::wind::turn_normal`).
fn turn_normal(normal: vec3<f32>, calm: vec3<f32>, swayed: vec3<f32>) -> vec3<f32> {
    if dot(calm, calm) < 1e-24 || dot(swayed, swayed) < 1e-24 {
        return normal;
    }
    let a = normalize(calm);
    let b = normalize(swayed);
    let c = dot(a, b);
    if c <= -0.999 {
        return normal;
    }
    let v = cross(a, b);
    return normalize(normal * c + cross(v, normal) + v * (dot(v, normal) / (1.0 + c)));
}

// `out` (a prism of the segment `a`–`b`) with its normal turned as the
// wind turns the segment.
fn swayed_prism(out: VertexOutput, a: vec3<f32>, b: vec3<f32>, world_from_local: mat4x4<f32>) -> VertexOutput {
    var result = out;
#ifndef CONIFER_SHADOW
    // (Shadow passes light nothing: their normals go unused.)
    if species.wind.z > 0.0 {
        let calm = (world_from_local * vec4<f32>(b - a, 0.0)).xyz;
        let swayed = swayed_segment(a, b, world_from_local);
        result.world_normal = turn_normal(out.world_normal, calm, swayed);
#ifdef CONIFER_ROUND_PRISMS
        result.prism_side = turn_normal(out.prism_side, calm, swayed);
        result.prism_toward = turn_normal(out.prism_toward, calm, swayed);
#endif
    }
#endif
    return result;
}

// `out` (a corner of the prism from `a` to `b` whose ring faces `toward`,
// in the frame of `world_from_local`) with the prism's ring frame, as
// `prism_vertex` turns its ring.
fn with_prism_side(out: VertexOutput, a: vec3<f32>, b: vec3<f32>, toward: vec3<f32>, world_from_local: mat4x4<f32>) -> VertexOutput {
    var result = out;
#ifdef CONIFER_ROUND_PRISMS
    var axis = b - a;
    if dot(axis, axis) < 1e-24 {
        axis = vec3<f32>(0.0, 1.0, 0.0);
    }
    axis = normalize(axis);
    let facing = facing_axis(axis, toward);
    let side = (world_from_local * vec4<f32>(cross(axis, facing), 0.0)).xyz;
    let front = (world_from_local * vec4<f32>(facing, 0.0)).xyz;
    result.prism_side = side / max(length(side), 1e-20);
    result.prism_toward = front / max(length(front), 1e-20);
#endif
    return result;
}

// `out` (a line from `a` to `b`) lit along the segment the wind moved it to.
fn swayed_line(out: VertexOutput, a: vec3<f32>, b: vec3<f32>, world_from_local: mat4x4<f32>, at_b: bool) -> VertexOutput {
    var result = out;
#ifndef CONIFER_SHADOW
    if species.wind.z > 0.0 {
        // `finish` has moved this vertex's end; only the other end's
        // displacement is left to evaluate.
        let other = (world_from_local * vec4<f32>(select(b, a, at_b), 1.0)).xyz;
        let moved = other + wind_displacement(other);
        let swayed = select(moved - out.world_position.xyz, out.world_position.xyz - moved, at_b);
        if dot(swayed, swayed) > 1e-24 {
            result.world_normal = normalize(swayed);
        }
    }
#endif
    return result;
}

// Whether line vertex `vertex_index` lies at the line's end (else its
// start): a hardware line's second vertex, or a quad corner at the end
// (CPU reference: `model::raster::line_quad_corner_ends`).
fn line_vertex_at_end(vertex_index: u32) -> bool {
#ifdef CONIFER_LINE_QUADS
    let corner = vertex_index % 6u;
    return corner == 1u || corner == 2u || corner == 4u;
#else
    return (vertex_index & 1u) != 0u;
#endif
}

#ifdef CONIFER_LINE_QUADS
// Framebuffer pixel of a clip position in front of the near plane.
fn clip_to_pixel(clip: vec4<f32>) -> vec2<f32> {
    let ndc = clip.xy / clip.w;
    return view.viewport.xy + vec2<f32>(0.5 + 0.5 * ndc.x, 0.5 - 0.5 * ndc.y) * view.viewport.zw;
}
#endif

// `out` (the vertex `vertex_index` of a line from `a` to `b`, at the end
// `line_vertex_at_end` gives, moved by the wind) as a corner of the line's
// quad: both ends clipped to the near plane and projected to pixels, the
// corner pushed out along the segment and across it by the strip's half
// width and `LINE_QUAD_MARGIN` (CPU reference:
// `model::raster::line_quad_corner`), kept at its end's depth; in a
// shadow view the strip itself, at least a texel wide
// (`model::raster::shadow_line_quad_corner`), a directional cascade's
// ends flattened onto its near plane, not clipped. A hardware line's
// vertex is `out` itself.
fn with_line_quad(out: VertexOutput, a: vec3<f32>, b: vec3<f32>, world_from_local: mat4x4<f32>, vertex_index: u32) -> VertexOutput {
#ifdef CONIFER_LINE_QUADS
    var result = out;
    let corner = vertex_index % 6u;
    let at_end = line_vertex_at_end(vertex_index);
    let left = corner == 2u || corner == 4u || corner == 5u;
    let calm = (world_from_local * vec4<f32>(select(b, a, at_end), 1.0)).xyz;
    let there_world = calm + wind_displacement(calm);
    var there = position_world_to_clip(there_world);
    // How far (pixels) the quad's corners lie past the line's ends along
    // the segment and from it across.
    let strip = strip_of(out.color.a, out.line_width);
    var reach_along = 0.5 * strip + LINE_QUAD_MARGIN;
    var reach_across = reach_along;
#ifdef CONIFER_MOTION_VECTORS
#else ifdef CONIFER_SHADOW
    // A directional cascade flattens the far end onto its near plane as
    // `finish` flattens this one: the line is cast whole, not clipped.
    there = flattened_onto_cascade(there);
    // A shadow view keeps each texel its quad covers with the line's
    // opacity (hashed), so the quad is the strip itself, at least a texel
    // wide (a thinner strip's opacity is its width), its ends exact: it
    // covers the strip's area on average, with no fragment off it.
    reach_along = 0.0;
    reach_across = 0.5 * max(strip, 1.0);
#endif
    var here = out.position;
    // In front of the near plane where w ≥ z (reversed Z; an orthographic
    // view's near plane is z = 1 = w).
    let d_here = here.w - here.z;
    let d_there = there.w - there.z;
    if !(d_here >= 0.0) && !(d_there >= 0.0) {
        return culled();
    }
    if !(d_here >= 0.0) {
        let t = d_here / (d_here - d_there);
        here = mix(here, there, t);
        result.world_position = vec4<f32>(mix(out.world_position.xyz, there_world, t), 1.0);
    } else if !(d_there >= 0.0) {
        there = mix(there, here, d_there / (d_there - d_here));
    }
    let p_here = clip_to_pixel(here);
    let p_there = clip_to_pixel(there);
    let start = select(p_here, p_there, at_end);
    let end = select(p_there, p_here, at_end);
    let d = end - start;
    let span = sqrt(dot(d, d));
    var along = vec2<f32>(1.0, 0.0);
    if span > 1e-6 {
        along = d / span;
    }
    let across = vec2<f32>(-along.y, along.x);
    let pixel = p_here + reach_along * select(-1.0, 1.0, at_end) * along + reach_across * select(-1.0, 1.0, left) * across;
    let ndc = 2.0 * (pixel - view.viewport.xy) / view.viewport.zw - vec2<f32>(1.0);
    result.position = vec4<f32>(vec2<f32>(ndc.x, -ndc.y) * here.w, here.z, here.w);
    result.line_ends = vec4<f32>(start, end);
    return result;
#else
    return out;
#endif
}

// `out` (a line's vertex) standing for something `pixels` wide, where
// the view covers pixels by its lines' areas: wider than a pixel, its
// strip is that wide (`strip_of`); else the opacity wide. Set before
// `with_line_quad`, which reaches past the strip.
fn with_line_width(out: VertexOutput, pixels: f32) -> VertexOutput {
#ifdef CONIFER_LINE_QUADS
    var result = out;
    result.line_width = select(0.0, pixels, pixels > 1.0);
    return result;
#else
    return out;
#endif
}

// `out` (a line's vertex) whose start and end run on into the next piece
// of one strip where `start` and `end` are set (`line_coverage`).
fn with_line_joints(out: VertexOutput, start: bool, end: bool) -> VertexOutput {
#ifdef CONIFER_LINE_QUADS
    var result = out;
    result.line_joints = select(0u, 1u, start) | select(0u, 2u, end);
    return result;
#else
    return out;
#endif
}

#ifdef CONIFER_LINE_QUADS
// The strip (pixels) a line of `opacity` standing for something `width`
// pixels wide covers: that width where it is over a pixel (at most
// `MAX_STRIP_WIDTH`), else the opacity (CPU reference:
// `model::raster::line_strip_width`).
fn strip_of(opacity: f32, width: f32) -> f32 {
    if width > 1.0 {
        return min(width, MAX_STRIP_WIDTH);
    }
    return clamp(opacity, 0.0, 1.0);
}
#endif

// A line of equivalent width `width` (metres) at `spatial_error`, in
// pixels, unclamped: what it stands for, where the line's opacity rule
// keeps its area (not the paper's, whose lines are one pixel at most); 0
// under the paper's rule.
fn line_pixels(lod: InstanceLod, spatial_error: f32, width: f32) -> f32 {
    if ((lod.code >> LOD_OPACITY_SHIFT) & 3u) == 0u {
        return 0.0;
    }
    return width * lod.pixel_error / max(spatial_error, 1e-12);
}

// The world normal `normal` of a surface at (calm) world point `world`,
// turned as the wind field bends the surface there: the cofactor of the
// field's Jacobian, from differences a centimetre apart (CPU reference:
// `model::wind::turned_surface_normal`).
fn swayed_surface_normal(world: vec3<f32>, normal: vec3<f32>) -> vec3<f32> {
    if !(species.wind.z > 0.0) {
        return normal;
    }
    let h = WIND_NORMAL_STEP * length(wind_tree[0].xyz);
    let d = wind_displacement(world);
    let j0 = vec3<f32>(1.0, 0.0, 0.0) + (wind_displacement(world + vec3<f32>(h, 0.0, 0.0)) - d) / h;
    let j1 = vec3<f32>(0.0, 1.0, 0.0) + (wind_displacement(world + vec3<f32>(0.0, h, 0.0)) - d) / h;
    let j2 = vec3<f32>(0.0, 0.0, 1.0) + (wind_displacement(world + vec3<f32>(0.0, 0.0, h)) - d) / h;
    let turned = cross(j1, j2) * normal.x + cross(j2, j0) * normal.y + cross(j0, j1) * normal.z;
    if dot(turned, turned) < 1e-24 {
        return normal;
    }
    return normalize(turned);
}

// `clip` in a directional shadow map flattened onto the cascade's near
// plane ("pancaking"): casters nearer the light than the plane still cast,
// not clipped. Other views' positions are kept.
fn flattened_onto_cascade(clip: vec4<f32>) -> vec4<f32> {
    var result = clip;
    if view.clip_from_view[3][3] == 1.0 {
        result.z = min(result.z, 1.0);
    }
    return result;
}

fn finish(local_position: vec3<f32>, local_normal: vec3<f32>, world_from_local: mat4x4<f32>, color: vec4<f32>) -> VertexOutput {
    var out: VertexOutput;
    let calm = (world_from_local * vec4<f32>(local_position, 1.0)).xyz;
    out.world_position = vec4<f32>(calm + wind_displacement(calm), 1.0);
    out.position = position_world_to_clip(out.world_position.xyz);
#ifdef CONIFER_MOTION_VECTORS
    wind_previous = true;
    out.previous_world_position = vec4<f32>(calm + wind_displacement(calm), 1.0);
    wind_previous = false;
#else ifdef CONIFER_SHADOW
    out.position = flattened_onto_cascade(out.position);
#endif
    out.world_normal = normalize((world_from_local * vec4<f32>(local_normal, 0.0)).xyz);
    out.color = color;
    out.tree = vertex_tree;
    return out;
}

// `out` with the tree-local height the bark's colour is taken at.
fn with_height(out: VertexOutput, height: f32) -> VertexOutput {
    var result = out;
#ifdef CONIFER_BARK
    result.local_height = height;
#endif
    return result;
}

fn grid_point(grid: vec4<f32>, x: u32, y: u32, z: u32) -> vec3<f32> {
    return grid.xyz + vec3<f32>(f32(x), f32(y), f32(z)) * grid.w;
}

fn needle_base(grid: vec4<f32>, k: u32) -> vec3<f32> {
    let w = needles[k];
    return grid_point(grid, w.x & 0xffffu, w.x >> 16u, w.y & 0xffffu);
}

fn needle_tip(grid: vec4<f32>, k: u32) -> vec3<f32> {
    let w = needles[k];
    return grid_point(grid, w.y >> 16u, w.z & 0xffffu, w.z >> 16u);
}

fn end_position(grid: vec4<f32>, reference: u32) -> vec3<f32> {
    let k = (reference & 0xffffffu) >> 1u;
    if (reference & 1u) != 0u {
        return needle_tip(grid, k);
    }
    return needle_base(grid, k);
}

// Sides of a prism of radius `radius` at spatial error `e`: ⌈π / arccos(1 − e/R)⌉.
fn prism_sides(radius: f32, e: f32) -> u32 {
    let max_sides = max(species.max_sides, 3u);
    let rho = e / max(radius, 1e-12);
    if rho >= 1.0 {
        return 3u;
    }
    if rho <= 0.0 {
        return max_sides;
    }
    return clamp(u32(ceil(PI / acos(1.0 - rho))), 3u, max_sides);
}

struct PrismCorner {
    slot: u32,
    at_tip: bool,
    cap: bool,
}

// Vertex `local` of an Lmax-slot prism, drawn without indices: Lmax side
// quads (two triangles each), then the base and the tip cap as fans, in the
// triangle order and winding of `model::prism::append_prism` (CPU
// reference: `model::compact::prism_corner`).
fn prism_corner(local: u32) -> PrismCorner {
    let m = max(species.max_sides, 3u);
    var corner: PrismCorner;
    if local < 6u * m {
        let quad = local / 6u;
        let j = local % 6u;
        let next = (quad + 1u) % m;
        // (base q, base q+1, tip q+1), (base q, tip q+1, tip q)
        corner.slot = select(quad, next, j == 1u || j == 2u || j == 4u);
        corner.at_tip = j == 2u || j == 4u || j == 5u;
        corner.cap = false;
        return corner;
    }
    let t = local - 6u * m;
    let fan = 3u * (m - 2u);
    corner.at_tip = t >= fan;
    let u = t % fan;
    let k = u / 3u + 1u;
    let j = u % 3u;
    // Tip: (0, k, k+1), facing +axis; base: (0, k+1, k), facing −axis.
    var slot = select(k + 1u, k, (j == 1u) == corner.at_tip);
    if j == 0u {
        slot = 0u;
    }
    corner.slot = slot;
    corner.cap = true;
    return corner;
}

// Position and normal of a prism corner of the (tapered) cylinder from
// `base` to `tip`, drawn with `sides` sides.
struct PrismVertex {
    position: vec3<f32>,
    normal: vec3<f32>,
}

// The unit normal of the unit `axis` that faces `toward` (the direction to
// the view): a prism's ring and a line's cylinder are turned by it. Seen
// along the axis, Duff et al.'s basis (JCGT 2017). CPU reference:
// `model::shading::visible_frame`.
fn facing_axis(axis: vec3<f32>, toward: vec3<f32>) -> vec3<f32> {
    let across = toward - axis * dot(axis, toward);
    if dot(across, across) >= 1e-12 * max(dot(toward, toward), 1e-30) {
        return normalize(across);
    }
    return ring_basis(axis)[0];
}

// Two unit vectors square to unit `axis` and to each other, Duff et al.'s
// basis (JCGT 2017; CPU reference: `model::compact::ring_basis`).
fn ring_basis(axis: vec3<f32>) -> array<vec3<f32>, 2> {
    let sign = select(-1.0, 1.0, axis.z >= 0.0);
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    return array<vec3<f32>, 2>(
        vec3<f32>(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x),
        vec3<f32>(b, sign + axis.y * axis.y * a, -axis.y),
    );
}

// The direction to the view from `local_point`, in the frame of
// `world_from_local` (a rotation and a uniform scale, whose transpose maps
// directions back up to that scale): toward the camera in a perspective
// view, the view's backward axis in an orthographic one (directional
// shadow maps).
fn toward_view_local(world_from_local: mat4x4<f32>, local_point: vec3<f32>) -> vec3<f32> {
    var toward = view.world_from_view[2].xyz;
    if view.clip_from_view[3][3] != 1.0 {
        toward = view.world_position - (world_from_local * vec4<f32>(local_point, 1.0)).xyz;
    }
    let m = mat3x3<f32>(world_from_local[0].xyz, world_from_local[1].xyz, world_from_local[2].xyz);
    return transpose(m) * toward;
}

// A vertex of an `sides`-sided prism whose ring faces the view: its first
// corner toward the viewer (odd sides) or half a step off (sides 2 mod 4),
// so the silhouette is centred on the axis, and `2r` wide, the
// cylinder's: an odd ring's corners stand `1/cos(π/2m)` radii out (CPU
// reference: `model::compact::prism_ring`).
fn prism_vertex(base: vec3<f32>, tip: vec3<f32>, base_radius: f32, tip_radius: f32, sides: u32, corner: PrismCorner, toward: vec3<f32>) -> PrismVertex {
    let m = max(species.max_sides, 3u);
    let k = corner.slot * sides / m;
    let phase = select(0.0, PI / f32(sides), sides % 4u == 2u);
    let angle = TAU * f32(k) / f32(sides) + phase;
    var axis = tip - base;
    if dot(axis, axis) < 1e-24 {
        axis = vec3<f32>(0.0, 1.0, 0.0);
    }
    axis = normalize(axis);
    let u = facing_axis(axis, toward);
    let v = cross(axis, u);
    let radial = u * cos(angle) + v * sin(angle);
    var out: PrismVertex;
    let end = select(base, tip, corner.at_tip);
    let radius = select(base_radius, tip_radius, corner.at_tip);
    let widen = select(1.0, 1.0 / cos(PI / f32(2u * sides)), sides % 2u == 1u);
    out.position = end + radial * (radius * widen);
    out.normal = radial;
    if corner.cap {
        out.normal = select(-axis, axis, corner.at_tip);
    }
    return out;
}

// Debug colours: prisms blue → cyan by side count, original lines green,
// merged lines yellow → red by error, wood brown.
fn debug_color(kind: i32, amount: f32) -> vec3<f32> {
    if kind < 0 {
        return vec3<f32>(0.1, 0.3 + 0.7 * amount, 1.0);
    }
    if kind == 0 {
        return vec3<f32>(0.1, 0.9, 0.1);
    }
    if kind == 1 {
        return vec3<f32>(1.0, 1.0 - amount, 0.05);
    }
    return vec3<f32>(0.45, 0.3, 0.15);
}

// `albedo` with `alpha`, or the debug colour of `kind` and `amount`.
fn base_color(kind: i32, amount: f32, alpha: f32, albedo: vec3<f32>) -> vec4<f32> {
    if species.debug_colors != 0u {
        return vec4<f32>(debug_color(kind, amount), alpha);
    }
    return vec4<f32>(albedo, alpha);
}

// `model::color::NEEDLE_MATURE_YEARS`.
const NEEDLE_MATURE_YEARS: f32 = 2.0;

// Needles `age` years old (`model::color::needle_age_color`).
fn needle_age_albedo(age: u32) -> vec3<f32> {
    let t = clamp(f32(age) / NEEDLE_MATURE_YEARS, 0.0, 1.0);
    return mix(species.young_needle_color.rgb, species.needle_color.rgb, t);
}

// A placed shoot's needles seen from the view (`model::color::needle_color`,
// from the centre of the prototype's sphere).
fn placed_needle_albedo(placement: Placement, prototype: Prototype, world_from_local: mat4x4<f32>) -> vec3<f32> {
    return shoot_needle_color(
        needle_age_albedo(placement.needle_age),
        species.needle_underside_color.rgb,
        unpack4x8snorm(prototype.upper_side).xyz,
        prototype.sphere.xyz,
        world_from_local,
        view.world_position,
    );
}

// Bark at tree-local `height` (`model::color::bark_color`).
fn bark_albedo(height: f32) -> vec3<f32> {
    return bark_between(species.wood_color.rgb, species.upper_wood_color.rgb, species.wood_heights.xy, height);
}

// A line of equivalent width `width` (metres) as coverage of its one-pixel
// line: the paper's `T = 2R/e` (`paper_width` is 2R for an original line,
// e(X) for a merged one), or the width over the pixel size
// (`line_pixels`), at most 1.
fn line_alpha(lod: InstanceLod, spatial_error: f32, width: f32, paper_width: f32) -> f32 {
    if ((lod.code >> LOD_OPACITY_SHIFT) & 3u) == 0u {
        return min(paper_width / max(spatial_error, 1e-12), 1.0);
    }
    return min(line_pixels(lod, spatial_error, width), 1.0);
}

// A merged line: as `line_alpha`, except under the coverage rule (2),
// where its needles overlap at random in its footprint: `1 − exp(−Σa/A)`
// (`model::metric::merged_line_coverage`).
fn merged_line_alpha(lod: InstanceLod, spatial_error: f32, width: f32, paper_width: f32) -> f32 {
    if ((lod.code >> LOD_OPACITY_SHIFT) & 3u) == 2u {
        return 1.0 - exp(-width * lod.pixel_error / max(spatial_error, 1e-12));
    }
    return line_alpha(lod, spatial_error, width, paper_width);
}

// The record's calibrated scale of a needle line's opacity at
// `spatial_error` (its pixel size in metres is the spatial error over the
// pixel error), interpolated in log size and clamped to the table's ends
// (CPU reference: `model::calibration::LineCalibration::scale_at`). Lines
// drawn by their area under the area-preserving rule only: the table is
// measured for them.
fn line_calibration(lod: InstanceLod, spatial_error: f32) -> f32 {
#ifdef CONIFER_LINE_QUADS
    if ((lod.code >> LOD_OPACITY_SHIFT) & 3u) != 1u {
        return 1.0;
    }
    let t = line_scale_step(lod, spatial_error);
    let k = min(u32(t), LINE_SCALE_STEPS - 2u);
    let below = species.line_scales[k / 4u][k % 4u];
    let above = species.line_scales[(k + 1u) / 4u][(k + 1u) % 4u];
    return mix(below, above, t - f32(k));
#else
    return 1.0;
#endif
}

// Where the line scale tables hold a line of `spatial_error`: its pixel
// size's step, fractional, clamped to the tables' ends.
fn line_scale_step(lod: InstanceLod, spatial_error: f32) -> f32 {
    let pixel = max(spatial_error, 1e-12) / max(lod.pixel_error, 1e-6);
    let last = f32(LINE_SCALE_STEPS - 1u);
    return clamp((log2(pixel) - species.line_scale_range.x) * species.line_scale_range.y, 0.0, last);
}

// The record's calibrated scale of a wood line of opacity `opacity` at
// `spatial_error`: the wood table bilinear in log size and in log opacity
// between its nodes at 1/64, 1/16, 1/4 and 1 (CPU reference:
// `model::calibration::LineCalibration::wood_scale_at`); area lines
// under the area-preserving rule only, as `line_calibration`.
fn wood_line_calibration(lod: InstanceLod, spatial_error: f32, opacity: f32) -> f32 {
#ifdef CONIFER_LINE_QUADS
    if ((lod.code >> LOD_OPACITY_SHIFT) & 3u) != 1u {
        return 1.0;
    }
    let t = line_scale_step(lod, spatial_error);
    let k = min(u32(t), LINE_SCALE_STEPS - 2u);
    let node = clamp(0.5 * (log2(max(opacity, 1e-12)) + 6.0), 0.0, f32(WOOD_OPACITY_NODES - 1u));
    let j = min(u32(node), WOOD_OPACITY_NODES - 2u);
    let below = mix(species.wood_line_scales[k][j], species.wood_line_scales[k][j + 1u], node - f32(j));
    let above = mix(species.wood_line_scales[k + 1u][j], species.wood_line_scales[k + 1u][j + 1u], node - f32(j));
    return mix(below, above, t - f32(k));
#else
    return 1.0;
#endif
}

#ifdef CONIFER_WOOD_LAYERS
// This draw's layer of a wood line covering `a` of a pixel whose wood the
// needles leave `in_sight` in sight: `a·(1 − g)/(1 − a·g)` under the
// foliage lines, `a·g` over them (CPU reference:
// `model::impostor::wood_layer_opacities`).
fn wood_layer_opacity(a: f32, in_sight: f32) -> f32 {
#ifdef CONIFER_WOOD_OVER_FOLIAGE
    return a * in_sight;
#else
    return a * (1.0 - in_sight) / max(1.0 - a * in_sight, 1e-6);
#endif
}
#endif

// How far a tree has faded into its impostor, in [0, 1].
fn impostor_fade(lod: InstanceLod) -> f32 {
    return f32(lod.code >> LOD_FADE_SHIFT) / 255.0;
}

// `model::impostor::CROSSFADE_THRESHOLDS`: ordered dithering's 4×4
// threshold map, a row a word, a column a byte (as Bevy's
// `visibility_range_dither` packs it); under 4× MSAA
// `CROSSFADE_SAMPLE_THRESHOLDS`' 2×2, row by row a byte each.
const CROSSFADE_THRESHOLDS: vec4<u32> = vec4<u32>(0x0a020800u, 0x060e040cu, 0x09010b03u, 0x050d070fu);
const CROSSFADE_SAMPLE_THRESHOLDS: u32 = 0x01030200u;

// The samples of framebuffer pixel `pixel` (a mask) the impostor, rather
// than the tree's cut, draws for instance `tree` faded by `fade_code`
// (0–255): the two take complementary samples, `round(16·fade)` of every
// 16 thresholds the impostor's, so the crown keeps its coverage through
// the fade. Under 4× MSAA (`CONIFER_CROSSFADE_SAMPLES`) the thresholds are
// a 2×2 block's samples, else a 4×4 block's pixels whole. CPU reference:
// `model::impostor::impostor_samples`.
fn impostor_samples(pixel: vec2<f32>, tree: u32, fade_code: u32) -> u32 {
    let offset = pcg(tree);
#ifdef CONIFER_CROSSFADE_SAMPLES
    let p = (vec2<u32>(pixel) + vec2<u32>(offset & 1u, (offset >> 1u) & 1u)) % vec2<u32>(2u);
    let base = (CROSSFADE_SAMPLE_THRESHOLDS >> ((2u * p.y + p.x) * 8u)) & 0xffu;
    var mask = 0u;
    for (var s = 0u; s < 4u; s += 1u) {
        if 255u * (2u * (4u * s + base) + 1u) < 32u * fade_code {
            mask |= 1u << s;
        }
    }
    return mask;
#else
    let p = (vec2<u32>(pixel) + vec2<u32>(offset & 3u, (offset >> 2u) & 3u)) % vec2<u32>(4u);
    let threshold = (CROSSFADE_THRESHOLDS[p.y] >> (p.x * 8u)) & 0xffu;
    return select(0u, 0xffffffffu, 255u * (2u * threshold + 1u) < 32u * fade_code);
#endif
}

// The samples of its pixel a camera pass's fragment of tree `tree` draws
// (a mask; 0: none): while the tree fades into its impostor
// (`impostor_samples`) the impostor draws its samples and the cut
// (prisms, lines, wood) the others; outside the fade all of them.
fn crossfade_samples(pixel: vec2<f32>, tree: u32) -> u32 {
    let fade_code = instance_lods[tree].code >> LOD_FADE_SHIFT;
#ifdef CONIFER_IMPOSTOR
    return impostor_samples(pixel, tree, fade_code);
#else
    if fade_code == 0u {
        return 0xffffffffu;
    }
    return ~impostor_samples(pixel, tree, fade_code);
#endif
}

// A line's colour; in shadow passes its index and tree (for the hashed
// alpha test) and its opacity. (A camera hands each sample of a fading
// tree to its lines or its impostor: `crossfade_samples`.)
fn line_color(color: vec4<f32>, line: u32, tree: u32) -> vec4<f32> {
#ifdef CONIFER_SHADOW
    return vec4<f32>(f32(line & 0xffffffu), f32(tree & 0xffffffu), 0.0, color.a);
#else
    return color;
#endif
}

// Spatial error of a wood segment (`start`, `end`: centre and radius of
// each end): the tree's, or seen from a view point, its own sphere's (the
// one `model::view` bounds it by).
fn wood_segment_error(lod: InstanceLod, start: vec4<f32>, end: vec4<f32>, tree_error: f32) -> f32 {
    if lod.view.w > 0.0 {
        let sphere = vec4<f32>(0.5 * (start.xyz + end.xyz), 0.5 * distance(start.xyz, end.xyz) + max(start.w, end.w));
        return sphere_error(lod, sphere, species.wind_motion.y);
    }
    return tree_error;
}

// What a foliage line's vertex takes from the tree or the expanded
// placement it is drawn in (`vertex`'s opening).
struct LineFrame {
    lod: InstanceLod,
    code: u32,
    spatial_error: f32,
    world_from_local: mat4x4<f32>,
    grid: vec4<f32>,
    needle_albedo: vec3<f32>,
    hash_tree: u32,
    original_from_needles: bool,
    merged_by_own: bool,
}

// Vertex `vertex_index` (its corner: `% LINE_VERTICES`) of original line
// `line` of the draw's order: the needle itself, or with
// `original_from_needles` off, the original-line order's `line`-th.
fn original_line_vertex(frame: LineFrame, line: u32, vertex_index: u32) -> VertexOutput {
    var k = line;
    if !frame.original_from_needles {
        k = line_orders[line];
    }
    let w = needles[k].w;
    let own = w & 0xffffu;
    if !(own <= frame.code && frame.code < (w >> 16u)) {
        return culled();
    }
    let width = log_decode(own);
    let scale = line_calibration(frame.lod, frame.spatial_error);
    let alpha = min(line_alpha(frame.lod, frame.spatial_error, width, width) * scale, 1.0) * frame.lod.transition;
    let base = needle_base(frame.grid, k);
    let tip = needle_tip(frame.grid, k);
    let at_end = line_vertex_at_end(vertex_index);
    let position = select(base, tip, at_end);
    var out = finish(position, tip - base, frame.world_from_local, line_color(base_color(0, 0.0, alpha, frame.needle_albedo), k, frame.hash_tree));
    out.alignment = 1.0;
    out = with_line_width(out, line_pixels(frame.lod, frame.spatial_error, width) * scale);
    return with_line_quad(swayed_line(out, base, tip, frame.world_from_local, at_end), base, tip, frame.world_from_local, vertex_index);
}

// Vertex `vertex_index` (its corner: `% LINE_VERTICES`) of merged line
// `index` of the draw's order: the merged line itself, or with
// `merged_by_own`, the order by own code's `index`-th.
fn merged_line_vertex(frame: LineFrame, index: u32, vertex_index: u32) -> VertexOutput {
    var line = index;
    if frame.merged_by_own {
        line = line_orders[index];
    }
    let a = merged_lines[3u * line];
    let b = merged_lines[3u * line + 1u];
    let codes = merged_lines[3u * line + 2u];
    let own = codes & 0xffffu;
    // Seen from a view point, a tree's level-2 line takes its own sphere's
    // code and its parent's sphere's (CPU reference:
    // `model::compact::CompactSpecies::placed_drawn`).
    var line_code = frame.code;
    var parent_view_code = frame.code;
    var line_error = frame.spatial_error;
#ifndef CONIFER_PLACED
    if frame.lod.view.w > 0.0 && species.placement_count > 0u {
        line_error = sphere_error(frame.lod, tree_spheres[line], species.wind_motion.y);
        line_code = threshold_code(line_error);
        let parent = tree_line_parents[line];
        parent_view_code = 0u;
        if parent != NO_SPHERE {
            parent_view_code = threshold_code(sphere_error(frame.lod, tree_spheres[parent], species.wind_motion.y));
        }
    }
#endif
    if !(own <= line_code && parent_view_code < (codes >> 16u)) {
        return culled();
    }
    // The width code's top 12 bits (`model::compact::CompactSpecies::merged_width_code`).
    let width = log_decode(((a >> 24u) | (((b >> 24u) & 0xfu) << 8u)) << 4u);
    let scale = line_calibration(frame.lod, line_error);
    let alpha = min(merged_line_alpha(frame.lod, line_error, width, log_decode(own)) * scale, 1.0);
    // Wider than a pixel its strip keeps its area, under the
    // area-preserving rule (the coverage rule's opacity saturates instead).
    let merged_pixels = select(0.0, line_pixels(frame.lod, line_error, width) * scale, ((frame.lod.code >> LOD_OPACITY_SHIFT) & 3u) == 1u);
    let span = f32(max(species.merged_code_max, species.merged_code_min + 1u) - species.merged_code_min);
    let amount = clamp(f32(own - min(own, species.merged_code_min)) / span, 0.0, 1.0);
    let start = end_position(frame.grid, a);
    let end = end_position(frame.grid, b);
    let at_end = line_vertex_at_end(vertex_index);
    let position = select(start, end, at_end);
    var out = finish(position, end - start, frame.world_from_local, line_color(base_color(1, amount, alpha, frame.needle_albedo), species.total_needle_count + line, frame.hash_tree));
    // `model::compact::CompactSpecies::merged_alignment`.
    out.alignment = f32(b >> 28u) / ALIGNMENT_STEPS;
    out = with_line_width(out, merged_pixels);
    return with_line_quad(swayed_line(out, start, end, frame.world_from_local, at_end), start, end, frame.world_from_local, vertex_index);
}

// Draws of the tree's own parts have one instance, the tree; placed draws
// one instance per expanded placement, whose entry names its tree,
// placement and threshold code. Either way the vertex works in the frame
// of what it draws (the tree, or the prototype), at that frame's error.
@vertex
fn vertex(@builtin(vertex_index) vertex_index: u32, @builtin(instance_index) instance_index: u32) -> VertexOutput {
#ifdef CONIFER_PLACED
    let entry = placed_entries[instance_index];
    let tree = entry.x & ENTRY_TREE_MASK;
    wind_tree = instance_world_from_local(instances[tree]);
    vertex_tree = tree;
    let placement = placements[entry.y & ENTRY_PLACEMENT_MASK];
    let lod = instance_lods[tree];
    let code = entry.y >> 16u;
    let original_from_needles = (entry.x & ENTRY_FROM_NEEDLES) != 0u;
    let merged_by_own = (entry.x & ENTRY_MERGED_BY_OWN) != 0u;
    let spatial_error = placement_error(lod, placement, prototypes[placement.prototype].sphere, species.wind_motion.y)
        / placement.translation_scale.w;
    let world_from_local = wind_tree * placement_matrix(placement);
    let grid = prototypes[placement.prototype].grid;
    // Shadow hash: the same per placement every frame.
    let hash_tree = tree ^ ((entry.y & ENTRY_PLACEMENT_MASK) << 9u);
    let needle_albedo = placed_needle_albedo(placement, prototypes[placement.prototype], world_from_local);
#else
    let tree = instance_index;
    wind_tree = instance_world_from_local(instances[tree]);
    vertex_tree = tree;
    let lod = instance_lods[tree];
    let code = lod.code & LOD_CODE_MASK;
    let original_from_needles = (lod.code & LOD_ORIGINAL_FROM_NEEDLES) != 0u;
    let merged_by_own = false;
    let spatial_error = lod.spatial_error;
    let world_from_local = wind_tree;
    let grid = species.grid;
    let hash_tree = tree;
    let needle_albedo = species.far_needle_color.rgb;
#endif

#ifdef CONIFER_PRISMS
    let k = vertex_index / species.prism_vertices;
    let radius = 0.5 * log_decode(needles[k].w & 0xffffu);
    let sides = prism_sides(radius, spatial_error);
    let corner = prism_corner(vertex_index % species.prism_vertices);
    let base = needle_base(grid, k);
    let tip = needle_tip(grid, k);
    let toward = toward_view_local(world_from_local, 0.5 * (base + tip));
    let p = prism_vertex(base, tip, radius, radius, sides, corner, toward);
    let m = max(species.max_sides, 3u);
    let amount = f32(m - sides) / max(f32(m - 3u), 1.0);
    let out = finish(p.position, p.normal, world_from_local, base_color(-1, amount, 1.0, needle_albedo));
    return swayed_prism(with_prism_side(out, base, tip, toward, world_from_local), base, tip, world_from_local);
#endif

#ifdef CONIFER_WOOD_PRISMS
    // In wind a segment is drawn in sections, each a prism straight
    // between its ends as the field moves them (CPU reference:
    // `model::wind::wood_bend_gap`); their joints' rings coincide.
    let sections = wood_sections(species.wind.z);
    let slot = vertex_index / species.prism_vertices;
    let s = slot / sections;
    let ends = decode_wood_segment(wood_segments[s], species.wood_grid);
    let start = ends.start;
    let end = ends.end;
    let wood_error = wood_segment_error(lod, start, end, spatial_error);
    if lod.view.w > 0.0 && !(wood_error < 2.0 * max(start.w, end.w)) {
        return culled();
    }
    let sides = prism_sides(max(start.w, end.w), wood_error);
    let corner = prism_corner(vertex_index % species.prism_vertices);
    let toward = toward_view_local(world_from_local, 0.5 * (start.xyz + end.xyz));
    let section = f32(slot % sections);
    let a = mix(start, end, section / f32(sections));
    let b = mix(start, end, (section + 1.0) / f32(sections));
    let p = prism_vertex(a.xyz, b.xyz, a.w, b.w, sides, corner, toward);
    let m = max(species.max_sides, 3u);
    // The fragment takes the bark's colour at its own height (CONIFER_BARK).
    var color = base_color(2, 0.0, 1.0, species.wood_color.rgb);
    if species.debug_colors != 0u {
        color = base_color(-1, f32(m - sides) / max(f32(m - 3u), 1.0), 1.0, color.rgb);
    }
    let out = with_prism_side(finish(p.position, p.normal, world_from_local, color), a.xyz, b.xyz, toward, world_from_local);
    return with_height(swayed_prism(out, a.xyz, b.xyz, world_from_local), p.position.y);
#endif

#ifdef CONIFER_ORIGINAL_LINES
    let frame = LineFrame(lod, code, spatial_error, world_from_local, grid, needle_albedo, hash_tree, original_from_needles, merged_by_own);
#ifdef CONIFER_LINES_BY_ENTRY
    // An expanded placement's merged lines, then its original lines, in
    // one draw (`ordered_splits`).
    let split = ordered_splits[instance_index];
    let line = vertex_index / LINE_VERTICES;
    if line < split.x {
        return merged_line_vertex(frame, line, vertex_index);
    }
    return original_line_vertex(frame, line - split.x + split.y, vertex_index);
#else
    return original_line_vertex(frame, vertex_index / LINE_VERTICES, vertex_index);
#endif
#endif

#ifdef CONIFER_MERGED_LINES
    let frame = LineFrame(lod, code, spatial_error, world_from_local, grid, needle_albedo, hash_tree, original_from_needles, merged_by_own);
    return merged_line_vertex(frame, vertex_index / LINE_VERTICES, vertex_index);
#endif

#ifdef CONIFER_WOOD_LINES
    // In wind a segment is drawn in sections, as its prism is.
    let sections = wood_sections(species.wind.z);
    let slot = vertex_index / LINE_VERTICES;
    let s = slot / sections;
    let segment = wood_segments[s];
    let ends = decode_wood_segment(segment, species.wood_grid);
    let start = ends.start;
    let end = ends.end;
    let width = start.w + end.w;
    let wood_error = wood_segment_error(lod, start, end, spatial_error);
    let line_from = 2.0 * max(start.w, end.w);
    if lod.view.w > 0.0 && (wood_error < line_from || !(wood_error < species.wood_line_fade * line_from)) {
        return culled();
    }
    // Scaled as the calibration measured, by the line's size and opacity:
    // a twig's line blends with the needle lines around it as if they fell
    // independently, where the twig lies inside its own needles. Wood
    // wider than a pixel (a line at a pixel error over 1) goes to its own
    // width by two pixels: it stands in front of or behind the needles,
    // not among them.
    let unscaled = line_alpha(lod, wood_error, width, width);
    let pixels = line_pixels(lod, wood_error, width);
    let scale = mix(wood_line_calibration(lod, wood_error, unscaled), 1.0, clamp(pixels - 1.0, 0.0, 1.0));
    var alpha = min(max(unscaled, pixels) * scale, 1.0);
    // Sections at least two pixels long: a line shorter than a pixel may
    // light none (CPU reference: `model::wind::wood_line_sections`); the
    // segment's slots past them are not drawn.
    let metres_per_pixel = wood_error / max(lod.pixel_error, 1e-6);
    let fit = distance(start.xyz, end.xyz) / (WOOD_LINE_SECTION_PIXELS * metres_per_pixel);
    var drawn = 1u;
    if fit >= 1.0 && fit < 1e9 {
        drawn = min(u32(fit), sections);
    }
    let section = slot % sections;
    if section >= drawn {
        return culled();
    }
    // A section runs on into the next one, and the segment's ends into
    // its branch's next segments where those continue it.
    let joined_start = section > 0u || (segment.w & WOOD_JOINED_START) != 0u;
    let joined_end = section + 1u < drawn || (segment.w & WOOD_JOINED_END) != 0u;
    let a = mix(start.xyz, end.xyz, f32(section) / f32(drawn));
    let b = mix(start.xyz, end.xyz, f32(section + 1u) / f32(drawn));
#ifdef CONIFER_WOOD_LAYERS
    // A camera draws the wood lines twice, under the foliage lines and
    // over them: at `a·(1 − g)/(1 − a·g)` and `a·g`, `g` the share of the
    // wood the needles leave in sight where they cover the pixel
    // (`model::impostor::WoodVisibility`), so that the wood takes `a·(g +
    // (1 − g)·t)` of a pixel the needle lines let `t` through and what lies
    // behind it `t·(1 − a)` (CPU reference:
    // `model::impostor::wood_layer_opacities`).
    let middle = 0.5 * (a + b);
    let camera = tree_local_point(world_from_local, length(world_from_local[0].xyz), view.world_position);
    var toward = camera.xz - species.impostor_box.xy;
    var in_sight = 0.0;
    if dot(toward, toward) > 1e-12 {
        toward = normalize(toward);
        in_sight = wood_visibility_at(middle.y, dot(middle.xz - species.impostor_box.xy, toward) + max(start.w, end.w));
    }
    // A line wider than a pixel has each pixel's coverage split in the
    // fragment (`pixel_line_coverage`): it covers a pixel at its edge in
    // part at full opacity. A thinner one (a strip as wide as its opacity)
    // and a hardware line have their opacity split here.
    var split_in_fragment = false;
#ifdef CONIFER_LINE_QUADS
    split_in_fragment = pixels * scale > 1.0;
#endif
    if !split_in_fragment {
        alpha = wood_layer_opacity(alpha, in_sight);
    }
#endif
    let at_end = line_vertex_at_end(vertex_index);
    let position = select(a, b, at_end);
    // The fragment takes the bark's colour at its own height (CONIFER_BARK).
    let color = line_color(base_color(2, 0.0, alpha, species.wood_color.rgb), 0xffffffu - s, hash_tree);
    var out = finish(position, b - a, world_from_local, color);
    out.alignment = 1.0;
    out = with_line_width(out, pixels * scale);
    out = with_line_joints(out, joined_start, joined_end);
#ifdef CONIFER_WOOD_LAYERS
#ifdef CONIFER_LINE_QUADS
    out.wood_in_sight = in_sight;
#endif
#endif
    return with_height(with_line_quad(swayed_line(out, a, b, world_from_local, at_end), a, b, world_from_local, vertex_index), position.y);
#endif

#ifdef CONIFER_IMPOSTOR
    // One quad standing on the impostor's axis, turned about it toward the
    // camera; its pictures are the two views nearest the camera's azimuth,
    // blended (`model::impostor`).
    wind_trunk_only = true;
    let fade = impostor_fade(lod);
    if !(fade > 0.0) {
        return culled();
    }
    let frame = species.impostor_box;
    let span = species.impostor_span;
    // An orthographic view (a directional light's cascade) looks along
    // one direction: the quad turns toward where the view looks from.
    var eye = view.world_position;
    if view.clip_from_view[3][3] == 1.0 {
        eye = world_from_local[3].xyz + 1.0e4 * normalize(view.world_from_view[2].xyz);
    }
    let camera = tree_local_point(world_from_local, length(world_from_local[0].xyz), eye);
    var toward = vec2<f32>(camera.x - frame.x, camera.z - frame.y);
    if dot(toward, toward) < 1e-12 {
        toward = vec2<f32>(0.0, 1.0);
    }
    // The camera stands at azimuth φ: (sin φ, cos φ) in (x, z).
    let phi = atan2(toward.x, toward.y);
    let right = vec3<f32>(cos(phi), 0.0, -sin(phi));
    // Two triangles: corners (0,0) (1,0) (1,1), (0,0) (1,1) (0,1).
    let corner = vertex_index % 6u;
    let u = select(0.0, 1.0, corner == 1u || corner == 2u || corner == 4u);
    let v = select(0.0, 1.0, corner == 2u || corner == 4u || corner == 5u);
    // The card stands on the axis about the crown's middle.
    let centre = 0.5 * (span.x + span.y);
    var up = vec3<f32>(0.0, 1.0, 0.0);
#ifdef CONIFER_SHADOW
    // Cast for a shadow view: seen from a light at elevation `el`, a crown
    // H tall and D wide spans H·cos(el) + D·sin(el) across the light, an
    // upright card only H·cos(el). The card leans away from the light
    // about the crown's middle by `t`, until H·cos(el − t) spans as much,
    // so its shadow is as long as the crown's and falls where it does
    // (CPU reference: `model::impostor::shadow_card_lean`).
    let height = max(span.y - span.x, 1e-6);
    let elevation = atan2(abs(camera.y - centre), max(length(toward), 1e-9));
    let across = min(cos(elevation) + 2.0 * frame.z / height * sin(elevation), 1.0);
    let lean = sign(camera.y - centre) * max(elevation - acos(across), 0.0);
    let to_light = vec3<f32>(sin(phi), 0.0, cos(phi));
    up = cos(lean) * up - sin(lean) * to_light;
#endif
    // In wind the card is wider and taller on every side: its fragments
    // move the picture by what the field moves it by and the lean did not
    // (`impostor_swayed_uv`), past the calm crown's edge.
    let margin = impostor_sway_margin();
    let across_card = (2.0 * u - 1.0) * (frame.z + margin);
    let along_card = mix(span.x - margin, span.y + margin, v);
    let position = vec3<f32>(frame.x, centre, frame.y) + (along_card - centre) * up + right * across_card;
    let views = max(span.z, 1.0);
    let f = fract(phi / TAU + 1.0) * views;
    let k0 = floor(f) % views;
    let k1 = (k0 + 1.0) % views;
    var out = finish(position, vec3<f32>(0.0, 1.0, 0.0), world_from_local, vec4<f32>(k0, k1, f - floor(f), fade));
    out.uv = vec2<f32>(0.5 * (across_card / frame.z + 1.0), (span.y - along_card) / max(span.y - span.x, 1e-6));
    out.card_point = position;
    out.card_right = right;
    out.card_up = up;
    return out;
#endif

#ifdef CONIFER_WOOD_MESH
    let vertex = wood_mesh[vertex_index];
    let w0 = wood_mesh[species.wood_index_count + 3u * vertex];
    let w1 = wood_mesh[species.wood_index_count + 3u * vertex + 1u];
    let w2 = wood_mesh[species.wood_index_count + 3u * vertex + 2u];
    let position = grid_point(species.wood_grid, w0 & 0xffffu, w0 >> 16u, w1 & 0xffffu);
    // Octahedral normal, 16 bits a coordinate (`model::file::decode_normal`).
    let x = f32(w2 & 0xffffu) / 65535.0 * 2.0 - 1.0;
    let y = f32(w2 >> 16u) / 65535.0 * 2.0 - 1.0;
    let z = 1.0 - abs(x) - abs(y);
    let t = max(-z, 0.0);
    let normal = vec3<f32>(x + select(t, -t, x >= 0.0), y + select(t, -t, y >= 0.0), z);
    // The fragment takes the bark's colour at its own height (CONIFER_BARK).
    let color = base_color(2, 0.0, 1.0, species.wood_color.rgb);
    var out = finish(position, normalize(normal), world_from_local, color);
#ifndef CONIFER_SHADOW
    let calm_world = (world_from_local * vec4<f32>(position, 1.0)).xyz;
    out.world_normal = swayed_surface_normal(calm_world, out.world_normal);
#endif
    return with_height(out, position.y);
#endif
}

#ifdef CONIFER_IMPOSTOR
// How far past the calm crown the impostor's picture can move on its
// leaning quad, tree metres: the largest sway of a branch and flutter of a
// shoot, and a quarter of the trunk's largest bend (how far a parabola
// strays from its chord). CPU reference: `model::wind::impostor_margin`.
fn impostor_sway_margin() -> f32 {
    let strength = species.wind.z;
    if !(strength > 0.0) {
        return 0.0;
    }
    let force = strength * (1.0 + species.wind.w);
    // MAX_REACH_RATIO^1.5 and the √1.25 of a sine and half a sine summed.
    let most = 1.8371173 * 1.1180340;
    let branch = force * WIND_BRANCH_SWAY * species.wind_clock.w * most;
    let flutter = force * species.wind_motion.x * WIND_FLUTTER * WIND_MAX_REACH_RATIO * 1.1180340;
    let trunk = force * species.wind_shape.w * (WIND_TRUNK_LEAN + WIND_TRUNK_SWAY);
    return (branch + flutter + 0.25 * trunk) * 1.001;
}

// Where on the impostor's pictures this fragment reads: its calm card
// point moved back by what the field moves it by there and the quad's
// lean did not (the quad's corners lean with the trunk, straight between
// them where the trunk bends), across the card and up (along the view a
// shift moves nothing), so the crown's picture sways as its needles do
// (CPU reference: `model::impostor::swayed_card_point`). `world` is where
// the leaning quad put the fragment.
fn impostor_swayed_uv(uv: vec2<f32>, tree: u32, card_point: vec3<f32>, right: vec3<f32>, up: vec3<f32>, world: vec3<f32>) -> vec2<f32> {
    if !(species.wind.z > 0.0) {
        return uv;
    }
    let world_from_local = instance_world_from_local(instances[tree]);
    wind_tree = world_from_local;
    let calm = (world_from_local * vec4<f32>(card_point, 1.0)).xyz;
    let moved = wind_displacement(calm) - (world - calm);
    // Back to tree metres in the tree's frame (its columns are the
    // rotation times the scale).
    let scale2 = max(dot(world_from_local[0].xyz, world_from_local[0].xyz), 1e-12);
    let local = vec3<f32>(
        dot(world_from_local[0].xyz, moved),
        dot(world_from_local[1].xyz, moved),
        dot(world_from_local[2].xyz, moved),
    ) / scale2;
    let frame = species.impostor_box;
    let span = species.impostor_span;
    return uv - vec2<f32>(
        0.5 * dot(local, right) / max(frame.z, 1e-6),
        -dot(local, up) / max(span.y - span.x, 1e-6),
    );
}

// `model::impostor::MAX_FOOTPRINT_TAPS`.
const MAX_FOOTPRINT_TAPS: f32 = 4.0;

// View `layer` of the impostor over the pixel's footprint `uv ± du/2 ±
// dv/2`: cut into taps × taps cells (one a level-0 texel, at most
// MAX_FOOTPRINT_TAPS a side), each read at its centre from the mip level
// of its own size, averaged: a box filter of the pixel, where one
// trilinear sample blurs the crown's gaps over two pixels (CPU reference:
// `model::impostor::ImpostorMips::footprint`).
fn impostor_footprint(uv: vec2<f32>, du: vec2<f32>, dv: vec2<f32>, layer: i32) -> vec4<f32> {
    let size = vec2<f32>(textureDimensions(impostor_texture));
    let texels = max(length(du * size), length(dv * size));
    var taps = 1.0;
    if texels == texels && texels < 1e30 {
        taps = clamp(ceil(texels), 1.0, MAX_FOOTPRINT_TAPS);
    }
    let tap_du = du / taps;
    let tap_dv = dv / taps;
    var sum = vec4<f32>(0.0);
    let n = u32(taps);
    for (var a = 0u; a < n; a++) {
        for (var b = 0u; b < n; b++) {
            let at = uv + du * ((f32(a) + 0.5) / taps - 0.5) + dv * ((f32(b) + 0.5) / taps - 0.5);
            // A tap off the pictures sees nothing (the sampler would
            // repeat their edge over the wind's margin).
            if all(at >= vec2<f32>(0.0)) && all(at <= vec2<f32>(1.0)) {
                sum += textureSampleGrad(impostor_texture, impostor_sampler, at, layer, tap_du, tap_dv);
            }
        }
    }
    return sum / (taps * taps);
}

// The impostor's texel under this fragment: its two views nearest the
// camera's azimuth (layers `color.x` and `color.y`), each over the pixel's
// footprint, blended by `color.z`.
fn impostor_texel(uv: vec2<f32>, color: vec4<f32>) -> vec4<f32> {
    let du = dpdx(uv);
    let dv = dpdy(uv);
    let first = impostor_footprint(uv, du, dv, i32(round(color.x)));
    let second = impostor_footprint(uv, du, dv, i32(round(color.y)));
    return mix(first, second, color.z);
}
#endif

#ifdef CONIFER_LINE_QUADS
// Length of the segment `a`–`b` inside the unit square at `pixel`
// (Liang–Barsky; CPU reference: `model::raster::segment_length_in_pixel`).
fn segment_length_in_pixel(a: vec2<f32>, b: vec2<f32>, pixel: vec2<f32>) -> f32 {
    let d = b - a;
    let lo = pixel - a;
    let hi = pixel + vec2<f32>(1.0) - a;
    var t0 = 0.0;
    var t1 = 1.0;
    for (var axis = 0u; axis < 2u; axis += 1u) {
        if abs(d[axis]) < 1e-12 {
            if lo[axis] > 0.0 || hi[axis] < 0.0 {
                return 0.0;
            }
        } else {
            let ta = lo[axis] / d[axis];
            let tb = hi[axis] / d[axis];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    return max(t1 - t0, 0.0) * length(d);
}

// The exact area inside the unit square at `pixel` of the rectangle of
// `width` pixels on the segment `a`–`b`: clipped to the square's sides,
// measured by the shoelace formula (CPU reference:
// `model::raster::strip_area_in_pixel`).
fn strip_area_in_pixel(a: vec2<f32>, b: vec2<f32>, width: f32, pixel: vec2<f32>) -> f32 {
    let d = b - a;
    let n = vec2<f32>(-d.y, d.x) * (0.5 * width / length(d));
    var polygon = array<vec2<f32>, 8>(a + n, b + n, b - n, a - n, vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0));
    var count = 4u;
    for (var side = 0u; side < 4u; side += 1u) {
        let axis = side / 2u;
        let sign = select(-1.0, 1.0, (side & 1u) == 1u);
        let bound = pixel[axis] + f32(side & 1u);
        var clipped: array<vec2<f32>, 8>;
        var kept = 0u;
        for (var i = 0u; i < count; i += 1u) {
            let p = polygon[i];
            let q = polygon[(i + 1u) % count];
            let dp = sign * (p[axis] - bound);
            let dq = sign * (q[axis] - bound);
            if dp <= 0.0 && kept < 8u {
                clipped[kept] = p;
                kept += 1u;
            }
            if ((dp < 0.0 && dq > 0.0) || (dp > 0.0 && dq < 0.0)) && kept < 8u {
                clipped[kept] = mix(p, q, dp / (dp - dq));
                kept += 1u;
            }
        }
        polygon = clipped;
        count = kept;
        if count < 3u {
            return 0.0;
        }
    }
    var twice = 0.0;
    for (var i = 0u; i < count; i += 1u) {
        let p = polygon[i];
        let q = polygon[(i + 1u) % count];
        twice += p.x * q.y - q.x * p.y;
    }
    return min(0.5 * abs(twice), 1.0);
}

// The pixel at `frag` covered by the line of `opacity` between `ends`
// (pixels) standing for something `line_width` pixels wide: thinner than a
// pixel, the area in the pixel's square of a strip as wide as the
// opacity, each quarter pixel of width at its two Gauss–Legendre nodes
// (CPU reference: `model::raster::strip_pixel_coverage`); wider, the
// opacity times the exact area of a strip that wide, and where an end is
// joined (`joints`, bit 0 the start, bit 1 the end) only for pixels whose
// centres lie on this side of it, by the strip extended `JOINT_REACH`
// past it (`model::raster::joined_line_pixel_coverage`).
fn line_coverage(frag: vec2<f32>, ends: vec4<f32>, opacity: f32, line_width: f32, joints: u32) -> f32 {
    let a = ends.xy;
    let b = ends.zw;
    let d = b - a;
    let span = sqrt(dot(d, d));
    if !(span > 1e-6) {
        return 0.0;
    }
    let pixel = floor(frag);
    if line_width > 1.0 {
        let along = dot(pixel + vec2<f32>(0.5) - a, d) / (span * span);
        let joined_start = (joints & 1u) != 0u;
        let joined_end = (joints & 2u) != 0u;
        if (joined_start && along < 0.0) || (joined_end && along >= 1.0) {
            return 0.0;
        }
        let reach = JOINT_REACH / span;
        let strip_start = select(a, a - reach * d, joined_start);
        let strip_end = select(b, b + reach * d, joined_end);
        return min(clamp(opacity, 0.0, 1.0) * strip_area_in_pixel(strip_start, strip_end, strip_of(opacity, line_width), pixel), 1.0);
    }
    let normal = vec2<f32>(-d.y, d.x) / span;
    let width = clamp(opacity, 0.0, 1.0);
    let pieces = max(u32(ceil(width * 4.0)), 1u);
    let piece = width / f32(pieces);
    let node = piece * 0.28867513;
    var sum = 0.0;
    for (var k = 0u; k < pieces; k += 1u) {
        let middle = -0.5 * width + (f32(k) + 0.5) * piece;
        let low = normal * (middle - node);
        let high = normal * (middle + node);
        sum += segment_length_in_pixel(a + low, b + low, pixel) + segment_length_in_pixel(a + high, b + high, pixel);
    }
    return min(opacity * sum / f32(2u * pieces), 1.0);
}

// The coverage the line of fragment `in` gives its pixel: its strip's
// area there (`line_coverage`); a layered wood line wider than a pixel
// takes its layer's share of it, `c·(1 − g)/(1 − c·g)` under the foliage
// lines and `c·g` over them (`g` the wood's share in sight; CPU
// reference: `model::impostor::wood_layer_opacities`), so that with
// nothing between the layers its pixel takes `c` (split by its opacity
// of 1, a pixel it half covers would take `½ + ½·g·½`). A thinner line's
// opacity was split by the vertex stage.
fn pixel_line_coverage(in: VertexOutput) -> f32 {
    let coverage = line_coverage(in.position.xy, in.line_ends, in.color.a, in.line_width, in.line_joints);
#ifdef CONIFER_WOOD_LAYERS
    if !(in.line_width > 1.0) {
        return coverage;
    }
    return wood_layer_opacity(coverage, clamp(in.wood_in_sight, 0.0, 1.0));
#else
    return coverage;
#endif
}
#endif

#ifdef CONIFER_MOTION_VECTORS

// Motion vectors (Bevy's prepass convention: this frame's unjittered
// clip position minus the previous frame's, in UV units). Prisms and wood
// replace the pixel's vector; a line covering at least
// `MOTION_MIN_OPACITY` of the pixel blends its own over it by its opacity
// (the pipeline's alpha blending). CPU reference:
// `model::wind::motion_vector`.
struct MotionOutput {
#ifdef CONIFER_NORMALS
    // Bevy's normal prepass encoding (written by prisms and wood only: a
    // line's target takes no writes).
    @location(0) normal: vec4<f32>,
#endif
    @location(1) motion_vector: vec4<f32>,
#ifdef CONIFER_CROSSFADE_SAMPLES
    // The samples the fragment goes to (`crossfade_samples`).
    @builtin(sample_mask) samples: u32,
#endif
}

@fragment
fn fragment(in: VertexOutput, @builtin(front_facing) is_front: bool) -> MotionOutput {
    let fade_samples = crossfade_samples(in.position.xy, in.tree);
    if fade_samples == 0u {
        discard;
    }
#ifdef CONIFER_LINE_QUADS
    let opacity = pixel_line_coverage(in);
#else
    let opacity = in.color.a;
#endif
#ifdef CONIFER_LINES
    if !(opacity >= MOTION_MIN_OPACITY) {
        discard;
    }
#endif
    var out: MotionOutput;
    let now = view.unjittered_clip_from_world * vec4<f32>(in.world_position.xyz, 1.0);
    let before = previous_view_uniforms.clip_from_world * vec4<f32>(in.previous_world_position.xyz, 1.0);
    let motion = (now.xy / now.w - before.xy / before.w) * vec2<f32>(0.5, -0.5);
    out.motion_vector = vec4<f32>(motion, 0.0, saturate(opacity));
#ifdef CONIFER_CROSSFADE_SAMPLES
    out.samples = fade_samples;
#endif
#ifdef CONIFER_NORMALS
    let normal = normalize(select(-in.world_normal, in.world_normal, is_front));
    out.normal = vec4<f32>(normal * 0.5 + vec3<f32>(0.5), 1.0);
#endif
    return out;
}

#else ifdef CONIFER_SHADOW

// Shadows of translucent lines: each fragment is kept with the line's
// opacity (drawn as a quad, each texel of its strip), by a hash of
// its texel, line and tree, so a line casts the shadow of the coverage it
// draws (`model::compact::shadow_texel_kept`).
// A tree past a shadow view's budget casts its crown impostor, each
// fragment kept with the coverage of the impostor's texels under it.
@fragment
fn fragment(in: VertexOutput) {
#ifdef CONIFER_IMPOSTOR
    let uv = impostor_swayed_uv(in.uv, in.tree, in.card_point, in.card_right, in.card_up, in.world_position.xyz);
    let coverage = impostor_texel(uv, in.color).r * in.color.w;
    let line = IMPOSTOR_SHADOW_LINE;
    let tree = in.tree;
#else
    // Drawn as a quad (`ConiferLodSettings::shadow_line_quads`), the line
    // covers its strip (`with_line_quad`): each texel in it is kept with
    // the opacity too.
    let coverage = in.color.a;
    let line = u32(in.color.r + 0.5);
    let tree = u32(in.color.g + 0.5);
#endif
    let texel = vec2<u32>(in.position.xy);
    let h = pcg(texel.x ^ pcg(texel.y ^ pcg(line ^ pcg(tree))));
    if !(f32(h >> 8u) * (1.0 / 16777216.0) < coverage) {
        discard;
    }
}
#else
#ifdef CONIFER_LINES
#ifndef CONIFER_FACING_STRIP
// Four-point Gauss–Legendre rule on [−1, 1]: offsets across a cylinder's
// projected width and their weights (they sum to 2).
fn across_offset(k: u32) -> f32 {
    let node = select(0.33998104358, 0.86113631159, (k & 1u) != 0u);
    return select(-node, node, k >= 2u);
}

fn across_weight(k: u32) -> f32 {
    return select(0.65214515486, 0.34785484514, (k & 1u) != 0u);
}

// What a pixel of lines or of the impostor sees: a cylinder's visible half
// (four normals across its projected width, `toward` facing the viewer
// turning to `side`) or a sphere's projected disk (facing the viewer
// `toward`, lit by its table, `sphere_light`).
struct Surface {
    toward: vec3<f32>,
    side: vec3<f32>,
    is_sphere: bool,
    // A cylinder's band `[s0, s1]` of its projected width the pixel sees
    // (the impostor's trunk, `trunk_band`); the whole width where
    // `s1 ≤ s0` (a zeroed surface's).
    band: vec2<f32>,
}

// The surfaces a pixel sees at once, each with its share of the pixel's
// colour (an impostor texel's needles: a vertical cylinder, one across the
// view and a sphere; a merged line's: its chord's cylinder and a sphere,
// whose share may be negative; anything else one surface), lit in one pass
// over the lights (`mixed_lighting`): each light's shadow and view light
// scale, the clustered lights' lookup and the ambient light are taken once
// for all of them. A share of 0 skips its surface.
struct SurfaceMix {
    first: Surface,
    second: Surface,
    third: Surface,
    shares: vec3<f32>,
    // The impostor's needles: each light's direct term scaled by the
    // species' view light scale (`view_light_scale`).
    light_scaled: bool,
}

// `surface` alone, unscaled.
fn single_surface(surface: Surface) -> SurfaceMix {
    var surfaces: SurfaceMix;
    surfaces.first = surface;
    surfaces.second = surface;
    surfaces.third = surface;
    surfaces.shares = vec3<f32>(1.0, 0.0, 0.0);
    surfaces.light_scaled = false;
    return surfaces;
}

// The part `[s0, s1]` of a cylinder's projected width whose normals face
// the light `to_light` (n(s)·L ≥ 0); empty for a light along the axis
// (CPU reference: `model::shading::lit_across`).
fn lit_across(surface: Surface, to_light: vec3<f32>) -> vec2<f32> {
    let a = dot(surface.toward, to_light);
    let b = dot(surface.side, to_light);
    let r = length(vec2<f32>(a, b));
    if r < 1e-6 {
        return vec2<f32>(0.0);
    }
    if b >= 0.0 {
        return vec2<f32>(-a / r, 1.0);
    }
    return vec2<f32>(-1.0, a / r);
}

// Normal `k` of a cylinder lit by `to_light` and its weight (weights that
// sum to the lit share of the width): the four nodes over the part of its
// width the light reaches. Over the whole width, a light from behind
// lights only a band at one edge, which the nodes missed (under half the
// light a cylinder's bright rim shows from behind).
// On a band of the width (`Surface::band`) the nodes span the part of it
// the light reaches and the weights sum to that part's share of the band
// (CPU reference: `model::shading::band_average`).
fn cylinder_normal(surface: Surface, k: u32, to_light: vec3<f32>) -> vec4<f32> {
    var lit = lit_across(surface, to_light);
    var width = 2.0;
    if surface.band.y > surface.band.x {
        lit = vec2<f32>(max(lit.x, surface.band.x), min(lit.y, surface.band.y));
        width = surface.band.y - surface.band.x;
    }
    let half = 0.5 * max(lit.y - lit.x, 0.0);
    let s = 0.5 * (lit.x + lit.y) + half * across_offset(k);
    return vec4<f32>(sqrt(max(1.0 - s * s, 0.0)) * surface.toward + s * surface.side, half * across_weight(k) / width);
}

// View cosine `k` (n·V) at which a cylinder's (or a sphere's) indirect
// light is taken, and its weight: the four-point Gauss–Legendre rule in
// the normal's angle φ ∈ [0, π/2] from the viewer, weighted by cos φ (a
// cylinder's projected width, s = sin φ) or by 2 sin φ cos φ (a sphere's
// disk), the weights summing to 1 (CPU reference:
// `model::shading::indirect_nodes`).
fn indirect_node(k: u32, is_sphere: bool) -> vec2<f32> {
    var cosines = array<f32, 4>(0.99405849, 0.86862415, 0.49547160, 0.10884719);
    var cylinder = array<f32, 4>(0.27158132, 0.44490373, 0.25377738, 0.02973755);
    var sphere = array<f32, 4>(0.05912220, 0.44087780, 0.44087780, 0.05912220);
    return vec2<f32>(cosines[k], select(cylinder[k], sphere[k], is_sphere));
}

// A sphere's mean diffuse (per unit diffuse colour) and specular over its
// projected disk, seen from `to_viewer` under a light of unit irradiance
// from `to_light`: the species' table by the angle between them,
// interpolated linearly (CPU reference: `model::shading::SphereLight::at`).
fn sphere_light(to_viewer: vec3<f32>, to_light: vec3<f32>) -> vec2<f32> {
    let x = acos(clamp(dot(to_viewer, to_light), -1.0, 1.0)) * (f32(SPHERE_LIGHT_STEPS - 1u) / PI);
    let k = min(u32(x), SPHERE_LIGHT_STEPS - 2u);
    let j = k + 1u;
    let below = vec2<f32>(species.sphere_diffuse[k / 4u][k % 4u], species.sphere_specular[k / 4u][k % 4u]);
    let above = vec2<f32>(species.sphere_diffuse[j / 4u][j % 4u], species.sphere_specular[j / 4u][j % 4u]);
    return mix(below, above, x - f32(k));
}

const LIGHT_POINT: u32 = 0u;
const LIGHT_SPOT: u32 = 1u;
const LIGHT_DIRECTIONAL: u32 = 2u;

// Bevy's light `light_id` of `kind` on the lighting input.
fn bevy_light(kind: u32, light_id: u32, input: ptr<function, lighting::LightingInput>) -> vec3<f32> {
    if kind == LIGHT_POINT {
        return lighting::point_light(light_id, input, true, true);
    }
    if kind == LIGHT_SPOT {
        return lighting::spot_light(light_id, input, true);
    }
    return lighting::directional_light(light_id, input, true);
}

// The irradiance a light of `kind` brings to `position` from `to_light`
// (its colour, distance falloff, spot cone and light texture): Bevy's own
// light function on a probe whose response is exactly 1/π of it, a white
// Burley diffuse seen and lit along its normal (both scatter terms 1) with
// no specular (F0 0).
fn light_irradiance(kind: u32, light_id: u32, position: vec3<f32>, to_light: vec3<f32>) -> vec3<f32> {
    var probe: lighting::LightingInput;
    probe.layers[lighting::LAYER_BASE].perceptual_roughness = 1.0;
    probe.layers[lighting::LAYER_BASE].roughness = 1.0;
    probe.layers[lighting::LAYER_BASE].N = to_light;
    probe.layers[lighting::LAYER_BASE].NdotV = 1.0;
    probe.layers[lighting::LAYER_BASE].R = to_light;
    probe.P = position;
    probe.V = to_light;
    probe.diffuse_color = vec3<f32>(1.0);
    probe.metallic = 0.0;
    probe.F0_dielectric = vec3<f32>(0.0);
    probe.F0_metallic = vec3<f32>(0.0);
    probe.F_ab = vec2<f32>(1.0, 0.0);
    return PI * bevy_light(kind, light_id, &probe);
}

// The surface's mean radiance under one light: a cylinder's Bevy BRDF at
// its four lit normals, a sphere's table times the light's irradiance.
fn surface_light(
    surface: Surface,
    input: ptr<function, lighting::LightingInput>,
    kind: u32,
    light_id: u32,
    to_light: vec3<f32>,
) -> vec3<f32> {
    if surface.is_sphere {
        let response = sphere_light((*input).V, to_light);
        let irradiance = light_irradiance(kind, light_id, (*input).P, to_light);
        return irradiance * ((*input).diffuse_color * response.x + response.y);
    }
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < 4u; k = k + 1u) {
        let normal = cylinder_normal(surface, k, to_light);
        set_normal(input, normal.xyz);
        sum += normal.w * bevy_light(kind, light_id, input);
    }
    return sum;
}

// Sets the lighting input's normal to unit `n`. `n·V` is kept ≤ 1: a
// normal facing the viewer (the sphere's centre) can round past it, and
// Burley's `pow(1 − n·V, 5)` of a negative base is NaN (a black pixel).
fn set_normal(input: ptr<function, lighting::LightingInput>, n: vec3<f32>) {
    let NdotV = clamp(dot(n, (*input).V), 0.0001, 1.0);
    (*input).layers[lighting::LAYER_BASE].N = n;
    (*input).layers[lighting::LAYER_BASE].NdotV = NdotV;
    (*input).layers[lighting::LAYER_BASE].R = reflect(-(*input).V, n);
    (*input).F_ab = lighting::F_AB((*input).layers[lighting::LAYER_BASE].perceptual_roughness, NdotV);
}

// A line stands for a cylinder (an original line) or a bundle of them along
// its chord (a merged line): its colour is the cylinder's radiance averaged
// over its visible width (CPU reference: `model::shading`), Bevy's BRDF (Burley diffuse, GGX specular) and
// lights evaluated at four normals across the visible half (Gauss–Legendre
// in the projected width, where a uniform measure is the average the pixel
// sees) rather than at one normal facing the viewer, which lights every
// line from the front. Each light's shadow is fetched once, at the axis.
fn cylinder_lighting(in: pbr_types::PbrInput, axis: vec3<f32>) -> vec4<f32> {
    return band_lighting(in, axis, vec2<f32>(0.0));
}

// The band `[s0, s1]` of a cylinder along `axis` the pixel sees (offsets
// across its projected width, `−1` at its left edge; the whole width where
// `s1 ≤ s0`): Bevy's BRDF at four normals over the band's lit part
// (`cylinder_normal`).
fn band_lighting(in: pbr_types::PbrInput, axis: vec3<f32>, band: vec2<f32>) -> vec4<f32> {
    return surface_lighting(in, cylinder_surface(axis, in.V, band));
}

// The cylinder along `axis` (any length; zero: upright) seen from `V`, on
// the band `band` of its width (`Surface::band`).
fn cylinder_surface(axis: vec3<f32>, V: vec3<f32>, band: vec2<f32>) -> Surface {
    var T = axis;
    if dot(T, T) < 1e-24 {
        T = vec3<f32>(0.0, 1.0, 0.0);
    }
    T = normalize(T);
    let toward = facing_axis(T, V);
    var surface: Surface;
    surface.toward = toward;
    surface.side = cross(T, toward);
    surface.is_sphere = false;
    surface.band = band;
    return surface;
}

// The sphere seen from `V`: needles spread every way, lit as the mean of
// Bevy's BRDF over its projected disk, from the species' table
// (`sphere_light`, `model::shading::SphereLight`).
fn sphere_surface(V: vec3<f32>) -> Surface {
    var surface: Surface;
    surface.toward = V;
    surface.is_sphere = true;
    return surface;
}

#ifdef CONIFER_IMPOSTOR
// A texel's needles lit as shares of a vertical cylinder, one across the
// view and, for the rest, a sphere (CPU reference:
// `model::shading::TexelShares::lambert`), each light's direct term scaled
// so that the texels are lit as the needles the views show
// (`view_light_scale`).
fn shares_lighting(in: pbr_types::PbrInput, axis: vec3<f32>, across_axis: vec3<f32>, vertical_share: f32, across_share: f32) -> vec4<f32> {
    let no_band = vec2<f32>(0.0);
    var surfaces: SurfaceMix;
    surfaces.first = cylinder_surface(axis, in.V, no_band);
    surfaces.second = cylinder_surface(across_axis, in.V, no_band);
    surfaces.third = sphere_surface(in.V);
    let shares = vec3<f32>(vertical_share, across_share, 1.0 - vertical_share - across_share);
    surfaces.shares = select(vec3<f32>(0.0), shares, shares > vec3<f32>(1.0 / 512.0));
    surfaces.light_scaled = true;
    return mixed_lighting(in, surfaces);
}

// What the impostor's direct light from `to_light` is scaled by, seen
// from `to_viewer`: the species' table
// (`model::impostor::ViewLightScale`) at the light's direction in the
// frame of the impostor view facing the viewer (toward it level, up,
// right), bilinear in the light's angle from the toward direction and its
// roll from above, a light from the left taken as its mirror (CPU
// reference: `model::impostor::ViewLightScale::at`).
fn view_light_scale(to_light: vec3<f32>, to_viewer: vec3<f32>) -> f32 {
    let level = vec3<f32>(to_viewer.x, 0.0, to_viewer.z);
    let l = normalize(to_light);
    if dot(level, level) < 1e-12 || !(dot(l, l) > 0.5) {
        return 1.0;
    }
    let toward = normalize(level);
    let right = cross(vec3<f32>(0.0, 1.0, 0.0), toward);
    let angle = acos(clamp(dot(l, toward), -1.0, 1.0)) * (f32(VIEW_LIGHT_ANGLES - 1u) / PI);
    let roll = atan2(abs(dot(l, right)), l.y) * (f32(VIEW_LIGHT_ROLLS - 1u) / PI);
    let a = min(u32(angle), VIEW_LIGHT_ANGLES - 2u);
    let r = min(u32(roll), VIEW_LIGHT_ROLLS - 2u);
    let fa = angle - f32(a);
    let fr = roll - f32(r);
    let k = a * VIEW_LIGHT_ROLLS + r;
    let below = mix(view_light_entry(k), view_light_entry(k + 1u), fr);
    let above = mix(view_light_entry(k + VIEW_LIGHT_ROLLS), view_light_entry(k + VIEW_LIGHT_ROLLS + 1u), fr);
    return mix(below, above, fa);
}

fn view_light_entry(k: u32) -> f32 {
    return species.view_light_scale[k / 4u][k % 4u];
}
#endif

// View depth of a world point (directional cascades are chosen by it).
fn view_depth(position: vec4<f32>) -> f32 {
    return dot(vec4<f32>(
        view_bindings::view.view_from_world[0].z,
        view_bindings::view.view_from_world[1].z,
        view_bindings::view.view_from_world[2].z,
        view_bindings::view.view_from_world[3].z
    ), position);
}

#ifdef CONIFER_IMPOSTOR
// `model::impostor::SHADOW_SAMPLES` points on the view ray through the
// crown where an impostor texel takes the shadows it receives from the
// shadow maps (where the crown's rings put its needles), the points where
// it takes the crown's own shade past them (where an even crown puts
// them: the crown's shade is an even medium's), and the directional
// lights' shadows averaged over them (the first IMPOSTOR_CACHED_LIGHTS
// lights; set once a fragment by `impostor_shadow_samples`, read by every
// share's lighting).
const IMPOSTOR_SHADOW_SAMPLES: u32 = 3u;
const IMPOSTOR_CACHED_LIGHTS: u32 = 4u;
var<private> impostor_shadow_points: array<vec4<f32>, 3>;
var<private> impostor_crown_points: array<vec4<f32>, 3>;
var<private> impostor_directional_shadows: array<f32, 4>;

// Places the texel's shadow samples on the view ray `V` through the crown
// from the card point `card` (world; `scale` world metres a tree metre),
// `depths` for the shadow maps and `crown_depths` for the crown's shade,
// and averages the directional lights' shadows over them.
fn impostor_shadow_samples(card: vec3<f32>, V: vec3<f32>, depths: vec3<f32>, crown_depths: vec3<f32>, scale: f32, frag: vec2<f32>) {
    for (var k = 0u; k < IMPOSTOR_SHADOW_SAMPLES; k++) {
        impostor_shadow_points[k] = vec4<f32>(card + V * (depths[k] * scale), 1.0);
        impostor_crown_points[k] = vec4<f32>(card + V * (crown_depths[k] * scale), 1.0);
    }
    for (var i = 0u; i < min(view_bindings::lights.n_directional_lights, IMPOSTOR_CACHED_LIGHTS); i++) {
        var shadow = 1.0;
        if (view_bindings::lights.directional_lights[i].flags & mesh_view_types::DIRECTIONAL_LIGHT_FLAGS_SHADOWS_ENABLED_BIT) != 0u {
            shadow = impostor_directional_shadow(i, V, frag);
        }
        impostor_directional_shadows[i] = shadow;
    }
}

// Directional light `i`'s shadow averaged over the texel's samples: the
// maps' at its map points, the crown's own at its crown points.
fn impostor_directional_shadow(i: u32, toward: vec3<f32>, frag: vec2<f32>) -> f32 {
    var sum = 0.0;
    for (var k = 0u; k < IMPOSTOR_SHADOW_SAMPLES; k++) {
        let p = impostor_shadow_points[k];
        let z = view_depth(p);
        sum += with_crown_shade(i, shadows::fetch_directional_shadow(i, p, toward, z, frag), impostor_crown_points[k].xyz, -z);
    }
    return sum / f32(IMPOSTOR_SHADOW_SAMPLES);
}
#endif

// Directional light `i`'s shadow at `position` (an impostor texel's: the
// mean over its samples through the crown).
fn directional_shadow(i: u32, position: vec4<f32>, toward: vec3<f32>, view_z: f32, frag: vec2<f32>) -> f32 {
#ifdef CONIFER_IMPOSTOR
    if i < IMPOSTOR_CACHED_LIGHTS {
        return impostor_directional_shadows[i];
    }
    return impostor_directional_shadow(i, toward, frag);
#else
    let shadow = shadows::fetch_directional_shadow(i, position, toward, view_z, frag);
    return with_crown_shade(i, shadow, position.xyz, -view_z);
#endif
}

// The tree the fragment belongs to (its index in `instances`), set first
// thing by `fragment`.
var<private> fragment_tree: u32;

// Directional light `i`'s `shadow` (from its shadow maps) at world
// `position`, `depth` metres ahead of the camera, with the tree's own
// crown's shade where the maps end: cross-faded into it over the last
// cascade's overlap band, all of it past the last cascade, where Bevy
// lights every fragment fully (CPU reference:
// `model::crown_shade::past_shadow_maps`,
// `model::crown_shade::CrownShade::transmittance`).
fn with_crown_shade(i: u32, shadow: f32, position: vec3<f32>, depth: f32) -> f32 {
    let light = &view_bindings::lights.directional_lights[i];
    let cascades = (*light).num_cascades;
    var far = 0.0;
    if cascades > 0u {
        far = (*light).cascades[cascades - 1u].far_bound;
    }
    let crown_share = past_shadow_maps(depth, far, (*light).cascades_overlap_proportion);
    if !(crown_share > 0.0) {
        return shadow;
    }
    let world_from_local = instance_world_from_local(instances[fragment_tree]);
    let scale = length(world_from_local[0].xyz);
    let local = tree_local_point(world_from_local, scale, position);
    let basis = mat3x3<f32>(world_from_local[0].xyz, world_from_local[1].xyz, world_from_local[2].xyz);
    let to_light = transpose(basis) * (*light).direction_to_light;
    return mix(shadow, crown_transmittance(local, to_light), crown_share);
}

// How much of a directional light's shade comes from the crown at view
// `depth`: 0 before the last cascade's overlap band (its last `overlap`
// share), 1 at and past its `far` bound (CPU reference:
// `model::crown_shade::past_shadow_maps`).
fn past_shadow_maps(depth: f32, far: f32, overlap: f32) -> f32 {
    if !(far > 0.0) || depth >= far {
        return 1.0;
    }
    let near = (1.0 - clamp(overlap, 0.0, 1.0)) * far;
    if !(depth > near) {
        return 0.0;
    }
    return (depth - near) / (far - near);
}

// Point light `light_id`'s shadow at `position` (an impostor texel's: the
// mean over its samples through the crown).
fn point_shadow(light_id: u32, position: vec4<f32>, toward: vec3<f32>, frag: vec2<f32>) -> f32 {
#ifdef CONIFER_IMPOSTOR
    var sum = 0.0;
    for (var k = 0u; k < IMPOSTOR_SHADOW_SAMPLES; k++) {
        sum += shadows::fetch_point_shadow(light_id, impostor_shadow_points[k], toward, frag);
    }
    return sum / f32(IMPOSTOR_SHADOW_SAMPLES);
#else
    return shadows::fetch_point_shadow(light_id, position, toward, frag);
#endif
}

// Spot light `light_id`'s shadow at `position` (an impostor texel's: the
// mean over its samples through the crown).
fn spot_shadow(light_id: u32, position: vec4<f32>, toward: vec3<f32>, frag: vec2<f32>) -> f32 {
    let near_z = view_bindings::clustered_lights.data[light_id].shadow_map_near_z;
#ifdef CONIFER_IMPOSTOR
    var sum = 0.0;
    for (var k = 0u; k < IMPOSTOR_SHADOW_SAMPLES; k++) {
        sum += shadows::fetch_spot_shadow(light_id, impostor_shadow_points[k], toward, near_z, frag);
    }
    return sum / f32(IMPOSTOR_SHADOW_SAMPLES);
#else
    return shadows::fetch_spot_shadow(light_id, position, toward, near_z, frag);
#endif
}

// One surface's radiance under every light, ambient and environment
// (`mixed_lighting` of it alone).
fn surface_lighting(in: pbr_types::PbrInput, surface: Surface) -> vec4<f32> {
    return mixed_lighting(in, single_surface(surface));
}

// The surfaces' radiance under every light, ambient and environment,
// summed by their shares (`SurfaceMix`). Each light's shadow is fetched
// once, at the first surface with a share (its `toward` the normal the
// shadow's bias leans on; an impostor texel's is the mean over its samples
// through the crown), and its view light scale taken once.
fn mixed_lighting(in: pbr_types::PbrInput, mixed: SurfaceMix) -> vec4<f32> {
    var surfaces = mixed;
    let V = in.V;
    var toward = surfaces.first.toward;
    if surfaces.shares.x == 0.0 {
        toward = select(surfaces.third.toward, surfaces.second.toward, surfaces.shares.y != 0.0);
    }

    let base = in.material.base_color.rgb;
    let perceptual_roughness = in.material.perceptual_roughness;
    var input: lighting::LightingInput;
    input.layers[lighting::LAYER_BASE].perceptual_roughness = perceptual_roughness;
    input.layers[lighting::LAYER_BASE].roughness = lighting::perceptualRoughnessToRoughness(perceptual_roughness);
    input.P = in.world_position.xyz;
    input.V = V;
    input.diffuse_color = pbr_functions::calculate_diffuse_color(base, 0.0, 0.0, 0.0);
    input.metallic = 0.0;
    input.F0_dielectric = pbr_functions::calculate_F0_dielectric(in.material.reflectance);
    input.F0_metallic = base;

    let view_z = view_depth(in.world_position);
    let cluster_index = clustering::view_fragment_cluster_index(in.frag_coord.xy, view_z, in.is_orthographic);
    var ranges = clustering::unpack_clusterable_object_index_ranges(cluster_index);
    let receiver = (in.flags & MESH_FLAGS_SHADOW_RECEIVER_BIT) != 0u;

    var direct = vec3<f32>(0.0);
    for (var i: u32 = ranges.first_point_light_index_offset; i < ranges.first_spot_light_index_offset; i = i + 1u) {
        let light_id = clustering::get_clusterable_object_id(i);
        let to_light = normalize(view_bindings::clustered_lights.data[light_id].position_radius.xyz - in.world_position.xyz);
        var shadow = 1.0;
        if receiver && (view_bindings::clustered_lights.data[light_id].flags & mesh_view_types::POINT_LIGHT_FLAGS_SHADOWS_ENABLED_BIT) != 0u {
            shadow = point_shadow(light_id, in.world_position, toward, in.frag_coord.xy);
        }
        direct += mixed_light(&surfaces, &input, LIGHT_POINT, light_id, to_light) * shadow;
    }
    for (var i: u32 = ranges.first_spot_light_index_offset; i < ranges.first_reflection_probe_index_offset; i = i + 1u) {
        let light_id = clustering::get_clusterable_object_id(i);
        let to_light = normalize(view_bindings::clustered_lights.data[light_id].position_radius.xyz - in.world_position.xyz);
        var shadow = 1.0;
        if receiver && (view_bindings::clustered_lights.data[light_id].flags & mesh_view_types::POINT_LIGHT_FLAGS_SHADOWS_ENABLED_BIT) != 0u {
            shadow = spot_shadow(light_id, in.world_position, toward, in.frag_coord.xy);
        }
        direct += mixed_light(&surfaces, &input, LIGHT_SPOT, light_id, to_light) * shadow;
    }
    for (var i: u32 = 0u; i < view_bindings::lights.n_directional_lights; i = i + 1u) {
        let to_light = view_bindings::lights.directional_lights[i].direction_to_light;
        var shadow = 1.0;
        if receiver && (view_bindings::lights.directional_lights[i].flags & mesh_view_types::DIRECTIONAL_LIGHT_FLAGS_SHADOWS_ENABLED_BIT) != 0u {
            shadow = directional_shadow(i, in.world_position, toward, view_z, in.frag_coord.xy);
        }
        direct += mixed_light(&surfaces, &input, LIGHT_DIRECTIONAL, i, to_light) * shadow;
    }

    // Bevy's indirect light depends on the normal's angle to the view (its
    // split-sum Fresnel grows toward a silhouette): averaged over the
    // cylinder's width or the sphere's disk at four view cosines. Bevy's
    // ambient light reads only the cosine, so the spheres and the
    // cylinders seen square-on share its four calls (their nodes lie at
    // the same cosines); a band of a cylinder, and a cylinder seen along
    // its axis, take their own (`surface_indirect`). The environment map
    // is taken at each surface's normal facing the viewer.
    let F0 = pbr_functions::calculate_F0(base, 0.0, in.material.reflectance);
    var indirect = vec3<f32>(0.0);
    var node_weights = vec4<f32>(0.0);
    indirect += surface_indirect(in, surfaces.first, surfaces.shares.x, input.diffuse_color, F0, &node_weights);
    indirect += surface_indirect(in, surfaces.second, surfaces.shares.y, input.diffuse_color, F0, &node_weights);
    indirect += surface_indirect(in, surfaces.third, surfaces.shares.z, input.diffuse_color, F0, &node_weights);
    for (var k = 0u; k < 4u; k = k + 1u) {
        if node_weights[k] != 0.0 {
            indirect += node_weights[k] * ambient::ambient_light(
                in.world_position,
                V,
                V,
                indirect_node(k, false).x,
                input.diffuse_color,
                F0,
                perceptual_roughness,
                in.diffuse_occlusion,
            );
        }
    }
#ifdef ENVIRONMENT_MAP
    indirect += surface_environment(in, surfaces.first, surfaces.shares.x, &input, &ranges);
    indirect += surface_environment(in, surfaces.second, surfaces.shares.y, &input, &ranges);
    indirect += surface_environment(in, surfaces.third, surfaces.shares.z, &input, &ranges);
#endif
    return vec4<f32>(view_bindings::view.exposure * (direct + indirect), in.material.base_color.a);
}

// The surfaces' direct radiance under one light (`surface_light`), summed
// by their shares, times the view light scale where the mix takes it.
fn mixed_light(
    surfaces: ptr<function, SurfaceMix>,
    input: ptr<function, lighting::LightingInput>,
    kind: u32,
    light_id: u32,
    to_light: vec3<f32>,
) -> vec3<f32> {
    let shares = (*surfaces).shares;
    var sum = vec3<f32>(0.0);
    if shares.x != 0.0 {
        sum += shares.x * surface_light((*surfaces).first, input, kind, light_id, to_light);
    }
    if shares.y != 0.0 {
        sum += shares.y * surface_light((*surfaces).second, input, kind, light_id, to_light);
    }
    if shares.z != 0.0 {
        sum += shares.z * surface_light((*surfaces).third, input, kind, light_id, to_light);
    }
#ifdef CONIFER_IMPOSTOR
    if (*surfaces).light_scaled {
        sum *= view_light_scale(to_light, (*input).V);
    }
#endif
    return sum;
}

// The ambient light on `surface` times its `share`. A cylinder seen at
// angle β to its axis turns its normal at angle φ from the viewer to
// `n·V = sin β · cos φ` (`toward·V = sin β`; a sphere's is 1): a band of a
// cylinder at its own four nodes, a whole width seen from aside at the
// shared nodes' cosines times `sin β`, each one call; a sphere's disk and
// a whole width seen square-on (`sin β` within 10⁻³ of 1) add the nodes'
// weights to `node_weights`, at the cosines those surfaces share
// (`indirect_node`), for one call each (CPU reference:
// `model::shading::cylinder_indirect_cosines`).
fn surface_indirect(
    in: pbr_types::PbrInput,
    surface: Surface,
    share: f32,
    diffuse_color: vec3<f32>,
    F0: vec3<f32>,
    node_weights: ptr<function, vec4<f32>>,
) -> vec3<f32> {
    var indirect = vec3<f32>(0.0);
    if share == 0.0 {
        return indirect;
    }
    let band = surface.band;
    let tilt = clamp(dot(surface.toward, in.V), 0.0, 1.0);
    for (var k = 0u; k < 4u; k = k + 1u) {
        var weight = share;
        var cosine = 0.0;
        if band.y > band.x {
            // A band of a cylinder: four Gauss–Legendre nodes across it.
            let s = 0.5 * (band.x + band.y) + 0.5 * (band.y - band.x) * across_offset(k);
            weight *= 0.5 * across_weight(k);
            cosine = sqrt(max(1.0 - s * s, 1e-8)) * tilt;
        } else if surface.is_sphere || tilt > 0.999 {
            (*node_weights)[k] += share * indirect_node(k, surface.is_sphere).y;
            continue;
        } else {
            let node = indirect_node(k, false);
            weight *= node.y;
            cosine = node.x * tilt;
        }
        indirect += weight * ambient::ambient_light(
            in.world_position,
            in.V,
            in.V,
            max(cosine, 1e-4),
            diffuse_color,
            F0,
            in.material.perceptual_roughness,
            in.diffuse_occlusion,
        );
    }
    return indirect;
}

#ifdef ENVIRONMENT_MAP
// The environment map's light on `surface` at its normal facing the
// viewer, times its `share`.
fn surface_environment(
    in: pbr_types::PbrInput,
    surface: Surface,
    share: f32,
    input: ptr<function, lighting::LightingInput>,
    ranges: ptr<function, clustering::ClusterableObjectIndexRanges>,
) -> vec3<f32> {
    if share == 0.0 {
        return vec3<f32>(0.0);
    }
    set_normal(input, surface.toward);
    let environment = environment_map::environment_map_light(input, ranges, false);
    return share * (environment.diffuse * in.diffuse_occlusion + environment.specular * in.specular_occlusion);
}
#endif
#endif
#endif

#ifdef CONIFER_IMPOSTOR
// `impostor_shadow_depths` for a crown whose needles are even along the
// chord, in closed form: `½ chord − chord · ln(1 − q · coverage) /
// ln(1 − coverage)` (CPU reference: `model::impostor::shadow_sample_depths`
// with every ring's density 1, which its steps give exactly).
fn even_crown_shadow_depths(coverage: f32, offset: f32, radius: f32) -> vec3<f32> {
    let half_chord = sqrt(max(radius * radius - offset * offset, 0.0));
    if !(half_chord > 0.0 && half_chord < 1e30 && coverage == coverage) {
        return vec3<f32>(0.0);
    }
    let c = clamp(coverage, 1e-4, 0.999);
    let q = vec3<f32>(1.0 / 6.0, 0.5, 5.0 / 6.0);
    return vec3<f32>(half_chord) - 2.0 * half_chord * log(vec3<f32>(1.0) - q * c) / log(1.0 - c);
}

// The crown's ring densities at tree-local `height`, linear between the
// profile's heights (CPU reference:
// `model::impostor::CrownDensity::row_at`).
fn crown_density_row(height: f32) -> array<f32, CROWN_DENSITY_RINGS> {
    let step = crown_profile_step(height);
    let k = u32(step.x);
    var row: array<f32, CROWN_DENSITY_RINGS>;
    for (var ring = 0u; ring < CROWN_DENSITY_RINGS; ring++) {
        let below = k * CROWN_DENSITY_RINGS + ring;
        let above = below + CROWN_DENSITY_RINGS;
        row[ring] = mix(species.crown_density[below / 4u][below % 4u], species.crown_density[above / 4u][above % 4u], step.y);
    }
    return row;
}

// A density row's density at `share` of the crown's radius from the axis,
// linear between the rings' middles (CPU reference:
// `model::impostor::density_across`).
fn density_across(row: ptr<function, array<f32, CROWN_DENSITY_RINGS>>, share: f32) -> f32 {
    let rings = f32(CROWN_DENSITY_RINGS);
    var f = clamp(share * rings - 0.5, 0.0, rings - 1.0);
    if !(f == f) {
        f = 0.0;
    }
    let k = min(u32(f), CROWN_DENSITY_RINGS - 2u);
    return mix((*row)[k], (*row)[k + 1u], f - f32(k));
}

// Depths (tree metres toward the camera from the card) of the texel's
// shadow samples: the 1/6, 1/2 and 5/6 quantiles of where its visible
// needles lie on the chord through a crown of `radius`, the texel
// `offset` from the axis, the needles as dense along
// it as the density `row` says at each point's distance from the axis
// (the crown's rings at the texel's height, or all 1 for an even crown)
// and `coverage` seen (CPU reference:
// `model::impostor::shadow_sample_depths`).
fn impostor_shadow_depths(coverage: f32, offset: f32, radius: f32, row: ptr<function, array<f32, CROWN_DENSITY_RINGS>>) -> vec3<f32> {
    let half_chord = sqrt(max(radius * radius - offset * offset, 0.0));
    if !(half_chord > 0.0 && half_chord < 1e30 && coverage == coverage) {
        return vec3<f32>(0.0);
    }
    let c = clamp(coverage, 1e-4, 0.999);
    let step = 2.0 * half_chord / f32(SHADOW_DEPTH_STEPS);
    // The chord's needles in front of each step's far end, from the near
    // side.
    var in_front: array<f32, SHADOW_DEPTH_STEPS + 1u>;
    in_front[0] = 0.0;
    for (var k = 0u; k < SHADOW_DEPTH_STEPS; k++) {
        let depth = half_chord - (f32(k) + 0.5) * step;
        let share = sqrt(offset * offset + depth * depth) / radius;
        in_front[k + 1u] = in_front[k] + density_across(row, share);
    }
    if !(in_front[SHADOW_DEPTH_STEPS] > 0.0 && in_front[SHADOW_DEPTH_STEPS] < 1e30) {
        for (var k = 0u; k <= SHADOW_DEPTH_STEPS; k++) {
            in_front[k] = f32(k);
        }
    }
    let through = log(1.0 - c);
    let q = vec3<f32>(1.0 / 6.0, 0.5, 5.0 / 6.0);
    var depths: vec3<f32>;
    for (var i = 0u; i < 3u; i++) {
        let wanted = in_front[SHADOW_DEPTH_STEPS] * log(1.0 - q[i] * c) / through;
        var k = SHADOW_DEPTH_STEPS - 1u;
        for (var j = 0u; j < SHADOW_DEPTH_STEPS - 1u; j++) {
            if in_front[j + 1u] >= wanted {
                k = j;
                break;
            }
        }
        let within = clamp((wanted - in_front[k]) / max(in_front[k + 1u] - in_front[k], 1e-12), 0.0, 1.0);
        depths[i] = half_chord - (f32(k) + within) * step;
    }
    return depths;
}
#endif

// Where tree-local `height` falls in the crown's profile: the step below
// it (x) and how far toward the next (y), linear between the steps'
// middles, the end steps' outside them (CPU reference:
// `model::impostor::CrownImpostor::crown_radius_at`).
fn crown_profile_step(height: f32) -> vec2<f32> {
    let steps = f32(CROWN_PROFILE_STEPS);
    let span = species.impostor_span;
    var f = clamp((height - span.x) / (span.y - span.x) * steps - 0.5, 0.0, steps - 1.0);
    if !(f == f) {
        f = 0.0;
    }
    let k = min(u32(f), CROWN_PROFILE_STEPS - 2u);
    return vec2<f32>(f32(k), f - f32(k));
}

// The crown's radius at tree-local `height` (CPU reference:
// `model::impostor::CrownImpostor::crown_radius_at`).
fn crown_radius_at(height: f32) -> f32 {
    let step = crown_profile_step(height);
    let k = u32(step.x);
    let a = species.crown_radii[k / 4u][k % 4u];
    let b = species.crown_radii[(k + 1u) / 4u][(k + 1u) % 4u];
    return mix(a, b, step.y);
}

// The trunk at tree-local `height`: its centre (tree-local x, z) and
// radius, 0 where none stands (CPU reference:
// `model::impostor::TrunkProfile::at`).
fn trunk_at(height: f32) -> vec3<f32> {
    let step = crown_profile_step(height);
    let k = u32(step.x);
    return mix(species.trunk[k].xyz, species.trunk[k + 1u].xyz, step.y);
}

// The band `[s0, s1]` of the trunk's projected width a pixel covers, its
// centre `offset` metres right of the trunk's axis and its footprint
// `footprint` metres wide across it; `s1 ≤ s0` where it misses the trunk
// (CPU reference: `model::impostor::TrunkProfile::band`).
fn trunk_band(offset: f32, footprint: f32, radius: f32) -> vec2<f32> {
    if !(radius > 0.0) {
        return vec2<f32>(0.0);
    }
    let half = 0.5 * abs(footprint);
    return vec2<f32>(max((offset - half) / radius, -1.0), min((offset + half) / radius, 1.0));
}

// The extinctions (per tree metre) of the crown's CROWN_SHADE_CLASSES
// media at tree-local `height` (CPU reference:
// `model::crown_shade::CrownShade::extinction_at`).
fn crown_extinction_at(height: f32) -> vec4<f32> {
    let step = crown_profile_step(height);
    let k = u32(step.x);
    return max(mix(species.crown_extinction[k], species.crown_extinction[k + 1u], step.y), vec4<f32>(0.0));
}

// How far inside the crown tree-local `p` lies, metres, negative outside
// (CPU reference: `model::crown_shade::CrownShade::inside`).
fn crown_inside(p: vec3<f32>) -> f32 {
    let span = species.impostor_span;
    let distance = length(p.xz - species.impostor_box.xy);
    return min(min(crown_radius_at(p.y) - distance, p.y - span.x), span.y - p.y);
}

// Where the ray from tree-local `p` along the unit `toward` crosses the
// upright cylinder of the crown's widest radius between its bottom and
// top: its distances in (no nearer than `p`) and out; (0, 0) where the ray
// never meets it (CPU reference: `model::crown_shade::CrownShade::crossing`).
fn crown_crossing(p: vec3<f32>, toward: vec3<f32>) -> vec2<f32> {
    let widest = species.crown_widest_radius;
    let span = species.impostor_span;
    let offset = p.xz - species.impostor_box.xy;
    let across = toward.xz;
    let a = dot(across, across);
    var side = vec2<f32>(-3.0e38, 3.0e38);
    if a > 1e-12 {
        let b = dot(offset, across);
        let c = dot(offset, offset) - widest * widest;
        let disc = b * b - a * c;
        if disc < 0.0 {
            return vec2<f32>(0.0);
        }
        side = vec2<f32>(-b - sqrt(disc), -b + sqrt(disc)) / a;
    } else if length(offset) > widest {
        return vec2<f32>(0.0);
    }
    var ends = vec2<f32>(-3.0e38, 3.0e38);
    if abs(toward.y) > 1e-6 {
        let to_bottom = (span.x - p.y) / toward.y;
        let to_top = (span.y - p.y) / toward.y;
        ends = vec2<f32>(min(to_bottom, to_top), max(to_bottom, to_top));
    } else if p.y < span.x || p.y > span.y {
        return vec2<f32>(0.0);
    }
    let enter = max(max(side.x, ends.x), 0.0);
    let exit = min(side.y, ends.y);
    if !(exit > enter && exit < 1.0e38) {
        return vec2<f32>(0.0);
    }
    return vec2<f32>(enter, exit);
}

// What the crown lets through from tree-local `p` toward a light along
// `to_light` (tree-local, any length): the mean over its media of exp of
// minus the extinction summed over CROWN_SHADE_STEPS even steps of its
// crossing, each step's length
// inside the crown taken with its inside depth linear along it; 1 without
// an impostor's profile (CPU reference:
// `model::crown_shade::CrownShade::transmittance`).
fn crown_transmittance(p: vec3<f32>, to_light: vec3<f32>) -> f32 {
    let span = species.impostor_span;
    let len = length(to_light);
    if !(span.w > 0.0 && span.y > span.x && len > 0.0 && len < 1.0e30) {
        return 1.0;
    }
    let toward = to_light / len;
    let crossing = crown_crossing(p, toward);
    if !(crossing.y > crossing.x) {
        return 1.0;
    }
    let step = (crossing.y - crossing.x) / f32(CROWN_SHADE_STEPS);
    var depth = vec4<f32>(0.0);
    var before = crown_inside(p + toward * crossing.x);
    for (var k = 1u; k <= CROWN_SHADE_STEPS; k++) {
        let after = crown_inside(p + toward * (crossing.x + step * f32(k)));
        let middle = p + toward * (crossing.x + step * (f32(k) - 0.5));
        var share = 0.0;
        if before > 0.0 && after > 0.0 {
            share = 1.0;
        } else if before > 0.0 {
            share = before / (before - after);
        } else if after > 0.0 {
            share = after / (after - before);
        }
        depth += crown_extinction_at(middle.y) * (share * step);
        before = after;
    }
    return dot(exp(-depth), vec4<f32>(1.0 / f32(CROWN_SHADE_CLASSES)));
}

// The share of the sky tree-local `p` sees through the crown: bilinear
// in the species' table by height (between the profile steps' middles)
// and by distance from the axis over the crown's radius there (clamped at
// its edge); 1 without an impostor, and everywhere with
// `ConiferLodSettings::sky_occlusion` off, whose table is all 1 (CPU
// reference: `model::crown_shade::SkyVisibility::at`).
fn sky_visibility_at(p: vec3<f32>) -> f32 {
    let span = species.impostor_span;
    if !(span.w > 0.0 && span.y > span.x) {
        return 1.0;
    }
    let step = crown_profile_step(p.y);
    let k = u32(step.x);
    let row = mix(species.sky_visibility[k], species.sky_visibility[k + 1u], step.y);
    let last = f32(SKY_VISIBILITY_RINGS - 1u);
    let radius = crown_radius_at(p.y);
    var ring = last;
    if radius > 0.0 {
        ring = clamp(length(p.xz - species.impostor_box.xy) / radius * last, 0.0, last);
    }
    if !(ring == ring) {
        return 1.0;
    }
    let j = min(u32(ring), SKY_VISIBILITY_RINGS - 2u);
    return mix(row[j], row[j + 1u], ring - f32(j));
}

// The share of the wood the needles leave in sight where they cover the
// picture, at tree-local `height` and `nearness` (metres toward the
// camera from the crown's axis): bilinear in the impostor's table, 1
// without an impostor (CPU reference: `model::impostor::WoodVisibility::at`).
fn wood_visibility_at(height: f32, nearness: f32) -> f32 {
    let span = species.impostor_span;
    if !(span.w > 0.0 && span.y > span.x) {
        return 1.0;
    }
    let radius = max(crown_radius_at(height), 1e-6);
    let steps = f32(CROWN_PROFILE_STEPS);
    let bins = f32(WOOD_NEARNESS_BINS);
    let fh = clamp((height - span.x) / (span.y - span.x) * steps - 0.5, 0.0, steps - 1.0);
    let fb = clamp((nearness / radius + 1.0) * 0.5 * bins - 0.5, 0.0, bins - 1.0);
    if !(fh == fh && fb == fb) {
        return 1.0;
    }
    let k = min(u32(fh), CROWN_PROFILE_STEPS - 2u);
    let b = min(u32(fb), WOOD_NEARNESS_BINS - 2u);
    let th = fh - f32(k);
    let tb = fb - f32(b);
    let low = mix(wood_visibility_entry(k, b), wood_visibility_entry(k, b + 1u), tb);
    let high = mix(wood_visibility_entry(k + 1u, b), wood_visibility_entry(k + 1u, b + 1u), tb);
    return clamp(mix(low, high, th), 0.0, 1.0);
}

fn wood_visibility_entry(step: u32, bin: u32) -> f32 {
    let k = step * WOOD_NEARNESS_BINS + bin;
    return species.wood_visibility[k / 4u][k % 4u];
}

#ifdef CONIFER_ROUND_PRISMS
// The normal of a round cylinder where a prism's fragment lies: `normal`
// is the prism's normal interpolated across its face (not normalized), its
// component along the unit `side` (across the view) the offset `s` across
// the width, as a corner's position is; `toward` is the ring's normal
// facing the view. Returns `√(1 − s²)·toward + s·side`; a cap's normal
// (along the axis) is kept. CPU reference:
// `model::shading::round_prism_normal`.
fn round_prism_normal(normal: vec3<f32>, side: vec3<f32>, toward: vec3<f32>) -> vec3<f32> {
    let s = clamp(dot(normal, side), -1.0, 1.0);
    let along = normal - s * side - dot(normal, toward) * toward;
    if dot(along, along) > 0.25 {
        return normalize(normal);
    }
    return sqrt(max(1.0 - s * s, 0.0)) * toward + s * side;
}
#endif

// The main pass's output: the colour, and under 4× MSAA the samples it
// goes to (`crossfade_samples`).
struct FragmentOutput {
    @location(0) color: vec4<f32>,
#ifdef CONIFER_CROSSFADE_SAMPLES
    @builtin(sample_mask) samples: u32,
#endif
}

@fragment
fn fragment(in: VertexOutput) -> FragmentOutput {
#ifdef CONIFER_LINES
#ifndef CONIFER_FACING_STRIP
    fragment_tree = in.tree;
#endif
#endif
    let fade_samples = crossfade_samples(in.position.xy, in.tree);
    if fade_samples == 0u {
        discard;
    }
#ifdef CONIFER_LINE_QUADS
    // The pixel takes the line's strip's area in it; a quad's corners
    // reach past the strip (`LINE_QUAD_MARGIN`), and most of its pixels
    // lie off it.
    let line_opacity = pixel_line_coverage(in);
    if !(line_opacity > 1.0 / 1024.0) {
        discard;
    }
#endif
    var pbr_input = pbr_types::pbr_input_new();
    pbr_input.material.base_color = in.color;
    var axis = in.world_normal;
    // The frame of the fragment's tree (the impostor's picture, the
    // crown's sky).
    let world_from_local = instance_world_from_local(instances[in.tree]);
    let tree_scale = length(world_from_local[0].xyz);
#ifdef CONIFER_IMPOSTOR
    // The two views' texels over the pixel's footprint: coverage, wood,
    // and the shares lit as a vertical cylinder and as one across the view
    // (both times coverage; the rest is lit as a sphere).
    let uv = impostor_swayed_uv(in.uv, in.tree, in.card_point, in.card_right, in.card_up, in.world_position.xyz);
    let texel = impostor_texel(uv, in.color);
    if !(texel.r > 1.0 / 512.0) {
        discard;
    }
    let wood = clamp(texel.g / texel.r, 0.0, 1.0);
    let height = tree_local_point(world_from_local, tree_scale, in.world_position.xyz).y;
    var needle_albedo = species.far_needle_color.rgb;
    var stem_albedo = bark_albedo(height);
    if species.debug_colors != 0u {
        needle_albedo = vec3<f32>(0.85, 0.2, 0.85);
        stem_albedo = needle_albedo;
    }
    let albedo = mix(needle_albedo, stem_albedo, wood);
    pbr_input.material.base_color = vec4<f32>(albedo, texel.r);
    let vertical_share = clamp(texel.b / texel.r, 0.0, 1.0);
    let across_share = clamp(texel.a / texel.r, 0.0, 1.0 - vertical_share);
    axis = normalize(world_from_local[1].xyz);
    // The view's right: across the camera's azimuth round the impostor's
    // axis, as the quad is turned.
    let camera_local = tree_local_point(world_from_local, tree_scale, view.world_position);
    var to_camera = camera_local.xz - species.impostor_box.xy;
    if dot(to_camera, to_camera) < 1e-12 {
        to_camera = vec2<f32>(0.0, 1.0);
    }
    to_camera = normalize(to_camera);
    let across_axis = normalize((world_from_local * vec4<f32>(to_camera.y, 0.0, -to_camera.x, 0.0)).xyz);
    // The wood the texel shows over the trunk is the round stem's band
    // under the pixel, not a cylinder's mean across its whole width
    // (`model::impostor::TrunkProfile`): the picture's row and column,
    // right of the trunk's centre along the camera's right.
    let picture_height = mix(species.impostor_span.y, species.impostor_span.x, uv.y);
    let trunk = trunk_at(picture_height);
    let trunk_offset = (2.0 * uv.x - 1.0) * species.impostor_box.z
        - dot(trunk.xy - species.impostor_box.xy, vec2<f32>(to_camera.y, -to_camera.x));
    // The pixel's footprint across it from the picture's own derivatives
    // (as `impostor_texel` takes them): where a fading tree's dither
    // discarded a neighbour, the derivative of a value built through a
    // `var` after the discard is not the picture's (lavapipe).
    let trunk_footprint = 2.0 * species.impostor_box.z * length(vec2<f32>(dpdx(uv.x), dpdy(uv.x)));
    let stem_band = trunk_band(trunk_offset, trunk_footprint, trunk.z);
#endif
#ifdef CONIFER_ROUND_PRISMS
    // A prism is shaded as the round cylinder it stands for: the normal at
    // the fragment's offset across the width (CPU reference:
    // `model::shading::round_prism_normal`), not the facets' interpolated
    // normal, which a prism of few sides spends twice as long near its rim.
    axis = round_prism_normal(in.world_normal, in.prism_side, in.prism_toward);
#endif
#ifdef CONIFER_BARK
    // The bark's colour at this fragment's height (taken at the vertices,
    // it would be right only at a segment's ends).
    if species.debug_colors == 0u {
        pbr_input.material.base_color = vec4<f32>(bark_albedo(in.local_height), in.color.a);
    }
#endif
#ifdef CONIFER_LINE_QUADS
    pbr_input.material.base_color.a = line_opacity;
#endif
#ifdef CONIFER_BARK
    pbr_input.material.perceptual_roughness = BARK_ROUGHNESS;
#else
    pbr_input.material.perceptual_roughness = species.roughness;
#endif
    pbr_input.material.reflectance = vec3<f32>(species.reflectance);
#ifdef CONIFER_LINES
    pbr_input.material.flags = pbr_types::STANDARD_MATERIAL_FLAGS_FOG_ENABLED_BIT
        | pbr_types::STANDARD_MATERIAL_FLAGS_ALPHA_MODE_BLEND;
#else
    pbr_input.material.flags = pbr_types::STANDARD_MATERIAL_FLAGS_FOG_ENABLED_BIT
        | pbr_types::STANDARD_MATERIAL_FLAGS_ALPHA_MODE_OPAQUE;
#endif
    pbr_input.frag_coord = in.position;
    pbr_input.world_position = in.world_position;
    pbr_input.world_normal = normalize(axis);
    pbr_input.is_orthographic = view.clip_from_view[3].w == 1.0;
    pbr_input.V = pbr_functions::calculate_view(in.world_position, pbr_input.is_orthographic);
#ifdef CONIFER_IMPOSTOR
    // The quad stands on the trunk, inside the crown: what the camera sees
    // of a texel are needles spread along its ray through the crown, nearer
    // its near side the denser it is. Shadows are averaged over three
    // points where they lie, lights taken at the middle one.
    // The shadow maps hold the crown's needles: their samples go where the
    // crown's rings put the texel's needles. The crown's own shade past
    // the maps is an even medium's: its samples go where an even crown
    // puts them, as the lines' shade past the maps and in them agree.
    let offset = (2.0 * uv.x - 1.0) * species.impostor_box.z;
    let radius = crown_radius_at(height);
    var density = crown_density_row(height);
    let depths = impostor_shadow_depths(texel.r, offset, radius, &density);
    let crown_depths = even_crown_shadow_depths(texel.r, offset, radius);
#ifdef CONIFER_FACING_STRIP
    // Bevy's own lighting takes one shadow, at the middle sample.
    pbr_input.world_position = vec4<f32>(in.world_position.xyz + pbr_input.V * (depths[1] * tree_scale), 1.0);
#else
    impostor_shadow_samples(in.world_position.xyz, pbr_input.V, depths, crown_depths, tree_scale, in.position.xy);
    pbr_input.world_position = impostor_shadow_points[1];
#endif
    let crown_point = in.world_position.xyz + pbr_input.V * (crown_depths[1] * tree_scale);
#endif
    pbr_input.N = pbr_input.world_normal;
    pbr_input.flags = MESH_FLAGS_SHADOW_RECEIVER_BIT;
    // The ambient light reaches a point inside the crown through it
    // (`ConiferLodSettings::sky_occlusion`), at the point the fragment is
    // lit at (an impostor's middle crown sample: the sky's table is the
    // even crown's).
#ifdef CONIFER_IMPOSTOR
    let sky = sky_visibility_at(tree_local_point(world_from_local, tree_scale, crown_point));
#else
    let sky = sky_visibility_at(tree_local_point(world_from_local, tree_scale, pbr_input.world_position.xyz));
#endif
    pbr_input.diffuse_occlusion = vec3<f32>(sky);
    pbr_input.specular_occlusion = sky;
#ifdef CONIFER_FACING_STRIP
    // A strip turned toward the viewer (`LineLighting::FacingStrip`).
    var normal = pbr_input.V - pbr_input.world_normal * dot(pbr_input.world_normal, pbr_input.V);
    if dot(normal, normal) < 1e-12 {
        normal = pbr_input.V;
    }
    pbr_input.world_normal = normalize(normal);
    pbr_input.N = pbr_input.world_normal;
    var color = pbr_functions::apply_pbr_lighting(pbr_input);
#else ifdef CONIFER_IMPOSTOR
    // The texel's needles lit as shares of two cylinders and a sphere
    // (CPU reference: `model::shading::TexelShares::lambert`).
    var color: vec4<f32>;
    if !(stem_band.y > stem_band.x && wood > 0.0) {
        color = shares_lighting(pbr_input, axis, across_axis, vertical_share, across_share);
    } else {
        // Over the trunk the needles keep their shares and the wood is the
        // stem's band (`model::shading::band_average`), in the bark's
        // roughness.
        var needles = pbr_input;
        needles.material.base_color = vec4<f32>(needle_albedo, texel.r);
        var stem = pbr_input;
        stem.material.base_color = vec4<f32>(stem_albedo, texel.r);
        stem.material.perceptual_roughness = BARK_ROUGHNESS;
        color = mix(
            shares_lighting(needles, axis, across_axis, vertical_share, across_share),
            band_lighting(stem, axis, stem_band),
            wood
        );
    }
    color.a = pbr_input.material.base_color.a;
#else ifdef CONIFER_LINES
#ifdef CONIFER_BUNDLE
    // A merged line's needles spread about its chord: its alignment's share
    // of the chord's cylinder, the rest lit as a sphere, in one pass over
    // the lights (CPU reference: `model::shading::bundle_lambert`).
    var surfaces = single_surface(cylinder_surface(axis, pbr_input.V, vec2<f32>(0.0)));
    let cylinder_share = 1.0 - BUNDLE_SLOPE * (1.0 - in.alignment);
    if cylinder_share < 1.0 - 1.0 / 512.0 {
        surfaces.second = sphere_surface(pbr_input.V);
        surfaces.shares = vec3<f32>(cylinder_share, 1.0 - cylinder_share, 0.0);
    }
    var color = mixed_lighting(pbr_input, surfaces);
    color = vec4<f32>(max(color.rgb, vec3<f32>(0.0)), color.a);
#else
    var color = cylinder_lighting(pbr_input, axis);
#endif
#else
    var color = pbr_functions::apply_pbr_lighting(pbr_input);
#endif
    color = pbr_functions::main_pass_post_lighting_processing(pbr_input, color);
    var out: FragmentOutput;
    out.color = color;
#ifdef CONIFER_CROSSFADE_SAMPLES
    out.samples = fade_samples;
#endif
    return out;
}
#endif
