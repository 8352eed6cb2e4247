//! The foliage material: Bevy's `StandardMaterial` (lighting, shadows, fog)
//! extended with the LOD vertex shader `conifer_lod.wgsl`, and for the
//! translucent lines' shadows the hashed alpha test of
//! `conifer_line_shadow.wgsl`.

use bevy::asset::{embedded_asset, embedded_path};
use bevy::mesh::{MeshVertexAttribute, MeshVertexBufferLayoutRef};
use bevy::pbr::{
    ExtendedMaterial, MaterialExtension, MaterialExtensionKey, MaterialExtensionPipeline, StandardMaterial,
};
use bevy::prelude::*;
use bevy::render::render_resource::{
    AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError, VertexFormat,
};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::{ShaderDefVal, ShaderRef};

/// Per-vertex code of the prism mesh (needle index, ring slot, end, cap);
/// see [`crate::model::gpu_layout`].
pub const ATTRIBUTE_PRISM_CODE: MeshVertexAttribute =
    MeshVertexAttribute::new("ConiferPrismCode", 0x5c0f_1e70_0001, VertexFormat::Uint32);

/// Per-vertex `[error, parent_error, width, kind]` of the line mesh.
pub const ATTRIBUTE_LINE_LOD: MeshVertexAttribute =
    MeshVertexAttribute::new("ConiferLineLod", 0x5c0f_1e70_0002, VertexFormat::Float32x4);

/// The material of a species' needles: PBR shading from the base
/// `StandardMaterial`, LOD selection from [`ConiferLodExtension`].
pub type ConiferMaterial = ExtendedMaterial<StandardMaterial, ConiferLodExtension>;

/// The uniform block of [`ConiferLodExtension`] (`ConiferLod` in the shader).
#[derive(Clone, Copy, Debug, PartialEq, ShaderType)]
pub struct ConiferLodUniform {
    /// Tree-local centre of the crown; the distance `D` is measured to it.
    pub center: Vec4,
    /// Pixel error ε.
    pub pixel_error: f32,
    /// Transition coefficient δ.
    pub transition: f32,
    /// `Lmax` of the record.
    pub max_sides: u32,
    /// 0: the paper's `2/ρ`; 1: area-preserving.
    pub opacity_rule: u32,
    /// 0: LOD off (all prisms of `Lmax` sides).
    pub lod_enabled: u32,
    /// 1: colour by representation.
    pub debug_colors: u32,
    /// Deepest merge level of the record's lines (for debug colours).
    pub max_merge_depth: u32,
    /// Padding to 16 bytes.
    pub padding_b: u32,
    /// Wood colour over needle colour (the vertex colour of wood lines).
    pub wood_tint: Vec4,
}

/// The LOD part of [`ConiferMaterial`]: the uniform block and the needles'
/// storage buffer (three `vec4` per needle, read by the prism mesh).
#[derive(Asset, AsBindGroup, Reflect, Debug, Clone)]
#[reflect(opaque)]
pub struct ConiferLodExtension {
    /// LOD parameters.
    #[uniform(100)]
    pub lod: ConiferLodUniform,
    /// The species' needles (`gpu_layout::PrismBuffers::needles`).
    #[storage(101, read_only)]
    pub needles: Handle<ShaderBuffer>,
}

impl MaterialExtension for ConiferLodExtension {
    fn vertex_shader() -> ShaderRef {
        ShaderRef::Path(shader_path())
    }

    fn prepass_vertex_shader() -> ShaderRef {
        ShaderRef::Path(shader_path())
    }

    /// Lines (blended) reach depth passes only as shadow casters; there each
    /// fragment is kept with the line's opacity, so a line casts the shadow
    /// of the coverage it draws. Prisms are opaque and run no fragment
    /// shader in depth passes.
    fn prepass_fragment_shader() -> ShaderRef {
        ShaderRef::Path(line_shadow_shader_path())
    }

    fn specialize(
        _pipeline: &MaterialExtensionPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        layout: &MeshVertexBufferLayoutRef,
        _key: MaterialExtensionKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        let prepass = descriptor
            .vertex
            .shader_defs
            .iter()
            .any(|d| matches!(d, ShaderDefVal::Bool(name, true) if name == "PREPASS_PIPELINE"));
        let (attributes, mesh_def) = if layout.0.contains(ATTRIBUTE_PRISM_CODE) {
            (vec![ATTRIBUTE_PRISM_CODE.at_shader_location(0)], "CONIFER_PRISMS")
        } else {
            (
                vec![
                    Mesh::ATTRIBUTE_POSITION.at_shader_location(0),
                    Mesh::ATTRIBUTE_NORMAL.at_shader_location(1),
                    ATTRIBUTE_LINE_LOD.at_shader_location(2),
                ],
                "CONIFER_LINES",
            )
        };
        descriptor.vertex.buffers = vec![layout.0.get_layout(&attributes)?];
        let mut defs: Vec<ShaderDefVal> = vec![mesh_def.into()];
        if !prepass || mesh_def == "CONIFER_LINES" {
            // Opacity and debug colours travel as the vertex colour the
            // StandardMaterial fragment shader multiplies in; in depth
            // passes, a line's opacity and hash seeds for the alpha test.
            defs.push("VERTEX_COLORS".into());
        }
        descriptor.vertex.shader_defs.extend(defs.iter().cloned());
        if let Some(fragment) = descriptor.fragment.as_mut() {
            fragment.shader_defs.extend(defs);
        }
        Ok(())
    }
}

fn shader_path() -> bevy::asset::AssetPath<'static> {
    let path = embedded_path!("conifer_lod.wgsl");
    bevy::asset::AssetPath::from_path_buf(path).with_source("embedded")
}

fn line_shadow_shader_path() -> bevy::asset::AssetPath<'static> {
    let path = embedded_path!("conifer_line_shadow.wgsl");
    bevy::asset::AssetPath::from_path_buf(path).with_source("embedded")
}

/// Registers the embedded shaders and the material.
pub(super) fn build(app: &mut App) {
    embedded_asset!(app, "conifer_lod.wgsl");
    embedded_asset!(app, "conifer_line_shadow.wgsl");
    app.add_plugins(MaterialPlugin::<ConiferMaterial>::default());
}
