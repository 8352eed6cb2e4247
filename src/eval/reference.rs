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

use bevy::asset::{embedded_asset, embedded_path};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, ShaderType};
use bevy::shader::ShaderRef;

use crate::model::record::LodRecord;

/// What the reference's shader reads: a plain opaque surface as
/// `StandardMaterial` describes it.
#[derive(ShaderType, Clone, Copy, Debug, PartialEq)]
pub struct ReferenceSurface {
    /// Linear RGBA.
    pub base_color: Vec4,
    /// As `StandardMaterial::perceptual_roughness`.
    pub perceptual_roughness: f32,
    /// As `StandardMaterial::reflectance`.
    pub reflectance: f32,
}

/// A mesh lit by Bevy's PBR functions as a `StandardMaterial` with only a
/// colour, roughness and reflectance would be, with position and normal
/// interpolated at the centroid of each pixel's covered samples (see the
/// module's docs).
#[derive(Asset, AsBindGroup, TypePath, Clone, Debug)]
pub struct ReferenceMaterial {
    /// The surface.
    #[uniform(0)]
    pub surface: ReferenceSurface,
}

impl ReferenceMaterial {
    /// The material a `StandardMaterial` of `base_color`, `perceptual_roughness`
    /// and `reflectance` (its other fields default) describes.
    pub fn new(base_color: LinearRgba, perceptual_roughness: f32, reflectance: f32) -> Self {
        Self {
            surface: ReferenceSurface {
                base_color: base_color.to_vec4(),
                perceptual_roughness,
                reflectance,
            },
        }
    }
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
}

/// Registers [`ReferenceMaterial`] and its shader.
pub struct ReferenceMaterialPlugin;

impl Plugin for ReferenceMaterialPlugin {
    fn build(&self, app: &mut App) {
        embedded_asset!(app, "reference.wgsl");
        app.add_plugins(MaterialPlugin::<ReferenceMaterial>::default());
    }
}

/// The reference's materials of `record`'s needles and wood, of the
/// surfaces the raw tree has ([`super::scene::raw_surfaces`]).
pub fn reference_materials(
    world: &mut World,
    record: &LodRecord,
) -> (Handle<ReferenceMaterial>, Handle<ReferenceMaterial>) {
    let mut materials = world.resource_mut::<Assets<ReferenceMaterial>>();
    let [needles, wood] =
        super::scene::raw_surfaces(record).map(|surface| materials.add(ReferenceMaterial { surface }));
    (needles, wood)
}
