//! The reference's material ([`ReferenceMaterial`]): the raw tree lit as a
//! `StandardMaterial` of the record's colours lights it, with every
//! sample's normal taken on the surface it covers.
//!
//! The reference draws needles a tenth of a sample wide and more. With
//! MSAA, Bevy's mesh shader runs once a pixel per triangle at the pixel's
//! centre, wherever the triangle covers a sample: the normal is
//! extrapolated tens of times past the needle's ring, where it points
//! sideways, toward the silhouette. Under a light from behind the tree a
//! sideways normal is the lit rim's, so the `StandardMaterial` reference
//! shone about twice as bright as its own needles shaded where they are
//! (the Scots pine from behind, 12 m, 160 px: its crown's own colour 111
//! against 65 with centroid shading or with no MSAA at 8×8 samples). The
//! reference's shader (`reference.wgsl`) interpolates at the centroid of the
//! covered samples, which lies in the triangle.
//!
//! The reference takes the tree's colours as the plugin gives them
//! ([`crate::model::color`]): each needle its shoot's, by the shoot's age
//! and by how much of its underside the viewer sees, and the bark its
//! height's ([`reference_shoots`], [`spawn_reference_tree`]). It had one
//! needle colour and one bark colour, which a tree drawn by its placements
//! (the mature records, as a game loads them) does not have.

use bevy::asset::{embedded_asset, embedded_path};
use bevy::camera::visibility::RenderLayers;
use bevy::mesh::{MeshVertexAttribute, MeshVertexBufferLayoutRef};
use bevy::pbr::{MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{
    AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError, VertexFormat,
};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::ShaderRef;

use crate::model::color::ShootColor;
use crate::model::record::LodRecord;
use crate::plugin::triangle_mesh;

/// Each reference needle vertex's shoot: an index into its material's
/// [`ReferenceMaterial::shoots`] (a flattened tree's needle group, which is
/// its placement).
pub const ATTRIBUTE_SHOOT: MeshVertexAttribute =
    MeshVertexAttribute::new("ConiferReferenceShoot", 3_187_404_551, VertexFormat::Uint32);

/// What the reference's shader reads: an opaque surface as
/// `StandardMaterial` describes it (colour, roughness, reflectance), with
/// the tree's colour rules.
#[derive(ShaderType, Clone, Copy, Debug, PartialEq)]
pub struct ReferenceSurface {
    /// Linear RGBA: the needles' colour where their mesh has no shoots
    /// ([`ATTRIBUTE_SHOOT`]); the bark's below `bark_heights.x`.
    pub base_color: Vec4,
    /// Linear RGBA of needles seen from under their shoot
    /// ([`crate::model::FoliageMaterial::needle_underside_color`]).
    pub underside_color: Vec4,
    /// Linear RGBA of the bark above `bark_heights.y`
    /// ([`crate::model::FoliageMaterial::upper_wood_color`]).
    pub upper_bark_color: Vec4,
    /// Where the bark turns, local metres
    /// ([`crate::model::FoliageMaterial::upper_wood_heights`]).
    pub bark_heights: Vec2,
    /// As `StandardMaterial::perceptual_roughness`.
    pub perceptual_roughness: f32,
    /// As `StandardMaterial::reflectance`.
    pub reflectance: f32,
    /// 1: bark, coloured by height ([`crate::model::color::bark_color`]);
    /// 0: one colour, or needles by shoot.
    pub bark_by_height: u32,
}

impl ReferenceSurface {
    /// A surface of one colour, as a `StandardMaterial` of `base_color`,
    /// `perceptual_roughness` and `reflectance` (its other fields default).
    pub fn plain(base_color: Vec4, perceptual_roughness: f32, reflectance: f32) -> Self {
        Self {
            base_color,
            underside_color: base_color,
            upper_bark_color: base_color,
            bark_heights: Vec2::ZERO,
            perceptual_roughness,
            reflectance,
            bark_by_height: 0,
        }
    }
}

/// One shoot as the reference's shader reads it
/// ([`crate::model::color::ShootColor`]).
#[derive(ShaderType, Clone, Copy, Debug, PartialEq)]
pub struct GpuShoot {
    /// Linear RGB of its needles seen from above (w 1).
    pub age_color: Vec4,
    /// Where the viewer's direction is taken from, local metres (w 1).
    pub center: Vec4,
    /// Its upper side, local (w 0).
    pub upper: Vec4,
}

impl From<&ShootColor> for GpuShoot {
    fn from(shoot: &ShootColor) -> Self {
        Self {
            age_color: shoot.age_color.extend(1.0),
            center: shoot.center.extend(1.0),
            upper: shoot.upper.extend(0.0),
        }
    }
}

/// A mesh lit by Bevy's PBR functions as a `StandardMaterial` with only a
/// colour, roughness and reflectance would be, with position and normal
/// interpolated at the centroid of each pixel's covered samples (see the
/// module's docs). A mesh with [`ATTRIBUTE_SHOOT`] takes each vertex's
/// colour from its shoot in [`Self::shoots`].
#[derive(Asset, AsBindGroup, TypePath, Clone, Debug)]
pub struct ReferenceMaterial {
    /// The surface.
    #[uniform(0)]
    pub surface: ReferenceSurface,
    /// The shoots ([`GpuShoot`], at least one) that [`ATTRIBUTE_SHOOT`]
    /// indexes.
    #[storage(1, read_only)]
    pub shoots: Handle<ShaderBuffer>,
}

impl ReferenceMaterial {
    /// The material a `StandardMaterial` of `base_color`, `perceptual_roughness`
    /// and `reflectance` (its other fields default) describes; its shoot
    /// buffer (one unused shoot) is added to `buffers`.
    pub fn new(
        buffers: &mut Assets<ShaderBuffer>,
        base_color: LinearRgba,
        perceptual_roughness: f32,
        reflectance: f32,
    ) -> Self {
        Self {
            surface: ReferenceSurface::plain(base_color.to_vec4(), perceptual_roughness, reflectance),
            shoots: buffers.add(shoot_buffer(&[])),
        }
    }
}

/// The storage buffer of `shoots` (one unused shoot where there are none:
/// a binding is never empty).
pub fn shoot_buffer(shoots: &[ShootColor]) -> ShaderBuffer {
    let mut gpu: Vec<GpuShoot> = shoots.iter().map(GpuShoot::from).collect();
    if gpu.is_empty() {
        gpu.push(GpuShoot {
            age_color: Vec4::ONE,
            center: Vec4::W,
            upper: Vec4::ZERO,
        });
    }
    ShaderBuffer::from(gpu)
}

fn shader() -> ShaderRef {
    ShaderRef::Path(bevy::asset::AssetPath::from_path_buf(embedded_path!("reference.wgsl")).with_source("embedded"))
}

impl Material for ReferenceMaterial {
    fn vertex_shader() -> ShaderRef {
        shader()
    }

    fn fragment_shader() -> ShaderRef {
        shader()
    }

    // The reference is drawn in scenes without shadow maps or prepasses;
    // its vertex layout (below) is the main pass's.
    fn enable_prepass() -> bool {
        false
    }

    fn enable_shadows() -> bool {
        false
    }

    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        layout: &MeshVertexBufferLayoutRef,
        _key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        let mut attributes = vec![
            Mesh::ATTRIBUTE_POSITION.at_shader_location(0),
            Mesh::ATTRIBUTE_NORMAL.at_shader_location(1),
        ];
        if layout.0.contains(ATTRIBUTE_SHOOT) {
            attributes.push(ATTRIBUTE_SHOOT.at_shader_location(2));
            descriptor.vertex.shader_defs.push("REFERENCE_SHOOTS".into());
            if let Some(fragment) = descriptor.fragment.as_mut() {
                fragment.shader_defs.push("REFERENCE_SHOOTS".into());
            }
        }
        descriptor.vertex.buffers = vec![layout.0.get_layout(&attributes)?];
        Ok(())
    }
}

