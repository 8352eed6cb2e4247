//! Rendering without a window (software Vulkan is enough): the engine of
//! `conifer render`, the render tests and the README pictures.
//!
//! Follows Bevy's `externally_driven_headless_renderer` example: no winit,
//! no primary window, synchronous pipeline compilation, the update loop
//! pumped by hand with a blocking device poll after every frame, and
//! screenshots of an image render target read back into memory.

use super::{ConiferLodPlugin, ConiferWind};
use bevy::app::SubApps;
use bevy::asset::{LoadState, RenderAssetUsages};
use bevy::camera::RenderTarget;
use bevy::prelude::*;
use bevy::render::RenderPlugin;
use bevy::render::render_resource::{Extent3d, PollType, TextureDimension, TextureFormat, TextureUsages};
use bevy::render::renderer::RenderDevice;
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::window::ExitCondition;
use bevy::winit::WinitPlugin;
use std::sync::{Arc, Mutex};

/// Why a headless frame could not be captured.
#[derive(Debug, thiserror::Error)]
pub enum HeadlessError {
    /// The screenshot did not arrive within the frames allowed.
    #[error("no screenshot arrived after {0} frames")]
    NoScreenshot(u32),
    /// The captured image could not be converted.
    #[error("captured image is not RGBA8: {0}")]
    Format(String),
    /// The GPU device could not be polled.
    #[error("device poll failed: {0}")]
    Poll(String),
    /// An asset failed to load.
    #[error("{0}")]
    LoadFailed(String),
    /// The assets did not load within the frames allowed.
    #[error("assets did not load in {0} frames")]
    NotLoaded(u32),
    /// A render or compute pipeline failed to compile (a shader that does
    /// not parse or validate): the frames would be drawn without it, and
    /// every figure read from them would be wrong. Its label and Bevy's
    /// error.
    #[error("pipeline {0} failed: {1}")]
    Pipeline(String, String),
}

/// Screenshots asked for by [`HeadlessRenderer::request_screenshots`].
pub struct PendingScreenshots {
    slots: Vec<Arc<Mutex<Option<Image>>>>,
}

impl PendingScreenshots {
    /// The pictures, in the order of the targets, once all have arrived
    /// (`None` before).
    pub fn take(&self) -> Result<Option<Vec<image::RgbaImage>>, HeadlessError> {
        let ready = self
            .slots
            .iter()
            .all(|slot| slot.lock().unwrap_or_else(|e| e.into_inner()).is_some());
        if !ready {
            return Ok(None);
        }
        self.slots
            .iter()
            .map(|slot| {
                let image = slot
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .take()
                    .ok_or_else(|| HeadlessError::Format("screenshot taken twice".into()))?;
                if image.texture_descriptor.format == TextureFormat::Rgba32Float {
                    return float_screenshot_as_srgb(&image);
                }
                let dynamic = image
                    .try_into_dynamic()
                    .map_err(|e| HeadlessError::Format(e.to_string()))?;
                Ok(dynamic.to_rgba8())
            })
            .collect::<Result<Vec<_>, _>>()
            .map(Some)
    }
}

/// An `Rgba32Float` screenshot as 8-bit sRGB: each colour channel's linear
/// light clamped to [0, 1] and encoded, alpha scaled to 0–255.
fn float_screenshot_as_srgb(image: &Image) -> Result<image::RgbaImage, HeadlessError> {
    const TEXEL_BYTES: usize = 16;
    let (width, height) = (image.width(), image.height());
    let data = image.data.as_deref().unwrap_or_default();
    let texels = width as usize * height as usize;
    if data.len() != texels * TEXEL_BYTES {
        return Err(HeadlessError::Format(format!(
            "Rgba32Float screenshot of {width}x{height} holds {} bytes, not {}",
            data.len(),
            texels * TEXEL_BYTES
        )));
    }
    let mut picture = image::RgbaImage::new(width, height);
    for (pixel, texel) in picture.pixels_mut().zip(data.chunks_exact(TEXEL_BYTES)) {
        let channel =
            |k: usize| f32::from_le_bytes([texel[4 * k], texel[4 * k + 1], texel[4 * k + 2], texel[4 * k + 3]]);
        let alpha = channel(3);
        pixel.0 = [
            crate::preview::linear_to_srgb(channel(0)),
            crate::preview::linear_to_srgb(channel(1)),
            crate::preview::linear_to_srgb(channel(2)),
            if alpha >= 0.0 {
                (alpha.min(1.0) * 255.0).round() as u8
            } else {
                0
            },
        ];
    }
    Ok(picture)
}

