//! `conifer render`: a record drawn through the Bevy plugin, headless.

use crate::model::read_record;
use crate::plugin::headless::HeadlessRenderer;
use crate::plugin::{ConiferFoliage, ConiferLodSettings, ConiferSpecies, ConiferWind, LineOpacity};
use anyhow::Context;
use bevy::prelude::*;
use image::RgbaImage;
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
    /// Wind strength (0 calm, 1 a light breeze, 3 strong), blowing to the
    /// right of the picture.
    #[arg(long, default_value_t = 0.0)]
    pub wind: f32,
    /// Frames to render: more than one writes an animated PNG of the wind
    /// (`--fps` frames a second of the wind's clock).
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Frames a second of the animation.
    #[arg(long, default_value_t = 12.0)]
    pub fps: f32,
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
    let frames = args.frames.max(1);
    let fps = if args.fps > 0.0 && args.fps.is_finite() {
        args.fps
    } else {
        12.0
    };
    let mut pictures = Vec::with_capacity(frames as usize);
    for k in 0..frames {
        if args.wind > 0.0 {
            renderer.world_mut().insert_resource(ConiferWind {
                direction: Vec2::X,
                strength: args.wind,
                time: Some(f64::from(k) / f64::from(fps)),
                ..ConiferWind::default()
            });
        }
        pictures.push(renderer.capture(&target, 10)?);
    }
    if frames == 1 {
        pictures[0]
            .save(&args.output)
            .with_context(|| format!("{}: cannot write PNG", args.output.display()))?;
    } else {
        write_apng(&args.output, &pictures, (1000.0 / fps).round() as u16)
            .with_context(|| format!("{}: cannot write animated PNG", args.output.display()))?;
    }

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
            "wind": args.wind,
            "frames": frames,
        })
    );
    Ok(())
}

/// Writes `frames` (all of one size, at least one) to `path` as an
/// animated PNG that loops forever, each frame shown `delay_ms`
/// milliseconds. Browsers (and GitHub's README view) play it; viewers
/// without APNG show the first frame.
pub(super) fn write_apng(path: &std::path::Path, frames: &[RgbaImage], delay_ms: u16) -> anyhow::Result<()> {
    let first = frames.first().ok_or_else(|| anyhow::anyhow!("no frames"))?;
    let (width, height) = first.dimensions();
    if frames.iter().any(|f| f.dimensions() != (width, height)) {
        anyhow::bail!("frames of different sizes");
    }
    let write_error = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e}", path.display());
    let file = std::fs::File::create(path).map_err(|e| write_error(&e))?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    encoder
        .set_animated(frames.len() as u32, 0)
        .map_err(|e| write_error(&e))?;
    encoder.set_frame_delay(delay_ms, 1000).map_err(|e| write_error(&e))?;
    let mut writer = encoder.write_header().map_err(|e| write_error(&e))?;
    for frame in frames {
        writer.write_image_data(frame.as_raw()).map_err(|e| write_error(&e))?;
    }
    writer.finish().map_err(|e| write_error(&e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_animated_png_holds_every_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("anim.png");
        let frames: Vec<RgbaImage> = (0..5u8)
            .map(|k| RgbaImage::from_pixel(6, 4, image::Rgba([k * 40, 10, 200, 255])))
            .collect();
        write_apng(&path, &frames, 80).unwrap();
        let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let control = reader.info().animation_control.unwrap();
        assert_eq!((control.num_frames, control.num_plays), (5, 0));
        let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
        for k in 0..5u8 {
            reader.next_frame(&mut buffer).unwrap();
            assert_eq!(&buffer[..4], &[k * 40, 10, 200, 255]);
            let delay = reader.info().frame_control.unwrap();
            assert_eq!((delay.delay_num, delay.delay_den), (80, 1000));
        }
        assert!(write_apng(&path, &[], 80).is_err());
        let mixed = [RgbaImage::new(2, 2), RgbaImage::new(3, 2)];
        assert!(write_apng(&path, &mixed, 80).is_err());
        // The first frame is also what a plain PNG reader sees.
        assert_eq!(
            image::open(&path).unwrap().to_rgba8().get_pixel(0, 0).0,
            [0, 10, 200, 255]
        );
    }
}
