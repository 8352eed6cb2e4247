//! `shadow_coverage_error`: how closely each method's shadow on the ground
//! matches the shadow of the tree's every needle and wood segment as a
//! solid (the reference).
//!
//! The scene: the tree on a large grey ground under a sun with Bevy's
//! default cascaded shadow maps (a game's setup), seen straight from above
//! by a camera that sees the ground and not the tree, so every picture is
//! the shadow alone. Each method has its own tree, ground, sun and camera on
//! render layers of their own (a directional light lights the views and
//! shadows the meshes its layers meet).
//!
//! A pixel's *darkening* is the fraction of the sun its ground hides,
//! `(L_lit − L)/(L_lit − L_dark)` in linear luminance, with `L_lit` the
//! ground without the tree and `L_dark` the ground without the sun (both
//! rendered, pixel by pixel; the ground has no specular, so luminance is
//! linear in the sun's share). The reference darkening is exact geometry,
//! computed on the CPU: every needle's cylinder and wood segment's
//! frustum projected along the sun onto the ground, rasterised with
//! `supersampling²` samples per pixel ([`reference_darkening`]). Neither
//! picture can resolve single shadow-map texels the same way (a shadow map
//! samples thin needles at its texel centres, then filters), so both are
//! averaged over [`SHADOW_BLOCK`]² pixel blocks before they are compared:
//! [`shadow_coverage_error`] is the mean |Δ| over the blocks of the
//! reference shadow's screen box.

use super::measure::PixelRect;
use super::scene::{
    EvalError, EvalView, Method, MethodSpecies, RawTree, raw_materials, renderer_with_species, sway_at,
};
use crate::model::LodRecord;
use crate::plugin::headless::HeadlessRenderer;
use crate::plugin::{ConiferFoliage, ConiferLodOverride, ConiferWind, triangle_mesh};
use bevy::camera::CameraProjection;
use bevy::camera::visibility::RenderLayers;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::light::CascadeShadowConfigBuilder;
use bevy::prelude::*;
use glam::{Mat4, Vec2};
use std::sync::Arc;

/// Direction the sunlight travels (down, toward −x and a little −z): the
/// sun 40° above the horizon.
pub fn sun_direction() -> Vec3 {
    let elevation = 40f32.to_radians();
    Vec3::new(-elevation.cos(), -elevation.sin(), 0.0)
        .normalize()
        .lerp(Vec3::new(0.0, 0.0, -1.0), 0.15)
        .normalize()
}

/// Pixels per side of the blocks both darkenings are averaged over before
/// they are compared.
pub const SHADOW_BLOCK: u32 = 4;

/// The methods whose shadows are measured: the plugin's two and the raw
/// prisms (the LOD chain and the sampled lines draw their shadows as `raw`
/// and `ours` do).
pub const SHADOW_METHODS: [Method; 3] = [Method::Paper, Method::Ours, Method::Raw];

/// Sun illuminance, lux, and ambient brightness of the shadow scene: the
/// lit ground stays below white without tonemapping.
const SUN_LUX: f32 = 3_000.0;
const AMBIENT: f32 = 400.0;

/// The moment on the wind's clock at which the shadow scene stands in
/// wind, seconds.
pub const SHADOW_WIND_SECONDS: f64 = 2.0;

/// `record` with every needle end, wood segment end and wood mesh vertex
/// moved by `sway` (radii, normals and the merge forest as they are).
pub fn swayed_record(record: &LodRecord, sway: impl Fn(Vec3) -> Vec3) -> LodRecord {
    let mut swayed = record.clone();
    for needle in &mut swayed.needles {
        (needle.base, needle.tip) = (sway(needle.base), sway(needle.tip));
    }
    for wood in &mut swayed.wood {
        (wood.start, wood.end) = (sway(wood.start), sway(wood.end));
    }
    for position in &mut swayed.wood_mesh.positions {
        *position = sway(*position);
    }
    swayed
}

