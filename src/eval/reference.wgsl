// The reference's surface: Bevy's PBR lighting of an opaque surface, as
// `StandardMaterial` lights one with only a colour, roughness and
// reflectance, with the position and normal interpolated at the centroid of
// the pixel's covered samples (CPU-side: `eval::reference`).
//
// With MSAA a triangle's fragment is shaded once a pixel, by default at the
// pixel's centre even where the triangle covers only a sample near its
// edge: a needle a tenth of a sample wide has its normal extrapolated ten
// times past its ring, where it points sideways. The centroid lies in the
// triangle, so every needle is shaded with a normal of its own surface.
//
// Colour as the plugin gives it (`model::color`): needles by their shoot
// (`REFERENCE_SHOOTS`: a shoot index per vertex into `shoots`, each
// shoot's age colour mixed with the underside colour as the viewer sees
// its upper side, the vertex shader's `placed_needle_albedo`), bark by
// height (`bark_heights`, the fragment shader's `bark_albedo`).

#import bevy_pbr::{
    mesh_bindings::mesh,
    mesh_functions,
    mesh_view_bindings::view,
    view_transformations::position_world_to_clip,
    pbr_types,
    pbr_functions,
}
#import bevy_conifer_lod::compact_types::{shoot_needle_color, bark_between}

struct ReferenceSurface {
    // Linear RGBA: the needles' colour where they have no shoots, the
    // bark's below `bark_heights.x`.
    base_color: vec4<f32>,
    // Linear RGBA: needles seen from under their shoot.
    underside_color: vec4<f32>,
    // Linear RGBA: the bark's above `bark_heights.y`.
    upper_bark_color: vec4<f32>,
    // Where the bark turns (local metres), with `bark_by_height`.
    bark_heights: vec2<f32>,
    perceptual_roughness: f32,
    reflectance: f32,
    // 1: the surface is bark, coloured by height.
    bark_by_height: u32,
}

// One placed shoot (`model::color::ShootColor`, local metres).
struct Shoot {
    // Linear RGB of its needles seen from above.
    age_color: vec4<f32>,
    // Where the viewer's direction is taken from.
    center: vec4<f32>,
    // Its upper side (length: how consistently its needles face one way).
    upper: vec4<f32>,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> surface: ReferenceSurface;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> shoots: array<Shoot>;

struct Vertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
#ifdef REFERENCE_SHOOTS
    @location(2) shoot: u32,
#endif
}

struct VertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) @interpolate(perspective, centroid) world_position: vec4<f32>,
    @location(1) @interpolate(perspective, centroid) world_normal: vec3<f32>,
    @location(2) @interpolate(flat) instance_index: u32,
    @location(3) @interpolate(flat) albedo: vec3<f32>,
    @location(4) @interpolate(perspective, centroid) local_height: f32,
}

// The needles of `shoot` seen from the view (`model::color::ShootColor::seen_from`).
fn shoot_albedo(shoot: Shoot, world_from_local: mat4x4<f32>) -> vec3<f32> {
    return shoot_needle_color(
        shoot.age_color.rgb,
        surface.underside_color.rgb,
        shoot.upper.xyz,
        shoot.center.xyz,
        world_from_local,
        view.world_position,
    );
}

// Bark at local `height` (`model::color::bark_color`).
fn bark_albedo(height: f32) -> vec3<f32> {
    return bark_between(surface.base_color.rgb, surface.upper_bark_color.rgb, surface.bark_heights, height);
}

@vertex
fn vertex(vertex: Vertex) -> VertexOutput {
    var out: VertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(vertex.instance_index);
    out.world_position = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(vertex.position, 1.0));
    out.position = position_world_to_clip(out.world_position.xyz);
    out.world_normal = mesh_functions::mesh_normal_local_to_world(vertex.normal, vertex.instance_index);
    out.instance_index = vertex.instance_index;
    out.local_height = vertex.position.y;
    out.albedo = surface.base_color.rgb;
#ifdef REFERENCE_SHOOTS
    out.albedo = shoot_albedo(shoots[vertex.shoot], world_from_local);
#endif
    return out;
}

@fragment
fn fragment(in: VertexOutput, @builtin(front_facing) is_front: bool) -> @location(0) vec4<f32> {
    var pbr_input = pbr_types::pbr_input_new();
    var albedo = in.albedo;
    if surface.bark_by_height != 0u {
        albedo = bark_albedo(in.local_height);
    }
    pbr_input.material.base_color = vec4<f32>(albedo, 1.0);
    pbr_input.material.perceptual_roughness = surface.perceptual_roughness;
    pbr_input.material.reflectance = vec3<f32>(surface.reflectance);
    pbr_input.material.flags = pbr_types::STANDARD_MATERIAL_FLAGS_FOG_ENABLED_BIT
        | pbr_types::STANDARD_MATERIAL_FLAGS_ALPHA_MODE_OPAQUE;
    pbr_input.flags = mesh[in.instance_index].flags;
    pbr_input.is_orthographic = view.clip_from_view[3].w == 1.0;
    pbr_input.V = pbr_functions::calculate_view(in.world_position, pbr_input.is_orthographic);
    pbr_input.frag_coord = in.position;
    pbr_input.world_position = in.world_position;
    pbr_input.world_normal = pbr_functions::prepare_world_normal(in.world_normal, false, is_front);
    pbr_input.N = normalize(pbr_input.world_normal);
    var color = pbr_functions::apply_pbr_lighting(pbr_input);
    return pbr_functions::main_pass_post_lighting_processing(pbr_input, color);
}