/// The first pipeline (its label and Bevy's error) whose shader failed to
/// compile, shared by the render world, which finds it, and the renderer,
/// which reports it.
#[derive(Resource, Clone, Default)]
struct PipelineFailure(Arc<Mutex<Option<(String, String)>>>);

/// Looks through the render world's pipeline cache for a pipeline whose
/// shader failed to compile. Bevy logs such a failure and draws on
/// without the pipeline (a missing import in a WGSL file drops every draw
/// that uses it); a headless frame, whose pictures are measured, fails
/// instead. A shader not loaded yet is not a failure (Bevy retries it).
fn find_pipeline_failure(cache: Res<bevy::render::render_resource::PipelineCache>, failure: Res<PipelineFailure>) {
    use bevy::render::render_resource::{CachedPipelineState, PipelineDescriptor};
    use bevy::shader::ShaderCacheError;
    let mut found = failure.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if found.is_some() {
        return;
    }
    for pipeline in cache.pipelines() {
        let CachedPipelineState::Err(error) = &pipeline.state else {
            continue;
        };
        if matches!(
            error,
            ShaderCacheError::ShaderNotLoaded(_) | ShaderCacheError::ShaderImportNotYetAvailable
        ) {
            continue;
        }
        let label = match &pipeline.descriptor {
            PipelineDescriptor::RenderPipelineDescriptor(d) => d.label.clone(),
            PipelineDescriptor::ComputePipelineDescriptor(d) => d.label.clone(),
        };
        let label = label.map_or_else(|| "(unnamed)".to_string(), |l| l.to_string());
        *found = Some((label, error.to_string()));
        return;
    }
}

/// A Bevy app with the conifer plugin, rendering to images, driven by hand.
pub struct HeadlessRenderer {
    apps: SubApps,
}

impl HeadlessRenderer {
    /// Builds the app: Bevy's default plugins without winit or a window, the
    /// conifer plugin in calm ([`ConiferWind::CALM`]), assets read from
    /// `asset_root`.
    pub fn new(asset_root: &str) -> Self {
        Self::with_setup(asset_root, |_| {})
    }