/// One method's tree, ground, sun and camera.
struct ShadowView {
    method: Method,
    camera: Entity,
    target: Handle<Image>,
    sun: Entity,
    trees: Vec<Entity>,
}

/// One distance's shadows: each method's darkening and the reference's, row
/// by row, `width × height` values in [0, 1].
pub struct ShadowFrame {
    /// The exact shadow.
    pub reference: Vec<f32>,
    /// Each method's darkening.
    pub methods: Vec<(Method, Vec<f32>)>,
    /// Each method's picture of the ground with the tree's shadow.
    pub pictures: Vec<(Method, image::RgbaImage)>,
    /// The reference shadow's screen box (empty when it is off the picture).
    pub screen_box: PixelRect,
}

/// The headless app of the shadow measure.
pub struct ShadowScene {
    renderer: HeadlessRenderer,
    record: Arc<LodRecord>,
    view: EvalView,
    views: Vec<ShadowView>,
}

impl ShadowScene {
    /// Builds the scene for `record` and those of `methods` that
    /// [`SHADOW_METHODS`] lists, and lets it reach the GPU. In `wind` (not
    /// calm) the scene stands at [`SHADOW_WIND_SECONDS`] on the wind's
    /// clock: the plugin's trees sway on the GPU, the raw tree and the
    /// exact shadow by the CPU reference of the same field. `paper_record`
    /// is the paper's model of `record` where a scene already baked it
    /// ([`super::scene::EvalScene::paper_record`]); `None` bakes it here
    /// when `methods` has `paper`.
    pub fn new(
        record: LodRecord,
        paper_record: Option<Arc<LodRecord>>,
        methods: &[Method],
        view: EvalView,
        wind: Option<ConiferWind>,
    ) -> Result<Self, EvalError> {
        let (mut renderer, species) = renderer_with_species(record.into(), &view)?;
        let record = match wind.filter(|w| !w.model().is_calm()) {
            Some(wind) => {
                renderer.world_mut().insert_resource(ConiferWind {
                    time: Some(SHADOW_WIND_SECONDS),
                    ..wind
                });
                let sway = sway_at(&wind.model(), &species.wind_shape, SHADOW_WIND_SECONDS);
                Arc::new(swayed_record(species.record(), sway))
            }
            None => species.record().clone(),
        };
        let world = renderer.world_mut();
        world.insert_resource(GlobalAmbientLight {
            brightness: AMBIENT,
            ..default()
        });
        let method_species = MethodSpecies::add(world, species, methods, paper_record)?;
        let (needle_material, wood_material) = raw_materials(world, &record);
        let raw = RawTree::new(&record);
        let raw_meshes = {
            let mut meshes = world.resource_mut::<Assets<Mesh>>();
            [
                (meshes.add(triangle_mesh(&raw.needles)), needle_material),
                (meshes.add(triangle_mesh(&raw.wood)), wood_material),
            ]
        };
        let ground_mesh = world
            .resource_mut::<Assets<Mesh>>()
            .add(Plane3d::default().mesh().size(2_000.0, 2_000.0));
        let ground_material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial {
            base_color: Color::linear_rgb(0.35, 0.35, 0.35),
            perceptual_roughness: 1.0,
            reflectance: 0.0,
            ..default()
        });

