// Shadows of translucent lines: a hashed (stochastic) alpha test in the
// prepass, with the very opacity the colour pass blends with.
//
// A line of opacity a covers a fraction a of the pixels (or shadow-map
// texels) it crosses; blended, overlapping lines give 1 − Π(1 − aᵢ). In a
// depth-only pass a fragment can only be kept or discarded, so each one is
// kept with probability a, decided by a hash of its texel, its line and its
// tree: independent between overlapping lines, so they compose as blending
// does, and fixed from frame to frame, so the shadow does not crawl while
// the light and tree stand still. The shadow's filtering (PCF) averages the
// kept texels back into a partial shadow.
//
// The LOD vertex shader (conifer_lod.wgsl) hands the line's index, its
// instance and its opacity over as the vertex colour. CPU reference:
// `model::gpu_layout::shadow_texel_kept`.

#import bevy_pbr::prepass_io::VertexOutput
#ifdef PREPASS_FRAGMENT
#import bevy_pbr::prepass_io::FragmentOutput
#endif
#ifdef MOTION_VECTOR_PREPASS
#import bevy_pbr::pbr_prepass_functions::calculate_motion_vector
#endif

// PCG hash (Jarzynski and Olano, "Hash Functions for GPU Rendering", JCGT 2020).
fn pcg(value: u32) -> u32 {
    let state = value * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Whether the fragment at `texel` of line `line` of tree `tree`, of opacity
// `alpha`, is kept: with probability `alpha`.
fn texel_kept(texel: vec2<u32>, line: u32, tree: u32, alpha: f32) -> bool {
    let h = pcg(texel.x ^ pcg(texel.y ^ pcg(line ^ pcg(tree))));
    return f32(h >> 8u) * (1.0 / 16777216.0) < alpha;
}

fn hashed_alpha_test(in: VertexOutput) {
#ifdef VERTEX_COLORS
    let line = u32(in.color.r + 0.5);
    let tree = u32(in.color.g + 0.5);
    if !texel_kept(vec2<u32>(in.position.xy), line, tree, in.color.a) {
        discard;
    }
#endif
}

#ifdef PREPASS_FRAGMENT
@fragment
fn fragment(in: VertexOutput) -> FragmentOutput {
    hashed_alpha_test(in);
    var out: FragmentOutput;
#ifdef UNCLIPPED_DEPTH_ORTHO_EMULATION
    out.frag_depth = in.unclipped_depth;
#endif
#ifdef NORMAL_PREPASS
    out.normal = vec4<f32>(in.world_normal * 0.5 + vec3<f32>(0.5), 1.0);
#endif
#ifdef MOTION_VECTOR_PREPASS
    out.motion_vector = calculate_motion_vector(in.world_position, in.previous_world_position);
#endif
    return out;
}
#else
@fragment
fn fragment(in: VertexOutput) {
    hashed_alpha_test(in);
}
#endif