/// Registers [`ReferenceMaterial`] and its shader.
pub struct ReferenceMaterialPlugin;

impl Plugin for ReferenceMaterialPlugin {
    fn build(&self, app: &mut App) {
        embedded_asset!(app, "reference.wgsl");
        app.add_plugins(MaterialPlugin::<ReferenceMaterial>::default());
    }
}

/// The shoots the reference colours `species`' needles by: its
/// placements' ([`crate::model::color::shoot_colors`]) where the plugin
/// draws the tree by its placements; `None` for a flat species, or a tree
/// of prototypes the compact layout fell back to drawing flat, whose
/// needles all take the needle colour.
pub fn reference_shoots(species: &crate::plugin::ConiferSpecies) -> Option<Vec<ShootColor>> {
    species
        .prototypes()
        .filter(|_| !species.compact.placements.is_empty())
        .map(|prototypes| crate::model::color::shoot_colors(prototypes))
}

/// Spawns the reference tree of `record` into `world` on `layers`: its
/// geometry ([`super::scene::RawTree::reference`]) with the reference's
/// materials of the surfaces the raw tree has
/// ([`super::scene::raw_surfaces`]); each needle coloured by its shoot
/// where `shoots` gives them (`shoots[needle.group]`: a flattened tree's
/// placements, [`crate::model::color::shoot_colors`]), else by the
/// record's needle colour; bark by height. Returns the triangles drawn,
/// needles' and wood's.
pub fn spawn_reference_tree(
    world: &mut World,
    record: &LodRecord,
    shoots: Option<&[ShootColor]>,
    layers: RenderLayers,
) -> [u64; 2] {
    let (reference, groups) = super::scene::RawTree::reference(record);
    let triangles = [
        reference.needles.triangle_count() as u64,
        reference.wood.triangle_count() as u64,
    ];
    let [needle_surface, wood_surface] = super::scene::raw_surfaces(record);
    let (mut needle_mesh, wood_mesh) = (triangle_mesh(&reference.needles), triangle_mesh(&reference.wood));
    drop(reference);
    // Needle groups index the shoots only where there is one per group.
    let shoots = shoots.filter(|s| groups.iter().all(|&g| (g as usize) < s.len()));
    if shoots.is_some() {
        needle_mesh.insert_attribute(ATTRIBUTE_SHOOT, groups);
    }
    let mut buffers = world.resource_mut::<Assets<ShaderBuffer>>();
    let needle_shoots = buffers.add(shoot_buffer(shoots.unwrap_or(&[])));
    let no_shoots = buffers.add(shoot_buffer(&[]));
    let mut materials = world.resource_mut::<Assets<ReferenceMaterial>>();
    let needle_material = materials.add(ReferenceMaterial {
        surface: needle_surface,
        shoots: needle_shoots,
    });
    let wood_material = materials.add(ReferenceMaterial {
        surface: wood_surface,
        shoots: no_shoots,
    });
    let mut meshes = world.resource_mut::<Assets<Mesh>>();
    let (needle_mesh, wood_mesh) = (meshes.add(needle_mesh), meshes.add(wood_mesh));
    for (mesh, material) in [(needle_mesh, needle_material), (wood_mesh, wood_material)] {
        world.spawn((
            Mesh3d(mesh),
            MeshMaterial3d(material),
            Transform::IDENTITY,
            layers.clone(),
        ));
    }
    triangles
}