        let mut views = Vec::new();
        for (k, method) in SHADOW_METHODS.into_iter().filter(|m| methods.contains(m)).enumerate() {
            let (tree_layer, ground_layer) = (2 * k + 1, 2 * k + 2);
            let world = renderer.world_mut();
            let trees = match method.line_opacity(view.ours_line_opacity) {
                Some(opacity) => vec![
                    world
                        .spawn((
                            ConiferFoliage(method_species.handle(method)),
                            ConiferLodOverride {
                                line_opacity: Some(opacity),
                                ..default()
                            },
                            Transform::IDENTITY,
                            RenderLayers::layer(tree_layer),
                        ))
                        .id(),
                ],
                None => raw_meshes
                    .iter()
                    .map(|(mesh, material)| {
                        world
                            .spawn((
                                Mesh3d(mesh.clone()),
                                MeshMaterial3d(material.clone()),
                                Transform::IDENTITY,
                                RenderLayers::layer(tree_layer),
                            ))
                            .id()
                    })
                    .collect(),
            };
            world.spawn((
                Mesh3d(ground_mesh.clone()),
                MeshMaterial3d(ground_material.clone()),
                Transform::IDENTITY,
                RenderLayers::layer(ground_layer),
            ));
            let sun = world
                .spawn((
                    DirectionalLight {
                        illuminance: SUN_LUX,
                        shadow_maps_enabled: true,
                        ..default()
                    },
                    Transform::IDENTITY.looking_to(sun_direction(), Vec3::Y),
                    CascadeShadowConfigBuilder::default().build(),
                    RenderLayers::from_layers(&[tree_layer, ground_layer]),
                ))
                .id();
            let target = renderer.render_target_with_format(view.width, view.height, view.methods_target_format());
            let camera = renderer
                .world_mut()
                .spawn((
                    HeadlessRenderer::camera_bundle(&target, Transform::IDENTITY, view.fov_deg.to_radians()),
                    Camera {
                        order: k as isize,
                        ..default()
                    },
                    Tonemapping::None,
                    RenderLayers::layer(ground_layer),
                ))
                .id();
            view.configure_camera(&mut renderer.world_mut().entity_mut(camera));
            views.push(ShadowView {
                method,
                camera,
                target,
                sun,
                trees,
            });
        }
        let mut scene = Self {
            renderer,
            record,
            view,
            views,
        };
        scene.set_distance(10.0);
        for _ in 0..HeadlessRenderer::SETTLE_FRAMES + 2 {
            scene.renderer.update()?;
        }
        Ok(scene)
    }

    /// The methods measured, in report order.
    pub fn methods(&self) -> Vec<Method> {
        self.views.iter().map(|v| v.method).collect()
    }

    /// Where the crown's shadow falls: the crown centre carried along the
    /// sun to the ground.
    pub fn shadow_center(&self) -> Vec3 {
        project_to_ground(self.record.crown_center(), sun_direction())
    }

    /// The cameras' transform at `distance`: that high above the shadow's
    /// centre, looking straight down (−z up the picture).
    pub fn camera_transform(&self, distance: f32) -> Transform {
        let center = self.shadow_center();
        let distance = if distance.is_finite() { distance.max(1e-2) } else { 1.0 };
        Transform::from_translation(center + Vec3::Y * distance).looking_at(center, Vec3::NEG_Z)
    }

    /// World → clip transform of the cameras at `distance` (Bevy's reversed,
    /// infinite perspective).
    pub fn clip_from_world(&self, distance: f32) -> Mat4 {
        let projection = PerspectiveProjection {
            fov: self.view.fov_deg.to_radians(),
            aspect_ratio: self.view.width as f32 / self.view.height as f32,
            ..default()
        };
        projection.get_clip_from_view() * self.camera_transform(distance).to_matrix().inverse()
    }

    fn set_distance(&mut self, distance: f32) {
        let transform = self.camera_transform(distance);
        for view in &self.views {
            if let Some(mut t) = self.renderer.world_mut().get_mut::<Transform>(view.camera) {
                *t = transform;
            }
        }
    }

    fn set_state(&mut self, trees: bool, sun: bool) {
        for view in &self.views {
            let world = self.renderer.world_mut();
            for &tree in &view.trees {
                world.entity_mut(tree).insert(if trees {
                    Visibility::Inherited
                } else {
                    Visibility::Hidden
                });
            }
            if let Some(mut light) = world.get_mut::<DirectionalLight>(view.sun) {
                light.illuminance = if sun { SUN_LUX } else { 0.0 };
            }
        }
    }

    fn capture_state(&mut self, trees: bool, sun: bool) -> Result<Vec<image::RgbaImage>, EvalError> {
        self.set_state(trees, sun);
        let targets: Vec<Handle<Image>> = self.views.iter().map(|v| v.target.clone()).collect();
        // A frame for the plugin to select the trees' detail for the moved
        // cameras and cascades, then the capture.
        self.renderer.update()?;
        Ok(self.renderer.capture_all(&targets, 10)?)
    }

    /// The shadows with the cameras `distance` metres above the shadow.
    pub fn capture(&mut self, distance: f32) -> Result<ShadowFrame, EvalError> {
        self.set_distance(distance);
        let shaded = self.capture_state(true, true)?;
        let lit = self.capture_state(false, true)?;
        let dark = self.capture_state(false, false)?;
        self.set_state(true, true);
        let (width, height) = (self.view.width, self.view.height);
        let clip_from_world = self.clip_from_world(distance);
        let reference = reference_darkening(
            &self.record,
            sun_direction(),
            clip_from_world,
            width,
            height,
            self.view.supersampling.max(4),
        );
        let screen_box = darkened_box(&reference, width, height, 0.01);
        let mut methods = Vec::new();
        let mut pictures = Vec::new();
        for (k, view) in self.views.iter().enumerate() {
            methods.push((view.method, darkening(&shaded[k], &lit[k], &dark[k])));
            pictures.push((view.method, shaded[k].clone()));
        }
        Ok(ShadowFrame {
            reference,
            methods,
            pictures,
            screen_box,
        })
    }
}

