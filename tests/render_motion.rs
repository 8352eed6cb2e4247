//! Motion vectors of the compact parts, rendered on Mesa's lavapipe into
//! Bevy's prepass motion vector texture (what TAA and motion blur read)
//! and compared with the CPU reference (`model::wind::motion_vector`): a
//! camera's move shows on every pixel a tree covers, lines over the sky
//! included, and the wind's sway shows with a still camera.
#![cfg(feature = "plugin")]

mod common;

use bevy::core_pipeline::prepass::PreviousViewData;
use bevy::core_pipeline::prepass::{DepthPrepass, MotionVectorPrepass, ViewPrepassTextures};
use bevy::core_pipeline::{Core3d, Core3dSystems};
use bevy::prelude::*;
use bevy::render::render_resource::{
    BindGroupEntry, BindGroupLayoutEntry, BindingResource, BindingType, Buffer, BufferBindingType, BufferDescriptor,
    BufferUsages, ComputePassDescriptor, MapMode, PipelineCompilationOptions, PipelineLayoutDescriptor, PollType,
    RawComputePipelineDescriptor, ShaderModuleDescriptor, ShaderSource, ShaderStages, TextureSampleType,
    TextureViewDimension,
};
use bevy::render::renderer::{RenderContext, RenderDevice, ViewQuery};
use bevy::render::view::ExtractedView;
use bevy::render::{Extract, ExtractSchedule, RenderApp};
use bevy_conifer_lod::model::wind::{TreeWindPhase, WindClock, motion_vector, wind_offset};
use bevy_conifer_lod::plugin::headless::HeadlessRenderer;
use bevy_conifer_lod::prelude::*;
use common::{covered, trunk_with_shoots};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

const SIZE: u32 = 128;
const FOV_DEG: f32 = 40.0;

/// Copies the motion vector texture into a buffer the main world maps,
/// once armed, in the first frame rendered where something moved (the
/// camera or the wind's clock; the render world runs a frame behind the
/// main world): the texture cannot be copied from (Bevy makes it for
/// rendering and sampling only), so a compute pass loads each texel into
/// a storage buffer.
#[derive(Resource, Clone, Default)]
struct MotionCopy(Arc<Mutex<CopyState>>);

/// What the copy holds between the worlds.
#[derive(Default)]
struct CopyState {
    armed: bool,
    /// The wind's clock ([`ConiferWind::time`]) of the frame before the
    /// one rendering, and of that one.
    wind_seconds: [Option<f64>; 2],
    /// The copied frame: the read-back buffer (one `vec2<f32>` a pixel),
    /// the picture's size and its wind clocks.
    copied: Option<(Buffer, UVec2, [Option<f64>; 2])>,
}

/// Render world, extraction: the wind's clock of the frame.
fn extract_wind_seconds(wind: Extract<Option<Res<ConiferWind>>>, copy: Res<MotionCopy>) {
    let mut state = copy.0.lock().unwrap();
    state.wind_seconds = [state.wind_seconds[1], wind.as_ref().and_then(|w| w.time)];
}

const COPY_SHADER: &str = r"
@group(0) @binding(0) var motion: texture_2d<f32>;
@group(0) @binding(1) var<storage, read_write> copied: array<vec2<f32>>;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(motion);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    copied[id.y * size.x + id.x] = textureLoad(motion, vec2<i32>(id.xy), 0).xy;
}
";

