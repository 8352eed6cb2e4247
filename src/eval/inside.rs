//! `conifer eval --inside`: view-dependent detail measured where it
//! matters, with the camera in a tall crown (2 m from the trunk at 40 % of
//! the tree's height, looking at the trunk across the crown).
//!
//! The tree is drawn as its shared prototypes (the layout that carries
//! per-placement errors) twice: with one error for the tree (the paper's,
//! from the crown centre: [`ErrorScope::Tree`]) and with each placement's
//! own ([`ErrorScope::Placement`], [`crate::model::view`]); both against
//! the supersampled reference of every needle as a prism, with the same
//! measures as the distances of `conifer eval`, and the primitives of each
//! cut counted on the CPU ([`PrototypeRecord::cut_seen_from`],
//! [`PrototypeRecord::cut`]), which the GPU draws equal (tests
//! `render_prototypes`).

use super::measure::{self, PixelRect};
use super::reference::{ReferenceMaterialPlugin, reference_shoots, spawn_reference_tree};
use super::scene::{EvalError, EvalView, resolve_reference, wood_counts, wood_counts_by};
use super::tonemap::ToneMap;
use super::{EvaluateError, flip_error};
use crate::model::{Cut, LodRecord, PrototypeRecord, Sphere, ViewPoint};
use crate::plugin::headless::HeadlessRenderer;
use crate::plugin::{ConiferFoliage, ConiferLodSettings, ConiferSpecies, ErrorScope};
use bevy::camera::visibility::RenderLayers;
use bevy::prelude::*;
use serde::Serialize;
use std::path::PathBuf;

/// Where the camera stands.
#[derive(Clone, Debug)]
pub struct InsideOptions {
    /// The picture (size, field of view, ε, δ, supersampling, sun).
    pub view: EvalView,
    /// Metres from the trunk's axis.
    pub from_trunk: f32,
    /// Height of the camera as a fraction of the tree's.
    pub height_fraction: f32,
    /// Where the pictures go (`None`: nothing written).
    pub out_dir: Option<PathBuf>,
}

impl InsideOptions {
    /// 2 m from the trunk at 40 % of the height.
    pub fn new(view: EvalView) -> Self {
        Self {
            view,
            from_trunk: 2.0,
            height_fraction: 0.4,
            out_dir: None,
        }
    }
}

/// One way of choosing the errors, from inside the crown.
#[derive(Clone, Debug, Serialize)]
pub struct InsideMethod {
    /// `"tree"` (one error, the paper's) or `"placement"` (each its own).
    pub error_scope: &'static str,
    /// Mean absolute coverage difference from the reference over the picture, in [0, 1].
    pub coverage_error: f64,
    /// Mean absolute RGB difference over the picture, 0–255.
    pub color_error: f64,
    /// Mean FLIP error over the picture, in [0, 1].
    pub perceptual: f64,
    /// Needles drawn as prisms.
    pub prisms: u64,
    /// Original lines drawn.
    pub original_lines: u64,
    /// Merged lines drawn.
    pub merged_lines: u64,
    /// Triangles (needles and wood).
    pub triangles: u64,
    /// Lines (needles and wood).
    pub lines: u64,
    /// Triangles plus lines.
    pub primitives: u64,
    /// Needles within 1 m of the camera drawn with fewer sides than `Lmax`
    /// or as lines.
    pub coarse_near_needles: u64,
}

/// What `conifer eval --inside` measured.
#[derive(Clone, Debug, Serialize)]
pub struct InsideReport {
    /// The tree's height, metres.
    pub tree_height: f32,
    /// Needles of the record.
    pub needles: u64,
    /// Camera position, tree metres.
    pub camera: [f32; 3],
    /// Where it looks.
    pub target: [f32; 3],
    /// Picture size.
    pub width: u32,
    /// Picture size.
    pub height: u32,
    /// Vertical field of view, degrees.
    pub fov_deg: f32,
    /// Reference samples per pixel along each axis.
    pub supersampling: u32,
    /// Triangles of the reference (every needle an `Lmax`-sided prism, wood cones).
    pub reference_triangles: u64,
    /// Needles within 1 m of the camera.
    pub near_needles: u64,
    /// One error for the tree, then one per placement.
    pub methods: Vec<InsideMethod>,
    /// Pictures written.
    pub files: Vec<PathBuf>,
}

