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

#import bevy_pbr::{
    mesh_bindings::mesh,
    mesh_functions,
    mesh_view_bindings::view,
    view_transformations::position_world_to_clip,
    pbr_types,
    pbr_functions,
}

struct ReferenceSurface {
    // Linear RGBA.
    base_color: vec4<f32>,
    perceptual_roughness: f32,
    reflectance: f32,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> surface: ReferenceSurface;

struct Vertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
}

struct VertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) @interpolate(perspective, centroid) world_position: vec4<f32>,
    @location(1) @interpolate(perspective, centroid) world_normal: vec3<f32>,
    @location(2) @interpolate(flat) instance_index: u32,
}

@vertex
fn vertex(vertex: Vertex) -> VertexOutput {
    var out: VertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(vertex.instance_index);
    out.world_position = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(vertex.position, 1.0));
    out.position = position_world_to_clip(out.world_position.xyz);
    out.world_normal = mesh_functions::mesh_normal_local_to_world(vertex.normal, vertex.instance_index);
    out.instance_index = vertex.instance_index;
    return out;
}

@fragment
fn fragment(in: VertexOutput, @builtin(front_facing) is_front: bool) -> @location(0) vec4<f32> {
    var pbr_input = pbr_types::pbr_input_new();
    pbr_input.material.base_color = surface.base_color;
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
