//! `conifer render`: a record drawn through the Bevy plugin, headless.

use crate::model::read_record;
use crate::plugin::headless::HeadlessRenderer;
use crate::plugin::{ConiferFoliage, ConiferLodSettings, ConiferSpecies, LineOpacity};
use anyhow::Context;
use bevy::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `conifer render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// The record.
    pub file: PathBuf,
    /// The picture.
    #[command(flatten)]
    pub picture: super::PictureArgs,
    /// Colour needles by representation (prisms blue, original lines green, merged lines yellow-red).
    #[arg(long)]
    pub overlay: bool,
    /// Use the paper's line opacity (2/ρ) instead of the area-preserving default.
    #[arg(long)]
    pub paper: bool,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// Frames allowed for the record to load and the screenshot to arrive.
const MAX_FRAMES: u32 = 600;

pub(super) fn render(args: &RenderArgs) -> anyhow::Result<()> {
    let picture = &args.picture;
    let (width, height, view) = super::commands::picture_view(picture)?;
    let record = read_record(&args.file).with_context(|| format!("{}: cannot load record", args.file.display()))?;
    let file = std::fs::canonicalize(&args.file)?;
    let root = file
        .parent()
        .map(|p| p.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();

    let mut renderer = HeadlessRenderer::new(&root);
    let crown = record.crown_center();
    {
        let world = renderer.world_mut();
        *world.resource_mut::<ConiferLodSettings>() = ConiferLodSettings {
            pixel_error: picture.pixel_error,
            transition: picture.transition,
            line_opacity: if args.paper {
                LineOpacity::Paper
            } else {
                LineOpacity::AreaPreserving
            },
            enabled: true,
            debug_colors: args.overlay,
            ..ConiferLodSettings::default()
        };
    }
    let target = renderer.render_target(width, height);
    let handle: Handle<ConiferSpecies> = renderer.world().resource::<AssetServer>().load(name);
    let eye = crown + Vec3::Z * picture.distance.max(1e-3);
    renderer.world_mut().spawn((
        HeadlessRenderer::camera_bundle(
            &target,
            Transform::from_translation(eye).looking_at(crown, Vec3::Y),
            picture.fov_deg.to_radians(),
        ),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::srgb(0.92, 0.93, 0.95)),
            ..default()
        },
    ));
    HeadlessRenderer::spawn_lights(renderer.world_mut());
    renderer
        .world_mut()
        .spawn((ConiferFoliage(handle.clone()), Transform::IDENTITY));

    renderer
        .load(&[handle.clone().untyped()], MAX_FRAMES)
        .with_context(|| format!("{}: cannot load the record", args.file.display()))?;
    // Time steady frames.
    let mut frame_ms = Vec::new();
    for _ in 0..3 {
        let started = Instant::now();
        renderer.update()?;
        frame_ms.push(started.elapsed().as_secs_f64() * 1e3);
    }
    frame_ms.sort_by(f64::total_cmp);
    let image = renderer.capture(&target, 10)?;
    image
        .save(&args.output)
        .with_context(|| format!("{}: cannot write PNG", args.output.display()))?;

    let e = super::commands::view_params(&view).spatial_error(picture.distance);
    let stats = record.cut_stats(&record.cut(e));
    println!(
        "{}",
        serde_json::json!({
            "output": args.output,
            "distance": picture.distance,
            "spatial_error": e,
            "prisms": stats.prisms,
            "lines_original": stats.lines_original,
            "lines_merged": stats.lines_merged,
            "triangles": stats.triangles,
            "lines": stats.line_segments,
            "render_ms": frame_ms[1],
        })
    );
    Ok(())
}