/// Renders and measures `record` seen from inside its crown.
pub fn evaluate_inside(
    record: &PrototypeRecord,
    options: &InsideOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<InsideReport, EvaluateError> {
    let view = &options.view;
    if view.width == 0 || view.height == 0 {
        return Err(EvalError::EmptyPicture(view.width, view.height).into());
    }
    if let Some(dir) = &options.out_dir {
        std::fs::create_dir_all(dir).map_err(|e| EvaluateError::OutDir(dir.clone(), e))?;
    }
    let flat = record
        .flatten()
        .map_err(|e| EvalError::Species(crate::model::RecordError::from(e).into()))?;
    let (lo, hi) = flat.bounds();
    let crown = flat.crown_center();
    let tree_height = hi.y - lo.y;
    let y = lo.y + options.height_fraction.clamp(0.0, 1.0) * tree_height;
    let target = Vec3::new(crown.x, y, crown.z);
    let camera = target + Vec3::X * options.from_trunk;

    progress("building the scene (placed species, raw reference)");
    let species = ConiferSpecies::from_prototype_record(record).map_err(EvalError::from)?;
    let shoots = reference_shoots(&species);
    let mut renderer = HeadlessRenderer::with_setup(".", |app| {
        app.add_plugins(ReferenceMaterialPlugin);
    });
    *renderer.world_mut().resource_mut::<ConiferLodSettings>() = ConiferLodSettings {
        pixel_error: view.pixel_error,
        transition: view.transition,
        line_lighting: view.line_lighting,
        line_raster: view.line_raster,
        wood_line_order: view.wood_line_order,
        line_order: view.line_order,
        ..ConiferLodSettings::default()
    };
    let world = renderer.world_mut();
    let sun = HeadlessRenderer::spawn_lights(world);
    world
        .entity_mut(sun)
        .insert((RenderLayers::from_layers(&[0, 1]), view.sun.transform()));
    view.lights.apply(world, sun);
    let handle = world.resource_mut::<Assets<ConiferSpecies>>().add(species);
    world.spawn((ConiferFoliage(handle), Transform::IDENTITY, RenderLayers::layer(0)));
    let [needle_triangles, wood_triangles] =
        spawn_reference_tree(world, &flat, shoots.as_deref(), RenderLayers::layer(1));
    let reference_triangles = needle_triangles + wood_triangles;
    let transform = Transform::from_translation(camera).looking_at(target, Vec3::Y);
    let s = view.supersampling.max(1);
    let mut targets = Vec::new();
    for (layer, scale, order) in [(0usize, 1u32, 0isize), (1, s, 1)] {
        let format = if layer == 1 {
            bevy::render::render_resource::TextureFormat::Rgba8UnormSrgb
        } else {
            view.methods_target_format()
        };
        let image = renderer.render_target_with_format(view.width * scale, view.height * scale, format);
        let [r, g, b] = super::scene::BACKGROUND;
        let mut camera = renderer.world_mut().spawn((
            HeadlessRenderer::camera_bundle(&image, transform, view.fov_deg.to_radians()),
            Camera {
                clear_color: ClearColorConfig::Custom(Color::srgba(r, g, b, 0.0)),
                order,
                ..default()
            },
            RenderLayers::layer(layer),
        ));
        if layer == 1 {
            view.configure_reference_camera(&mut camera);
        } else {
            view.configure_camera(&mut camera);
        }
        targets.push(image);
    }
    let reference_tone = if view.reference_tone_maps_on_cpu() {
        Some(ToneMap::from_world(renderer.world_mut()).ok_or(EvalError::NoToneMapLut)?)
    } else {
        None
    };
    for _ in 0..3 {
        renderer.update().map_err(EvalError::from)?;
    }

    let slope = view.params().error_per_distance();
    let seen_from = ViewPoint::new(camera, slope);
    let near = |i: u32| {
        let n = &flat.needles[i as usize];
        n.base.distance(camera).min(n.tip.distance(camera)) < 1.0
    };
    let near_needles = (0..flat.needle_count() as u32).filter(|&i| near(i)).count() as u64;
    let rect = PixelRect::full(view.width, view.height);
    let mut files = Vec::new();
    let write = |image: &image::RgbaImage, name: &str, files: &mut Vec<PathBuf>| -> Result<(), EvaluateError> {
        if let Some(dir) = &options.out_dir {
            let path = dir.join(name);
            image.save(&path).map_err(|e| EvaluateError::Write(path.clone(), e))?;
            files.push(path);
        }
        Ok(())
    };
    let mut methods = Vec::new();
    for scope in [ErrorScope::Tree, ErrorScope::Placement] {
        let name = match scope {
            ErrorScope::Tree => "tree",
            ErrorScope::Placement => "placement",
        };
        progress(&format!("one error per {name}"));
        renderer.world_mut().resource_mut::<ConiferLodSettings>().error_scope = scope;
        renderer.update().map_err(EvalError::from)?;
        let mut images = renderer.capture_all(&targets, 10).map_err(EvalError::from)?;
        let reference = resolve_reference(&images.pop().expect("reference"), s, reference_tone.as_ref());
        let mut picture = images.pop().expect("picture");
        view.tone_map_methods(reference_tone.as_ref(), std::slice::from_mut(&mut picture));
        if methods.is_empty() {
            write(&reference, "ref_inside.png", &mut files)?;
        }
        write(&picture, &format!("ours-per-{name}_inside.png"), &mut files)?;
        let (cut, (wood_triangles, wood_lines)) = match scope {
            ErrorScope::Tree => {
                let e = slope * camera.distance(crown);
                (record.cut(e), wood_counts(&flat, e))
            }
            ErrorScope::Placement => (
                record.cut_seen_from(&seen_from),
                wood_counts_seen_from(&flat, &seen_from),
            ),
        };
        let stats = flat.cut_stats(&cut);
        let lines = stats.lines_original + stats.lines_merged + wood_lines;
        let triangles = stats.triangles + wood_triangles;
        methods.push(InsideMethod {
            error_scope: name,
            coverage_error: measure::coverage_error(&reference, &picture, &rect)?,
            color_error: measure::color_error(&reference, &picture, &rect)?,
            perceptual: flip_error(&reference, &picture, &rect)?,
            prisms: stats.prisms,
            original_lines: stats.lines_original,
            merged_lines: stats.lines_merged,
            triangles,
            lines,
            primitives: triangles + lines,
            coarse_near_needles: coarse_near(&cut, flat.max_sides, near),
        });
    }
    Ok(InsideReport {
        tree_height,
        needles: flat.needle_count() as u64,
        camera: camera.to_array(),
        target: target.to_array(),
        width: view.width,
        height: view.height,
        fov_deg: view.fov_deg,
        supersampling: s,
        reference_triangles,
        near_needles,
        methods,
        files,
    })
}

/// Near needles (by `near`) drawn coarser than full prisms: as lines or
/// with fewer than `max_sides` sides.
fn coarse_near(cut: &Cut, max_sides: u8, near: impl Fn(u32) -> bool) -> u64 {
    let thin_prisms = cut.prisms.iter().filter(|p| p.1 < max_sides && near(p.0)).count();
    let lines = cut.original_lines.iter().filter(|&&i| near(i)).count();
    (thin_prisms + lines) as u64
}

/// Wood triangles and lines the plugin draws seen from `view`: each segment
/// at its own sphere's error (as `conifer_compact.wgsl` does), for a camera
/// within range of the tree (the trees `conifer eval --inside` looks at).
pub fn wood_counts_seen_from(record: &LodRecord, view: &ViewPoint) -> (u64, u64) {
    wood_counts_by(record, |segment| view.spatial_error(&Sphere::around_wood(segment)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wood_seen_from_afar_counts_as_at_one_error() {
        // Far away every segment's sphere is about as far as the tree: the
        // counts approach those at the tree's one error.
        let tree = crate::generate::generate(
            crate::generate::Species::ScotsPine,
            &crate::generate::GenerateOptions {
                seed: 1,
                target_needles: Some(2000),
                age: crate::generate::Age::Young,
            },
        );
        let record = crate::model::bake(&tree, &crate::model::BakeOptions::default(), &()).unwrap();
        let camera = record.crown_center() + Vec3::Z * 1e4;
        let slope = 1e-6;
        let seen = wood_counts_seen_from(&record, &ViewPoint::new(camera, slope));
        let one = wood_counts(&record, slope * 1e4);
        assert_eq!(seen, one);
        // Beside the trunk, the near segments are prisms of full sides.
        let near = ViewPoint::new(record.crown_center(), 1e-3);
        let (triangles, _) = wood_counts_seen_from(&record, &near);
        assert!(triangles > 0);
    }
}