/// Render world, after the prepass: the armed copy of the view's motion
/// vectors, in a frame where the camera or the wind moved.
fn copy_motion_vectors(
    view: ViewQuery<(&ViewPrepassTextures, &ExtractedView, &PreviousViewData)>,
    copy: Res<MotionCopy>,
    device: Res<RenderDevice>,
    mut ctx: RenderContext,
) {
    let mut state = copy.0.lock().unwrap();
    let (textures, extracted, previous) = view.into_inner();
    let camera_moved = extracted.world_from_view.to_matrix() != previous.view_from_world.inverse();
    let wind_moved = state.wind_seconds[0] != state.wind_seconds[1];
    let Some(texture) = textures.motion_vectors.as_ref() else {
        return;
    };
    if !state.armed || !(camera_moved || wind_moved) {
        return;
    }
    state.armed = false;
    let size = UVec2::new(texture.texture.texture.width(), texture.texture.texture.height());
    let bytes = u64::from(size.x * size.y) * 8;
    let storage = device.create_buffer(&BufferDescriptor {
        label: Some("motion copy"),
        size: bytes,
        usage: BufferUsages::STORAGE | BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let read = device.create_buffer(&BufferDescriptor {
        label: Some("motion read"),
        size: bytes,
        usage: BufferUsages::COPY_DST | BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let layout = device.create_bind_group_layout(
        "motion copy",
        &[
            BindGroupLayoutEntry {
                binding: 0,
                visibility: ShaderStages::COMPUTE,
                ty: BindingType::Texture {
                    sample_type: TextureSampleType::Float { filterable: false },
                    view_dimension: TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
            BindGroupLayoutEntry {
                binding: 1,
                visibility: ShaderStages::COMPUTE,
                ty: BindingType::Buffer {
                    ty: BufferBindingType::Storage { read_only: false },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
        ],
    );
    let group = device.create_bind_group(
        "motion copy",
        &layout,
        &[
            BindGroupEntry {
                binding: 0,
                resource: BindingResource::TextureView(&texture.texture.default_view),
            },
            BindGroupEntry {
                binding: 1,
                resource: storage.as_entire_binding(),
            },
        ],
    );
    let module = device.create_and_validate_shader_module(ShaderModuleDescriptor {
        label: Some("motion copy"),
        source: ShaderSource::Wgsl(COPY_SHADER.into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&PipelineLayoutDescriptor {
        label: Some("motion copy"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_compute_pipeline(&RawComputePipelineDescriptor {
        label: Some("motion copy"),
        layout: Some(&pipeline_layout),
        module: &module,
        entry_point: Some("main"),
        compilation_options: PipelineCompilationOptions::default(),
        cache: None,
    });
    let encoder = ctx.command_encoder();
    {
        let mut pass = encoder.begin_compute_pass(&ComputePassDescriptor {
            label: Some("motion copy"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &*group, &[]);
        pass.dispatch_workgroups(size.x.div_ceil(8), size.y.div_ceil(8), 1);
    }
    encoder.copy_buffer_to_buffer(&storage, 0, &read, 0, bytes);
    state.copied = Some((read, size, state.wind_seconds));
}

/// One tree at the origin seen by a camera with Bevy's depth and motion
/// vector prepasses (MSAA off, as TAA has it), and the copy of its motion
/// vectors.
fn scene(species: ConiferSpecies) -> (HeadlessRenderer, Handle<Image>, Entity, MotionCopy) {
    let copy = MotionCopy::default();
    let render_copy = copy.clone();
    let mut renderer = HeadlessRenderer::with_setup(".", move |app| {
        app.sub_app_mut(RenderApp)
            .insert_resource(render_copy)
            .add_systems(ExtractSchedule, extract_wind_seconds)
            .add_systems(
                Core3d,
                copy_motion_vectors
                    .after(Core3dSystems::Prepass)
                    .before(Core3dSystems::MainPass),
            );
    });
    let handle = renderer
        .world_mut()
        .resource_mut::<Assets<ConiferSpecies>>()
        .add(species);
    HeadlessRenderer::spawn_lights(renderer.world_mut());
    renderer
        .world_mut()
        .spawn((ConiferFoliage(handle), Transform::IDENTITY));
    let target = renderer.render_target(SIZE, SIZE);
    let camera = common::background_camera(renderer.world_mut(), &target);
    renderer
        .world_mut()
        .entity_mut(camera)
        .insert((DepthPrepass, MotionVectorPrepass, Msaa::Off));
    (renderer, target, camera, copy)
}

/// Renders frames with the copy armed until a frame where something moved
/// is copied; returns the motion vector (UV units a frame) of each pixel,
/// row by row, and the wind's clocks of the frame before and of that one.
fn motion_of_next_move(renderer: &mut HeadlessRenderer, copy: &MotionCopy) -> (Vec<Vec2>, [Option<f64>; 2]) {
    copy.0.lock().unwrap().armed = true;
    let mut copied = None;
    for _ in 0..4 {
        renderer.update().unwrap();
        copied = copy.0.lock().unwrap().copied.take();
        if copied.is_some() {
            break;
        }
    }
    let (buffer, size, wind_seconds) = copied.expect("a frame where something moved was copied");
    assert_eq!(size, UVec2::splat(SIZE));
    let slice = buffer.slice(..);
    let mapped = Arc::new(Mutex::new(None));
    let signal = mapped.clone();
    slice.map_async(MapMode::Read, move |result| *signal.lock().unwrap() = Some(result));
    let device = renderer.world().resource::<RenderDevice>();
    device
        .poll(PollType::Wait {
            submission_index: None,
            timeout: None,
        })
        .unwrap();
    mapped.lock().unwrap().take().expect("mapped").unwrap();
    let data = slice.get_mapped_range();
    let motion = data
        .chunks_exact(8)
        .map(|c| {
            Vec2::new(
                f32::from_le_bytes(c[0..4].try_into().unwrap()),
                f32::from_le_bytes(c[4..8].try_into().unwrap()),
            )
        })
        .collect();
    (motion, wind_seconds)
}

/// The camera `distance` metres in front of `look` (+z), shifted `shift`
/// metres along x, looking along −z.
fn place_camera(renderer: &mut HeadlessRenderer, camera: Entity, look: Vec3, distance: f32, shift: f32) {
    common::look_at_crown(renderer.world_mut(), camera, look, distance, FOV_DEG);
    renderer.world_mut().get_mut::<Transform>(camera).unwrap().translation.x += shift;
}

/// The camera's `clip_from_world` (Bevy's perspective: reversed, infinite).
fn clip_from_world(look: Vec3, distance: f32, shift: f32) -> Mat4 {
    let eye = look + Vec3::Z * distance + Vec3::X * shift;
    let projection = Mat4::perspective_infinite_reverse_rh(FOV_DEG.to_radians(), 1.0, 0.1);
    projection * Mat4::look_to_rh(eye, -Vec3::Z, Vec3::Y)
}

/// Where the test tree's shoots stand: round a 10 m trunk, up to a metre
/// in front of it and behind.
const SHOOTS: [Vec3; 5] = [
    Vec3::new(-0.17, 9.7, 0.0),
    Vec3::new(2.3, 4.85, 0.0),
    Vec3::new(-2.6, 6.0, 0.5),
    Vec3::new(1.5, 7.5, -1.0),
    Vec3::new(-1.2, 3.5, 1.0),
];

/// The camera's distance from the trunk: 12.5 pixels a metre, so a needle
/// is a third of a pixel wide (a line) and the trunk 2–4 pixels (wood).
const DISTANCE: f32 = 14.0;

/// The point the camera looks at: the tree's middle.
const LOOK: Vec3 = Vec3::new(0.0, 5.0, 0.0);

/// A 10 m trunk with shoots at [`SHOOTS`].
fn tree() -> ConiferSpecies {
    trunk_with_shoots(&SHOOTS, |k| 0.15 - 0.011 * k as f32)
}

/// Points along every needle of every shoot and up the trunk.
fn tree_points() -> Vec<Vec3> {
    let needles = SHOOTS.iter().flat_map(|&origin| {
        common::shoot()
            .into_iter()
            .flat_map(move |n| (0..6).map(move |i| origin + n.base.lerp(n.tip, (i as f32 + 0.5) / 6.0)))
    });
    needles
        .chain((0..40).map(|k| Vec3::new(0.0, 9.7 * k as f32 / 39.0, 0.0)))
        .collect()
}

fn save(image: &image::RgbaImage, name: &str) {
    let out = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-output/render");
    std::fs::create_dir_all(&out).unwrap();
    image.save(out.join(format!("{name}.png"))).unwrap();
}

#[test]
fn a_camera_move_shows_on_every_pixel_the_tree_covers_and_nowhere_else() {
    let _turn = common::gpu_turn();
    let (mut renderer, target, camera, copy) = scene(tree());
    let (look, distance) = (LOOK, DISTANCE);
    // A step of 30 cm to the right. What the CPU says of a point on the
    // tree: its depth sets its motion, from the nearest shoot (1 m in
    // front of the trunk) to the farthest.
    let step = 0.3;
    let (now, before) = (
        clip_from_world(look, distance, step),
        clip_from_world(look, distance, 0.0),
    );
    let expected = |z: f32| motion_vector(now, before, Vec3::new(0.0, 5.0, z), Vec3::new(0.0, 5.0, z));
    let (nearest, farthest) = (expected(1.2), expected(-1.2));
    assert!(nearest.x < farthest.x && farthest.x < 0.0, "{nearest} {farthest}");
    // Hardware lines, then lines as quads covering each pixel by their
    // strip's area (their motion pass draws the quads too).
    for raster in [LineRaster::Hardware, LineRaster::Area] {
        renderer.world_mut().resource_mut::<ConiferLodSettings>().line_raster = raster;
        place_camera(&mut renderer, camera, look, distance, 0.0);
        let still = renderer.capture(&target, 20).unwrap();
        save(&still, &format!("motion_still_{raster:?}"));
        // The step, and the picture of that frame.
        place_camera(&mut renderer, camera, look, distance, step);
        let pending = renderer.request_screenshots(std::slice::from_ref(&target));
        let (motion, _) = motion_of_next_move(&mut renderer, &copy);
        let moved = renderer.wait_for(&pending, 20).unwrap().remove(0);
        save(&moved, &format!("motion_moved_{raster:?}"));
        let mask = covered(&moved);
        // Pixels the tree covers nearly whole: under 150 grey (the sunlit
        // bark is 105–145, the background 238, so at least nine tenths bark).
        let dark = |i: usize| common::grey(moved.get_pixel(i as u32 % SIZE, i as u32 / SIZE)) < 150.0;
        let (mut tree_pixels, mut solid, mut solid_with_tree_motion, mut share) = (0usize, 0usize, 0usize, 0.0f32);
        for (i, m) in motion.iter().enumerate() {
            // No pixel moves faster than the tree's nearest point, none the
            // other way, none up or down (the camera slid sideways).
            assert!(
                m.x >= nearest.x * 1.02 && m.x <= 1e-5 && m.y.abs() < 1e-4,
                "pixel {i}: {m} (the tree moves {:.4}–{:.4})",
                nearest.x,
                farthest.x
            );
            if !mask[i] {
                continue;
            }
            tree_pixels += 1;
            // A translucent line moves its pixel by its share; where the tree
            // covers most of the pixel (the trunk, shoots seen on end) the
            // pixel moves as the tree.
            share += m.x / (0.5 * (nearest.x + farthest.x));
            if dark(i) {
                solid += 1;
                solid_with_tree_motion += usize::from(m.x <= farthest.x * 0.9);
            }
        }
        let share = share / tree_pixels.max(1) as f32;
        println!(
            "{raster:?}: {tree_pixels} pixels covered, moved by {share:.2} of the tree's motion on average; {solid_with_tree_motion} of the {solid} dark ones by the tree's ({:.4}–{:.4} UV)",
            nearest.x, farthest.x
        );
        assert!(tree_pixels > 300 && solid > 100, "{tree_pixels} {solid}");
        // Without the tree's motion vectors the covered pixels would keep the
        // sky's (none): TAA would drag the tree's history along with the sky.
        assert!(
            solid_with_tree_motion as f32 >= 0.9 * solid as f32,
            "{solid_with_tree_motion} of {solid}"
        );
        assert!(share > 0.3, "{share}");
    }
}

#[test]
fn the_wind_shows_in_the_motion_vectors_as_the_cpu_field_moves_the_tree() {
    let _turn = common::gpu_turn();
    let species = tree();
    let shape = species.wind_shape;
    let (mut renderer, _target, camera, copy) = scene(species);
    let (look, distance) = (LOOK, DISTANCE);
    place_camera(&mut renderer, camera, look, distance, 0.0);
    let wind = |seconds: f64| ConiferWind {
        direction: Vec2::X,
        strength: 4.0,
        gustiness: 0.3,
        turbulence: 0.6,
        time: Some(seconds),
    };
    // Frames at 2.0 s, then one at 2.1 s: the motion of a tenth of a
    // second of sway.
    renderer.world_mut().insert_resource(wind(2.0));
    for _ in 0..3 {
        renderer.update().unwrap();
    }
    renderer.world_mut().insert_resource(wind(2.1));
    let (motion, seconds) = motion_of_next_move(&mut renderer, &copy);
    assert_eq!(seconds, [Some(2.0), Some(2.1)]);
    // The CPU field's motion of the tree's points over the same tenth.
    let camera_clip = clip_from_world(look, distance, 0.0);
    let phase = TreeWindPhase::of_root(Vec2::ZERO, &wind(2.0).model());
    let (clock_now, clock_before) = (WindClock::at(2.1, &shape), WindClock::at(2.0, &shape));
    let cpu: Vec<f32> = tree_points()
        .iter()
        .map(|&p| {
            let now = p + wind_offset(&wind(2.1).model(), &shape, &clock_now, &phase, p).world(Vec2::X, 1.0);
            let before = p + wind_offset(&wind(2.0).model(), &shape, &clock_before, &phase, p).world(Vec2::X, 1.0);
            motion_vector(camera_clip, camera_clip, now, before).length()
        })
        .collect();
    let cpu_max = cpu.iter().copied().fold(0.0f32, f32::max);
    let gpu: Vec<f32> = motion.iter().map(|m| m.length()).filter(|&l| l > 1e-5).collect();
    let gpu_max = gpu.iter().copied().fold(0.0f32, f32::max);
    println!(
        "{} pixels moved, largest {gpu_max:.6} UV; the CPU field's largest over the tree {cpu_max:.6} UV",
        gpu.len()
    );
    assert!(gpu.len() > 200, "{} pixels moved", gpu.len());
    // The pixels move as the field moves the points: no faster than its
    // fastest point, and the fastest of them near it.
    assert!(gpu_max <= cpu_max * 1.15, "{gpu_max} > {cpu_max}");
    assert!(gpu_max >= cpu_max * 0.5, "{gpu_max} < {cpu_max}");
}