/// Where a point carried along `direction` meets the ground `y = 0`.
pub fn project_to_ground(point: Vec3, direction: Vec3) -> Vec3 {
    if direction.y.abs() < 1e-6 {
        return Vec3::new(point.x, 0.0, point.z);
    }
    point - direction * (point.y / direction.y)
}

/// Darkening of each pixel, `(L_lit − L)/(L_lit − L_dark)` in linear
/// luminance, clamped to [0, 1]; 0 where the sun adds nothing.
pub fn darkening(shaded: &image::RgbaImage, lit: &image::RgbaImage, dark: &image::RgbaImage) -> Vec<f32> {
    let luminance = |p: &image::Rgba<u8>| {
        0.2126 * crate::preview::srgb_to_linear(p[0])
            + 0.7152 * crate::preview::srgb_to_linear(p[1])
            + 0.0722 * crate::preview::srgb_to_linear(p[2])
    };
    shaded
        .pixels()
        .zip(lit.pixels())
        .zip(dark.pixels())
        .map(|((s, l), d)| {
            let (s, l, d) = (luminance(s), luminance(l), luminance(d));
            if l - d <= 1e-4 {
                0.0
            } else {
                ((l - s) / (l - d)).clamp(0.0, 1.0)
            }
        })
        .collect()
}