    /// Like [`HeadlessRenderer::new`], with `setup` adding the caller's
    /// plugins, resources and systems (an example's scene) before the app is
    /// finished.
    pub fn with_setup(asset_root: &str, setup: impl FnOnce(&mut App)) -> Self {
        let mut app = App::new();
        // A second renderer in one process keeps the first one's logger.
        let logger_set = bevy::log::tracing::dispatcher::has_been_set();
        let mut plugins = DefaultPlugins.build();
        if logger_set {
            plugins = plugins.disable::<bevy::log::LogPlugin>();
        }
        app.add_plugins(
            plugins
                .set(WindowPlugin {
                    primary_window: None,
                    exit_condition: ExitCondition::DontExit,
                    ..default()
                })
                .set(RenderPlugin {
                    synchronous_pipeline_compilation: true,
                    ..default()
                })
                .set(AssetPlugin {
                    file_path: asset_root.to_string(),
                    ..default()
                })
                .disable::<WinitPlugin>(),
        )
        .add_plugins(ConiferLodPlugin::default())
        // Pictures repeat: calm, unless the caller's setup brings wind.
        .insert_resource(ConiferWind::CALM);
        setup(&mut app);
        let failure = PipelineFailure::default();
        app.insert_resource(failure.clone());
        if let Some(render) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render.insert_resource(failure).add_systems(
                bevy::render::Render,
                find_pipeline_failure.in_set(bevy::render::RenderSystems::Cleanup),
            );
        }
        app.finish();
        app.cleanup();
        Self {
            apps: std::mem::take(app.sub_apps_mut()),
        }
    }

    /// The main world, to spawn cameras, lights and trees.
    pub fn world_mut(&mut self) -> &mut World {
        self.apps.main.world_mut()
    }

    /// The main world.
    pub fn world(&self) -> &World {
        self.apps.main.world()
    }

    /// Renders frames until every asset of `handles` has loaded (at most
    /// `max_frames`), then [`HeadlessRenderer::SETTLE_FRAMES`] more, so that
    /// the trees' parts, meshes, buffers and pipelines reach the GPU before
    /// a capture.
    pub fn load(&mut self, handles: &[UntypedHandle], max_frames: u32) -> Result<(), HeadlessError> {
        for _ in 0..max_frames {
            self.update()?;
            let server = self.world().resource::<AssetServer>();
            let mut all_loaded = true;
            for handle in handles {
                match server.load_state(handle) {
                    LoadState::Loaded => {}
                    LoadState::Failed(error) => return Err(HeadlessError::LoadFailed(error.to_string())),
                    _ => all_loaded = false,
                }
            }
            if all_loaded {
                for _ in 0..Self::SETTLE_FRAMES {
                    self.update()?;
                }
                return Ok(());
            }
            // Loading runs on other threads: give them time.
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        Err(HeadlessError::NotLoaded(max_frames))
    }

    /// Frames run after loading before a picture is worth taking.
    pub const SETTLE_FRAMES: u32 = 3;

    /// A new sRGB image to render into.
    pub fn render_target(&mut self, width: u32, height: u32) -> Handle<Image> {
        self.render_target_with_format(width, height, TextureFormat::Rgba8UnormSrgb)
    }

    /// A new image of `format` to render into. Screenshots of an
    /// `Rgba32Float` one come back as 8-bit sRGB of the linear light it
    /// holds (clamped to [0, 1]), as an `Rgba8UnormSrgb` target's do.
    pub fn render_target_with_format(&mut self, width: u32, height: u32, format: TextureFormat) -> Handle<Image> {
        let mut image = Image::new_uninit(
            Extent3d {
                width: width.max(1),
                height: height.max(1),
                depth_or_array_layers: 1,
            },
            TextureDimension::D2,
            format,
            RenderAssetUsages::RENDER_WORLD,
        );
        image.texture_descriptor.usage |= TextureUsages::RENDER_ATTACHMENT;
        self.world_mut().resource_mut::<Assets<Image>>().add(image)
    }

    /// Runs one frame and waits for the GPU to finish it.
    pub fn update(&mut self) -> Result<(), HeadlessError> {
        self.apps.update();
        self.pipeline_failure()?;
        self.apps
            .main
            .world()
            .resource::<RenderDevice>()
            .wgpu_device()
            .poll(PollType::Wait {
                submission_index: None,
                timeout: None,
            })
            .map_err(|e| HeadlessError::Poll(e.to_string()))?;
        Ok(())
    }

    /// The first pipeline whose shader failed to compile, as an error
    /// ([`HeadlessError::Pipeline`], found by the render world's
    /// `find_pipeline_failure`).
    fn pipeline_failure(&self) -> Result<(), HeadlessError> {
        let failure = self.apps.main.world().resource::<PipelineFailure>();
        match failure
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
        {
            Some((label, error)) => Err(HeadlessError::Pipeline(label, error)),
            None => Ok(()),
        }
    }

    /// Renders frames until `target`'s screenshot arrives (at most
    /// `max_frames`) and returns it.
    pub fn capture(&mut self, target: &Handle<Image>, max_frames: u32) -> Result<image::RgbaImage, HeadlessError> {
        let mut images = self.capture_all(std::slice::from_ref(target), max_frames)?;
        Ok(images.remove(0))
    }

    /// Screenshots of several targets taken in the same frame.
    pub fn capture_all(
        &mut self,
        targets: &[Handle<Image>],
        max_frames: u32,
    ) -> Result<Vec<image::RgbaImage>, HeadlessError> {
        let pending = self.request_screenshots(targets);
        self.wait_for(&pending, max_frames)
    }

    /// Renders frames until `pending`'s pictures arrive (at most
    /// `max_frames`) and returns them: a request made before some frame,
    /// waited for after it (the world may change meanwhile; the pictures
    /// are of the frame after the request).
    pub fn wait_for(
        &mut self,
        pending: &PendingScreenshots,
        max_frames: u32,
    ) -> Result<Vec<image::RgbaImage>, HeadlessError> {
        for _ in 0..max_frames {
            self.update()?;
            if let Some(images) = pending.take()? {
                return Ok(images);
            }
        }
        Err(HeadlessError::NoScreenshot(max_frames))
    }

    /// Asks for screenshots of `targets` from the next frame rendered,
    /// without waiting: run [`HeadlessRenderer::update`] (the frame) and
    /// poll the result with [`PendingScreenshots::take`]. The pictures
    /// arrive a frame or two later, so a camera can move on meanwhile and a
    /// sequence costs about one frame per picture.
    pub fn request_screenshots(&mut self, targets: &[Handle<Image>]) -> PendingScreenshots {
        let slots: Vec<Arc<Mutex<Option<Image>>>> = targets.iter().map(|_| Arc::default()).collect();
        for (target, slot) in targets.iter().zip(&slots) {
            let sink = slot.clone();
            self.world_mut().spawn(Screenshot::image(target.clone())).observe(
                move |captured: On<ScreenshotCaptured>| {
                    *sink.lock().unwrap_or_else(|e| e.into_inner()) = Some(captured.image.clone());
                },
            );
        }
        PendingScreenshots { slots }
    }

    /// A sun (9,000 lux from above one side, no shadow maps) and ambient
    /// light, as `conifer render`, `conifer eval`, `conifer bench` and the
    /// README pictures use; returns the sun.
    pub fn spawn_lights(world: &mut World) -> Entity {
        world.insert_resource(GlobalAmbientLight {
            brightness: 600.0,
            ..default()
        });
        world
            .spawn((
                DirectionalLight {
                    illuminance: 9_000.0,
                    shadow_maps_enabled: false,
                    ..default()
                },
                Transform::from_xyz(4.0, 8.0, 6.0).looking_at(Vec3::ZERO, Vec3::Y),
            ))
            .id()
    }

    /// A camera rendering into `target`.
    pub fn camera_bundle(target: &Handle<Image>, transform: Transform, vertical_fov: f32) -> impl Bundle {
        (
            Camera3d::default(),
            RenderTarget::from(target.clone()),
            Projection::Perspective(PerspectiveProjection {
                fov: vertical_fov,
                ..default()
            }),
            transform,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn float_image(width: u32, height: u32, texels: &[[f32; 4]]) -> Image {
        let mut image = Image::new_uninit(
            Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            TextureDimension::D2,
            TextureFormat::Rgba32Float,
            RenderAssetUsages::RENDER_WORLD,
        );
        image.data = Some(texels.iter().flatten().flat_map(|c| c.to_le_bytes()).collect());
        image
    }

    #[test]
    fn float_screenshots_come_back_as_srgb_of_their_linear_light() {
        let image = float_image(
            2,
            2,
            &[
                [0.0, 1.0, 0.215_861, 1.0],
                [2.5, -0.5, f32::NAN, 0.5],
                [0.003_130_8, 0.5, 0.18, -0.25],
                [0.2, 0.2, 0.2, 3.0],
            ],
        );
        let picture = float_screenshot_as_srgb(&image).unwrap();
        // 0.215861 is sRGB 128; 0.5 is 188; 0.18 is 118; 0.0031308 is 10
        // (12.92 × 0.0031308 × 255); 0.2 is 124.
        assert_eq!(picture.get_pixel(0, 0).0, [0, 255, 128, 255]);
        assert_eq!(picture.get_pixel(1, 0).0, [255, 0, 0, 128]);
        assert_eq!(picture.get_pixel(0, 1).0, [10, 188, 118, 0]);
        assert_eq!(picture.get_pixel(1, 1).0, [124, 124, 124, 255]);
        // A buffer that does not hold the image's texels is an error.
        let mut short = image.clone();
        short.data.as_mut().unwrap().truncate(40);
        assert!(matches!(
            float_screenshot_as_srgb(&short),
            Err(HeadlessError::Format(_))
        ));
    }
}