/// The exact shadow of `record` (at the origin, untransformed) on the ground
/// `y = 0` under parallel light travelling along `sun`, as seen through
/// `clip_from_world` on a `width × height` picture: per pixel, the fraction
/// of `supersampling²` samples the shadow of a needle's cylinder, a wood
/// segment's frustum or an imported wood triangle covers.
pub fn reference_darkening(
    record: &LodRecord,
    sun: Vec3,
    clip_from_world: Mat4,
    width: u32,
    height: u32,
    supersampling: u32,
) -> Vec<f32> {
    let s = supersampling.max(1);
    let mut mask = CoverageMask::new(width * s, height * s);
    let to_samples = |point: Vec3| -> Option<Vec2> {
        let clip = clip_from_world * project_to_ground(point, sun).extend(1.0);
        (clip.w > 1e-6).then(|| {
            let ndc = clip.truncate() / clip.w;
            Vec2::new(
                (ndc.x + 1.0) * 0.5 * (width * s) as f32,
                (1.0 - ndc.y) * 0.5 * (height * s) as f32,
            )
        })
    };
    // The silhouette of a cylinder seen along the light: its axis widened by
    // its radius across both the axis and the light.
    let mut segment = |a: Vec3, b: Vec3, radius_a: f32, radius_b: f32| {
        let across = (b - a).cross(sun).normalize_or_zero();
        let corners = [
            a + across * radius_a,
            b + across * radius_b,
            b - across * radius_b,
            a - across * radius_a,
        ];
        if let [Some(p0), Some(p1), Some(p2), Some(p3)] = corners.map(to_samples) {
            mask.fill_convex(&[p0, p1, p2, p3]);
        }
    };
    for needle in &record.needles {
        segment(needle.base, needle.tip, needle.radius, needle.radius);
    }
    for wood in &record.wood {
        segment(wood.start, wood.end, wood.start_radius, wood.end_radius);
    }
    let mesh = &record.wood_mesh;
    for triangle in mesh.indices.chunks_exact(3) {
        let corners = [0, 1, 2].map(|k| mesh.positions.get(triangle[k] as usize).and_then(|&p| to_samples(p)));
        if let [Some(p0), Some(p1), Some(p2)] = corners {
            mask.fill_convex(&[p0, p1, p2]);
        }
    }
    mask.fractions(s)
}

/// A bit per sample: whether some shadow covers it.
struct CoverageMask {
    width: u32,
    height: u32,
    covered: Vec<bool>,
}

impl CoverageMask {
    fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            covered: vec![false; width as usize * height as usize],
        }
    }

    /// Marks the samples (at half-integer positions) inside the convex
    /// polygon `corners` (either winding; degenerate polygons cover nothing).
    fn fill_convex(&mut self, corners: &[Vec2]) {
        if corners.iter().any(|c| !c.is_finite()) {
            return;
        }
        let area: f32 = (0..corners.len())
            .map(|k| corners[k].perp_dot(corners[(k + 1) % corners.len()]))
            .sum();
        if area.abs() < 1e-12 {
            return;
        }
        let sign = area.signum();
        let (lo, hi) = corners.iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), &c| (lo.min(c), hi.max(c)),
        );
        let x0 = (lo.x - 0.5).ceil().max(0.0) as u32;
        let y0 = (lo.y - 0.5).ceil().max(0.0) as u32;
        let x1 = ((hi.x - 0.5).floor() + 1.0).clamp(0.0, self.width as f32) as u32;
        let y1 = ((hi.y - 0.5).floor() + 1.0).clamp(0.0, self.height as f32) as u32;
        for y in y0..y1 {
            for x in x0..x1 {
                let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let inside = (0..corners.len()).all(|k| {
                    let (a, b) = (corners[k], corners[(k + 1) % corners.len()]);
                    (b - a).perp_dot(p - a) * sign >= 0.0
                });
                if inside {
                    self.covered[(y * self.width + x) as usize] = true;
                }
            }
        }
    }

    /// The covered fraction of each `s × s` block, row by row.
    fn fractions(&self, s: u32) -> Vec<f32> {
        let (width, height) = (self.width / s, self.height / s);
        let mut out = vec![0.0f32; width as usize * height as usize];
        for y in 0..self.height {
            for x in 0..self.width {
                if self.covered[(y * self.width + x) as usize] {
                    out[((y / s) * width + x / s) as usize] += 1.0;
                }
            }
        }
        let samples = (s * s) as f32;
        out.iter_mut().for_each(|v| *v /= samples);
        out
    }
}

/// The box of the pixels darkened by more than `threshold`, widened by a
/// block and clamped to the picture (empty when none is).
pub fn darkened_box(darkening: &[f32], width: u32, height: u32, threshold: f32) -> PixelRect {
    let mut rect: Option<PixelRect> = None;
    for (i, &v) in darkening.iter().enumerate() {
        if v > threshold {
            let (x, y) = (i as u32 % width.max(1), i as u32 / width.max(1));
            let pixel = PixelRect {
                x0: x,
                y0: y,
                x1: x + 1,
                y1: y + 1,
            };
            rect = Some(rect.map_or(pixel, |r| r.union(&pixel)));
        }
    }
    rect.map_or(
        PixelRect {
            x0: 0,
            y0: 0,
            x1: 0,
            y1: 0,
        },
        |r| PixelRect {
            x0: r.x0.saturating_sub(SHADOW_BLOCK),
            y0: r.y0.saturating_sub(SHADOW_BLOCK),
            x1: (r.x1 + SHADOW_BLOCK).min(width),
            y1: (r.y1 + SHADOW_BLOCK).min(height),
        },
    )
}

/// Mean |Δ| between `reference` and `test` (darkenings of a picture
/// `width` wide, row by row) over `rect`, both first averaged over
/// [`SHADOW_BLOCK`]² blocks (the last, partial blocks averaged over what
/// they hold). `None` when `rect` is empty or the sizes differ.
pub fn shadow_coverage_error(reference: &[f32], test: &[f32], width: u32, rect: &PixelRect) -> Option<f64> {
    if reference.len() != test.len() || rect.area() == 0 || width == 0 {
        return None;
    }
    let height = reference.len() as u32 / width;
    if rect.x1 > width || rect.y1 > height {
        return None;
    }
    let mut total = 0.0f64;
    let mut blocks = 0usize;
    let mut y = rect.y0;
    while y < rect.y1 {
        let mut x = rect.x0;
        while x < rect.x1 {
            let (x1, y1) = ((x + SHADOW_BLOCK).min(rect.x1), (y + SHADOW_BLOCK).min(rect.y1));
            let (mut a, mut b) = (0.0f64, 0.0f64);
            for yy in y..y1 {
                for xx in x..x1 {
                    let i = (yy * width + xx) as usize;
                    a += f64::from(reference[i]);
                    b += f64::from(test[i]);
                }
            }
            let n = f64::from((x1 - x) * (y1 - y));
            total += (a - b).abs() / n;
            blocks += 1;
            x = x1;
        }
        y = (y + SHADOW_BLOCK).min(rect.y1);
    }
    Some(total / blocks as f64)
}

/// The darkening as a grey picture (white: no shadow), to look at.
pub fn darkening_picture(darkening: &[f32], width: u32) -> image::RgbaImage {
    let height = darkening.len() as u32 / width.max(1);
    image::RgbaImage::from_fn(width, height, |x, y| {
        let v = 255 - (darkening[(y * width + x) as usize].clamp(0.0, 1.0) * 255.0).round() as u8;
        image::Rgba([v, v, v, 255])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::wind::{Wind, WindShape};

    #[test]
    fn a_swayed_record_moves_every_end_by_the_field_and_its_shadow_downwind() {
        // A 10 m pole of needles, one every metre, on a trunk.
        let input = crate::model::TreeInput {
            name: "pole".into(),
            needles: (0..10)
                .map(|k| crate::model::Needle {
                    base: Vec3::new(0.0, k as f32 + 0.5, 0.0),
                    tip: Vec3::new(0.3, k as f32 + 0.5, 0.0),
                    radius: 0.01,
                    normal: Vec3::Y,
                    group: k,
                })
                .collect(),
            wood: vec![crate::model::WoodSegment {
                start: Vec3::ZERO,
                end: Vec3::Y * 10.0,
                start_radius: 0.1,
                end_radius: 0.02,
            }],
            ..Default::default()
        };
        let record = crate::model::bake(&input, &Default::default(), &()).unwrap();
        let shape = WindShape::from_bounds(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 10.0, 0.5), Vec2::ZERO);
        let wind = Wind {
            strength: 4.0,
            ..Wind::LIGHT_BREEZE
        };
        let sway = sway_at(&wind, &shape, SHADOW_WIND_SECONDS);
        let swayed = swayed_record(&record, &sway);
        for (calm, moved) in record.needles.iter().zip(&swayed.needles) {
            assert_eq!(moved.base, sway(calm.base));
            assert_eq!(moved.tip, sway(calm.tip));
            assert_eq!((moved.radius, moved.normal), (calm.radius, calm.normal));
        }
        assert_eq!(swayed.wood[0].start, sway(record.wood[0].start));
        assert_eq!(swayed.merged, record.merged);
        // The top leans downwind (+x) by centimetres; the foot stays.
        assert!(swayed.wood[0].end.x - record.wood[0].end.x > 0.05);
        assert!(swayed.wood[0].start.distance(record.wood[0].start) < 1e-3);
        // So does the exact shadow: its darkened mass moves.
        let clip = Mat4::orthographic_rh(-20.0, 20.0, -20.0, 20.0, -100.0, 100.0)
            * Mat4::look_at_rh(Vec3::Y * 50.0, Vec3::ZERO, Vec3::NEG_Z);
        let centroid = |r: &LodRecord| {
            let dark = reference_darkening(r, sun_direction(), clip, 128, 128, 2);
            let total: f32 = dark.iter().sum();
            let x: f32 = dark.iter().enumerate().map(|(i, d)| (i % 128) as f32 * d).sum();
            x / total
        };
        let (calm, moved) = (centroid(&record), centroid(&swayed));
        assert!((moved - calm).abs() > 0.05, "shadow centroid {calm} → {moved} px");
    }

    #[test]
    fn a_square_covers_its_area() {
        let mut mask = CoverageMask::new(64, 64);
        mask.fill_convex(&[
            Vec2::new(8.0, 8.0),
            Vec2::new(24.0, 8.0),
            Vec2::new(24.0, 40.0),
            Vec2::new(8.0, 40.0),
        ]);
        // Clockwise too, overlapping: the union counts once.
        mask.fill_convex(&[
            Vec2::new(8.0, 8.0),
            Vec2::new(8.0, 40.0),
            Vec2::new(24.0, 40.0),
            Vec2::new(24.0, 8.0),
        ]);
        let fractions = mask.fractions(8);
        let covered: f32 = fractions.iter().sum::<f32>() * 64.0;
        assert_eq!(covered, 16.0 * 32.0);
        // Pixel (1, 1) is the block [8, 16)²: fully covered.
        assert_eq!(fractions[8 + 1], 1.0);
        assert_eq!(fractions[0], 0.0);
    }

    #[test]
    fn block_error_of_known_darkenings() {
        let width = 8;
        let reference = vec![0.5f32; 64];
        // A checkerboard of 0 and 1 averages to the reference over blocks.
        let test: Vec<f32> = (0..64).map(|i| ((i % 8 + i / 8) % 2) as f32).collect();
        let rect = PixelRect::full(8, 8);
        assert!(shadow_coverage_error(&reference, &test, width, &rect).unwrap() < 1e-9);
        let shifted = vec![0.75f32; 64];
        assert!((shadow_coverage_error(&reference, &shifted, width, &rect).unwrap() - 0.25).abs() < 1e-9);
        assert_eq!(
            shadow_coverage_error(
                &reference,
                &test,
                width,
                &PixelRect {
                    x0: 2,
                    y0: 2,
                    x1: 2,
                    y1: 5
                }
            ),
            None
        );
        assert_eq!(shadow_coverage_error(&reference, &test[1..], width, &rect), None);
    }

    #[test]
    fn ground_projection_follows_the_light() {
        let sun = sun_direction();
        let p = project_to_ground(Vec3::new(1.0, 3.0, 2.0), sun);
        assert!(p.y.abs() < 1e-6);
        // The offset is parallel to the light.
        assert!((p - Vec3::new(1.0, 3.0, 2.0)).normalize().dot(sun) > 0.9999);
    }
}
