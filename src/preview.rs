//! A small CPU rasterizer for preview pictures: no GPU, no Bevy.
//!
//! Every primitive is a segment with a world-space width (a needle's `2R`,
//! a line's pixel width, a branch's diameter), projected in perspective and
//! drawn as a screen-space quad whose width is its projected width. A
//! primitive narrower than one (supersampled) pixel is drawn one pixel wide
//! with alpha `w_px × opacity` — exactly the paper's translucent line, whose
//! opacity is the needle's width over the pixel's. Shading is Lambert plus
//! ambient with a two-sided `|n·l|`; visibility is the painter's algorithm
//! (back to front, alpha blended). The picture is supersampled and
//! box-filtered down, blended in linear light and written as sRGB.
//!
//! It serves `conifer preview` (looking at trees and LOD cuts) and as a CPU
//! reference for the GPU renderer.

use glam::{Mat4, Vec2, Vec3};
use image::RgbaImage;

use crate::model::prism::TriangleMesh;
use crate::model::{Cut, LodRecord, Needle, TreeInput, WoodSegment};

/// Fraction of the light every surface gets regardless of orientation.
const AMBIENT: f32 = 0.35;

/// Distance of the near clipping plane, metres.
const NEAR: f32 = 1e-3;

/// One segment to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewPrimitive {
    /// One end, world space (metres).
    pub a: Vec3,
    /// The other end.
    pub b: Vec3,
    /// World-space width in metres (a needle's `2R`; lines use their real
    /// width too).
    pub width: f32,
    /// Shading normal (any length; zero: no orientation, shaded as half lit).
    pub normal: Vec3,
    /// Linear RGB colour.
    pub color: [f32; 3],
    /// Extra alpha factor in `[0, 1]`.
    pub opacity: f32,
}

impl PreviewPrimitive {
    /// A needle as its real cylinder seen side-on: width `2R`, opaque.
    pub fn needle(needle: &Needle, color: [f32; 3]) -> Self {
        Self {
            a: needle.base,
            b: needle.tip,
            width: 2.0 * needle.radius,
            normal: needle.normal,
            color,
            opacity: 1.0,
        }
    }

    /// A piece of wood: width the mean diameter, no orientation.
    pub fn wood(segment: &WoodSegment, color: [f32; 3]) -> Self {
        Self {
            a: segment.start,
            b: segment.end,
            width: segment.start_radius + segment.end_radius,
            normal: Vec3::ZERO,
            color,
            opacity: 1.0,
        }
    }

    fn is_drawable(&self) -> bool {
        self.a.is_finite()
            && self.b.is_finite()
            && self.normal.is_finite()
            && self.color.iter().all(|c| c.is_finite())
            && self.opacity.is_finite()
            && self.opacity > 0.0
            && self.width.is_finite()
            && self.width > 0.0
    }
}

/// Every needle and wood segment of `tree`, in the tree's material colours.
pub fn tree_primitives(tree: &TreeInput) -> Vec<PreviewPrimitive> {
    let rgb = |c: [f32; 4]| [c[0], c[1], c[2]];
    let wood = rgb(tree.material.wood_color);
    let needle = rgb(tree.material.needle_color);
    tree.wood
        .iter()
        .map(|w| PreviewPrimitive::wood(w, wood))
        .chain(tree.needles.iter().map(|n| PreviewPrimitive::needle(n, needle)))
        .collect()
}

/// The primitives of a cut of `record`: its wood, prisms and original lines
/// at the needle's width `2R` (the rasterizer turns a sub-pixel width into
/// the paper's `2/ρ` coverage), original lines' opacity scaled by the
/// transition coefficient `transition` (δ), and merged lines at the width
/// that keeps their needles' summed side area (`Σ 2R·L / length`), so a
/// merged line covers what its needles covered.
pub fn cut_primitives(record: &LodRecord, cut: &Cut, transition: f32) -> Vec<PreviewPrimitive> {
    let rgb = |c: [f32; 4]| [c[0], c[1], c[2]];
    let needle_color = rgb(record.material.needle_color);
    let wood_color = rgb(record.material.wood_color);
    let mut primitives =
        Vec::with_capacity(record.wood.len() + cut.prisms.len() + cut.original_lines.len() + cut.merged_lines.len());
    primitives.extend(record.wood.iter().map(|w| PreviewPrimitive::wood(w, wood_color)));
    for &(needle, _) in &cut.prisms {
        primitives.push(PreviewPrimitive::needle(&record.needles[needle as usize], needle_color));
    }
    for &needle in &cut.original_lines {
        let line = PreviewPrimitive::needle(&record.needles[needle as usize], needle_color);
        primitives.push(PreviewPrimitive {
            opacity: transition,
            ..line
        });
    }
    for &node in &cut.merged_lines {
        let [(a, normal_a), (b, normal_b)] = record.node_ends(node);
        let length = a.distance(b).max(1e-6);
        primitives.push(PreviewPrimitive {
            a,
            b,
            width: record.node_needle_area(node) / length,
            normal: (normal_a + normal_b).normalize_or(normal_a),
            color: needle_color,
            opacity: transition,
        });
    }
    primitives
}

/// One flat triangle to draw (imported wood meshes), shaded with its face
/// normal, two-sided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewTriangle {
    /// Corners, world space (metres).
    pub corners: [Vec3; 3],
    /// Linear RGB colour.
    pub color: [f32; 3],
}

/// The triangles of `mesh` in one colour.
pub fn mesh_triangles(mesh: &TriangleMesh, color: [f32; 3]) -> Vec<PreviewTriangle> {
    mesh.indices
        .chunks_exact(3)
        .filter_map(|t| {
            let corner = |k: usize| mesh.positions.get(t[k] as usize).copied();
            Some(PreviewTriangle {
                corners: [corner(0)?, corner(1)?, corner(2)?],
                color,
            })
        })
        .collect()
}

/// A perspective camera looking from `eye` at `target`, +Y up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewCamera {
    /// Eye position, world space.
    pub eye: Vec3,
    /// The point looked at (the image centre).
    pub target: Vec3,
    /// Vertical field of view, radians.
    pub vertical_fov: f32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl PreviewCamera {
    /// A side view from +Z looking at the centre of the box
    /// `bounds_min..bounds_max`, far enough back that all of it is in frame
    /// (with a 5 % margin).
    pub fn framing(bounds_min: Vec3, bounds_max: Vec3, width: u32, height: u32, vertical_fov: f32) -> Self {
        let vertical_fov = if vertical_fov.is_finite() && vertical_fov > 1e-3 && vertical_fov < 3.1 {
            vertical_fov
        } else {
            0.8
        };
        let (lo, hi) = (bounds_min.min(bounds_max), bounds_min.max(bounds_max));
        let center = 0.5 * (lo + hi);
        let half = 0.5 * (hi - lo);
        let tan_v = (0.5 * vertical_fov).tan();
        let tan_h = tan_v * width.max(1) as f32 / height.max(1) as f32;
        let fit = (half.y / tan_v).max(half.x / tan_h) * 1.05;
        let distance = (fit + half.z).max(half.z + 1e-2);
        Self {
            eye: center + Vec3::Z * distance,
            target: center,
            vertical_fov,
            width,
            height,
        }
    }

    /// Height in metres that one pixel covers at `distance` from the eye.
    pub fn pixel_height_at(&self, distance: f32) -> f32 {
        2.0 * distance * (0.5 * self.vertical_fov).tan() / self.height.max(1) as f32
    }

    /// Distance from the eye to the target.
    pub fn distance(&self) -> f32 {
        self.eye.distance(self.target)
    }
}

/// How to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreviewOptions {
    /// Background colour, sRGB with straight alpha.
    pub background: [u8; 4],
    /// Direction toward the light (any length).
    pub light_direction: Vec3,
    /// Supersampling: this many samples along each side of a pixel (1–8).
    pub samples_per_pixel_side: u32,
}

impl Default for PreviewOptions {
    fn default() -> Self {
        Self {
            background: [236, 240, 244, 255],
            light_direction: Vec3::new(0.35, 0.8, 0.5),
            samples_per_pixel_side: 2,
        }
    }
}

/// Renders `primitives` seen by `camera`. A camera with no pixels gives a
/// 0×0 image; a degenerate camera (eye on target, not finite) gives the
/// background; primitives with non-finite numbers are skipped.
pub fn render_preview(primitives: &[PreviewPrimitive], camera: &PreviewCamera, options: &PreviewOptions) -> RgbaImage {
    render_preview_scene(primitives, &[], camera, options)
}

/// [`render_preview`] with flat triangles too (an imported tree's wood
/// mesh); triangles reaching behind the near plane are skipped, as are
/// those with non-finite corners.
pub fn render_preview_scene(
    primitives: &[PreviewPrimitive],
    triangles: &[PreviewTriangle],
    camera: &PreviewCamera,
    options: &PreviewOptions,
) -> RgbaImage {
    if camera.width == 0 || camera.height == 0 {
        return RgbaImage::new(0, 0);
    }
    let samples = options.samples_per_pixel_side.clamp(1, 8);
    let mut canvas = Canvas::new(camera.width * samples, camera.height * samples, options.background);
    if let Some(projection) = Projection::new(camera, samples) {
        let light = options.light_direction.try_normalize().unwrap_or(Vec3::Y);
        let mut quads: Vec<ScreenQuad> = primitives
            .iter()
            .filter(|p| p.is_drawable())
            .filter_map(|p| projection.project(p, light))
            .chain(triangles.iter().filter_map(|t| projection.project_triangle(t, light)))
            .collect();
        quads.sort_unstable_by(|x, y| y.depth.total_cmp(&x.depth));
        for quad in &quads {
            canvas.fill(quad);
        }
    }
    canvas.downsample(samples)
}

/// World → supersampled screen.
struct Projection {
    view: Mat4,
    /// Supersampled pixels per unit of `x/depth`.
    focal: f32,
    center: Vec2,
}

impl Projection {
    fn new(camera: &PreviewCamera, samples: u32) -> Option<Self> {
        let forward = (camera.target - camera.eye).try_normalize()?;
        if !camera.eye.is_finite() || !camera.vertical_fov.is_finite() || camera.vertical_fov <= 0.0 {
            return None;
        }
        let up = if forward.y.abs() > 0.999 { Vec3::Z } else { Vec3::Y };
        let height = (camera.height * samples) as f32;
        Some(Self {
            view: Mat4::look_at_rh(camera.eye, camera.target, up),
            focal: 0.5 * height / (0.5 * camera.vertical_fov.min(3.1)).tan(),
            center: Vec2::new(0.5 * (camera.width * samples) as f32, 0.5 * height),
        })
    }

    /// The primitive clipped to the near plane and projected, or `None`
    /// when it lies wholly behind the eye.
    fn project(&self, primitive: &PreviewPrimitive, light: Vec3) -> Option<ScreenQuad> {
        let mut a = self.view.transform_point3(primitive.a);
        let mut b = self.view.transform_point3(primitive.b);
        let (depth_a, depth_b) = (-a.z, -b.z);
        if depth_a < NEAR && depth_b < NEAR {
            return None;
        }
        if depth_a < NEAR {
            a = b + (a - b) * ((depth_b - NEAR) / (depth_b - depth_a));
        } else if depth_b < NEAR {
            b = a + (b - a) * ((depth_a - NEAR) / (depth_a - depth_b));
        }
        let (depth_a, depth_b) = (-a.z, -b.z);
        let width_a = primitive.width * self.focal / depth_a;
        let width_b = primitive.width * self.focal / depth_b;
        let mean_width = 0.5 * (width_a + width_b);
        let (half_a, half_b, coverage) = if mean_width < 1.0 {
            (0.5, 0.5, mean_width)
        } else {
            (0.5 * width_a, 0.5 * width_b, 1.0)
        };
        let alpha = (primitive.opacity.min(1.0) * coverage).clamp(0.0, 1.0);
        let quad = ScreenQuad::new(
            self.to_screen(a, depth_a),
            self.to_screen(b, depth_b),
            half_a,
            half_b,
            shade(primitive, light),
            alpha,
            0.5 * (depth_a + depth_b),
        );
        quad.corners.iter().all(|c| c.is_finite()).then_some(quad)
    }

    /// The triangle projected (a quad with a repeated corner), or `None`
    /// when a corner is behind the near plane or not finite.
    fn project_triangle(&self, triangle: &PreviewTriangle, light: Vec3) -> Option<ScreenQuad> {
        let view = triangle.corners.map(|c| self.view.transform_point3(c));
        if view.iter().any(|v| !v.is_finite() || -v.z < NEAR) || !triangle.color.iter().all(|c| c.is_finite()) {
            return None;
        }
        let [a, b, c] = view.map(|v| self.to_screen(v, -v.z));
        let [p, q, r] = triangle.corners;
        let quad = ScreenQuad {
            corners: [a, b, c, c],
            mostly_horizontal: false,
            color: shade_color(triangle.color, (q - p).cross(r - p), light),
            alpha: 1.0,
            depth: -(view[0].z + view[1].z + view[2].z) / 3.0,
        };
        quad.corners.iter().all(|c| c.is_finite()).then_some(quad)
    }

    fn to_screen(&self, view_point: Vec3, depth: f32) -> Vec2 {
        self.center + Vec2::new(view_point.x, -view_point.y) * (self.focal / depth)
    }
}

/// Lambert plus ambient, two-sided; a zero normal is half lit.
fn shade(primitive: &PreviewPrimitive, light: Vec3) -> [f32; 3] {
    shade_color(primitive.color, primitive.normal, light)
}

/// `color` lit from `light` with the surface normal `normal` (any length).
fn shade_color(color: [f32; 3], normal: Vec3, light: Vec3) -> [f32; 3] {
    let diffuse = normal.try_normalize().map_or(0.5, |n| n.dot(light).abs());
    let factor = AMBIENT + (1.0 - AMBIENT) * diffuse;
    color.map(|c| (c * factor).max(0.0))
}

/// A projected primitive: a convex quad (a trapezoid when the ends lie at
/// different depths).
struct ScreenQuad {
    corners: [Vec2; 4],
    /// Closer to horizontal than vertical: rasterized column by column, so
    /// that spans always run across the primitive's width.
    mostly_horizontal: bool,
    color: [f32; 3],
    alpha: f32,
    depth: f32,
}

impl ScreenQuad {
    fn new(a: Vec2, b: Vec2, half_a: f32, half_b: f32, color: [f32; 3], alpha: f32, depth: f32) -> Self {
        let along = b - a;
        let length = along.length();
        let dir = if length > 1e-6 { along / length } else { Vec2::X };
        // An end-on cylinder still shows its disc: never shorter than wide.
        let min_length = half_a + half_b;
        let (a, b) = if length < min_length {
            let grow = 0.5 * (min_length - length);
            (a - dir * grow, b + dir * grow)
        } else {
            (a, b)
        };
        let normal = dir.perp();
        Self {
            corners: [
                a + normal * half_a,
                b + normal * half_b,
                b - normal * half_b,
                a - normal * half_a,
            ],
            mostly_horizontal: dir.x.abs() > dir.y.abs(),
            color,
            alpha,
            depth,
        }
    }
}

/// The span `[lo, hi]` of the convex polygon `corners` on the line `y`.
fn span(corners: &[Vec2; 4], y: f32) -> Option<(f32, f32)> {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    for i in 0..4 {
        let (p, q) = (corners[i], corners[(i + 1) % 4]);
        let (top, bottom) = if p.y <= q.y { (p, q) } else { (q, p) };
        if y < top.y || y > bottom.y || top.y == bottom.y {
            continue;
        }
        let x = top.x + (y - top.y) * (bottom.x - top.x) / (bottom.y - top.y);
        lo = lo.min(x);
        hi = hi.max(x);
    }
    (lo <= hi).then_some((lo, hi))
}

/// A supersampled premultiplied linear RGBA buffer.
struct Canvas {
    width: u32,
    height: u32,
    pixels: Vec<[f32; 4]>,
}

impl Canvas {
    fn new(width: u32, height: u32, background: [u8; 4]) -> Self {
        let alpha = f32::from(background[3]) / 255.0;
        let [r, g, b] = [0, 1, 2].map(|i| srgb_to_linear(background[i]) * alpha);
        Self {
            width,
            height,
            pixels: vec![[r, g, b, alpha]; (width as usize) * (height as usize)],
        }
    }

    /// Blends the quad over the pixels it covers: scan lines (rows, or
    /// columns for mostly horizontal quads) are sampled at their centres,
    /// and each pixel along a span gets the exact length of the span it
    /// holds, so a primitive's drawn width is exact across it.
    fn fill(&mut self, quad: &ScreenQuad) {
        if quad.alpha <= 0.0 {
            return;
        }
        let transposed = quad.mostly_horizontal;
        let corners = if transposed {
            quad.corners.map(|c| Vec2::new(c.y, c.x))
        } else {
            quad.corners
        };
        let (lines, line_length) = if transposed {
            (self.width, self.height)
        } else {
            (self.height, self.width)
        };
        let (min_y, max_y) = corners.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), c| {
            (lo.min(c.y), hi.max(c.y))
        });
        let first_line = (min_y - 0.5).ceil().max(0.0) as u32;
        let end_line = ((max_y - 0.5).floor() + 1.0).clamp(0.0, lines as f32) as u32;
        for line in first_line..end_line {
            let Some((lo, hi)) = span(&corners, line as f32 + 0.5) else {
                continue;
            };
            let (lo, hi) = (lo.max(0.0), hi.min(line_length as f32));
            let mut position = lo.floor();
            while position < hi {
                let cover = hi.min(position + 1.0) - lo.max(position);
                let (x, y) = if transposed {
                    (line, position as u32)
                } else {
                    (position as u32, line)
                };
                self.blend((y * self.width + x) as usize, quad.color, quad.alpha * cover);
                position += 1.0;
            }
        }
    }

    /// `color` at `alpha` over the pixel.
    fn blend(&mut self, index: usize, color: [f32; 3], alpha: f32) {
        let pixel = &mut self.pixels[index];
        let keep = 1.0 - alpha;
        pixel[0] = color[0] * alpha + pixel[0] * keep;
        pixel[1] = color[1] * alpha + pixel[1] * keep;
        pixel[2] = color[2] * alpha + pixel[2] * keep;
        pixel[3] = alpha + pixel[3] * keep;
    }

    /// Box-filters `samples × samples` blocks into an 8-bit sRGB image.
    fn downsample(&self, samples: u32) -> RgbaImage {
        let (width, height) = (self.width / samples, self.height / samples);
        let weight = 1.0 / (samples * samples) as f32;
        let mut image = RgbaImage::new(width, height);
        for (x, y, out) in image.enumerate_pixels_mut() {
            let mut sum = [0.0_f32; 4];
            for sy in 0..samples {
                let row = ((y * samples + sy) * self.width + x * samples) as usize;
                for pixel in &self.pixels[row..row + samples as usize] {
                    for (s, p) in sum.iter_mut().zip(pixel) {
                        *s += p;
                    }
                }
            }
            let alpha = sum[3] * weight;
            let unpremultiply = if alpha > 0.0 { weight / alpha } else { 0.0 };
            out.0 = [
                linear_to_srgb(sum[0] * unpremultiply),
                linear_to_srgb(sum[1] * unpremultiply),
                linear_to_srgb(sum[2] * unpremultiply),
                (alpha * 255.0).round().clamp(0.0, 255.0) as u8,
            ];
        }
        image
    }
}

/// An 8-bit sRGB value in linear light, [0, 1].
pub fn srgb_to_linear(value: u8) -> f32 {
    let c = f32::from(value) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear light (clamped to [0, 1]) as an 8-bit sRGB value.
pub(crate) fn linear_to_srgb(value: f32) -> u8 {
    let c = value.clamp(0.0, 1.0);
    let encoded = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (encoded * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    const BLACK: [u8; 4] = [0, 0, 0, 255];

    fn camera(size: u32) -> PreviewCamera {
        PreviewCamera {
            eye: Vec3::new(0.0, 0.0, 10.0),
            target: Vec3::ZERO,
            vertical_fov: 0.5,
            width: size,
            height: size,
        }
    }

    fn options(samples: u32) -> PreviewOptions {
        PreviewOptions {
            background: BLACK,
            light_direction: Vec3::Z,
            samples_per_pixel_side: samples,
        }
    }

    fn white(a: Vec3, b: Vec3, width: f32) -> PreviewPrimitive {
        PreviewPrimitive {
            a,
            b,
            width,
            normal: Vec3::Z,
            color: [1.0; 3],
            opacity: 1.0,
        }
    }

    fn brightness(image: &RgbaImage, x: u32, y: u32) -> f32 {
        f32::from(image.get_pixel(x, y).0[0]) / 255.0
    }

    #[test]
    fn wide_horizontal_primitive_covers_its_rows() {
        let camera = camera(100);
        let metres_per_pixel = camera.pixel_height_at(10.0);
        // 20 pixels wide, centred: rows 40..60.
        let band = white(
            Vec3::new(-100.0, 0.0, 0.0),
            Vec3::new(100.0, 0.0, 0.0),
            20.0 * metres_per_pixel,
        );
        let image = render_preview(&[band], &camera, &options(2));
        for y in 0..100 {
            let expected = if (40..60).contains(&y) { 1.0 } else { 0.0 };
            for x in [0, 50, 99] {
                assert!((brightness(&image, x, y) - expected).abs() < 0.02, "row {y} col {x}");
            }
        }
    }

    #[test]
    fn thin_primitive_alpha_matches_projected_width() {
        let camera = camera(64);
        let metres_per_pixel = camera.pixel_height_at(10.0);
        for fraction in [0.1_f32, 0.3, 0.6] {
            let line = PreviewPrimitive {
                color: [1.0; 3],
                ..white(
                    Vec3::new(0.05, -100.0, 0.0),
                    Vec3::new(0.05, 100.0, 0.0),
                    fraction * metres_per_pixel,
                )
            };
            let image = render_preview(&[line], &camera, &options(2));
            // The vertical line lands in column 32 (linear light; sRGB-decode the pixel).
            let total: f32 = (0..64).map(|x| srgb_to_linear(image.get_pixel(x, 20).0[0])).sum();
            assert!((total - fraction).abs() < 0.03, "width {fraction}: drawn {total}");
        }
    }

    #[test]
    fn opacity_scales_thin_lines() {
        let camera = camera(32);
        let metres_per_pixel = camera.pixel_height_at(10.0);
        let line = PreviewPrimitive {
            opacity: 0.5,
            ..white(
                Vec3::new(0.0, -100.0, 0.0),
                Vec3::new(0.0, 100.0, 0.0),
                0.4 * metres_per_pixel,
            )
        };
        let image = render_preview(&[line], &camera, &options(1));
        let total: f32 = (0..32).map(|x| srgb_to_linear(image.get_pixel(x, 10).0[0])).sum();
        assert!((total - 0.2).abs() < 0.02, "drawn {total}");
    }

    #[test]
    fn near_primitive_is_drawn_over_far_one() {
        let camera = camera(32);
        let near = PreviewPrimitive {
            color: [1.0, 0.0, 0.0],
            ..white(Vec3::new(-5.0, 0.0, 2.0), Vec3::new(5.0, 0.0, 2.0), 1.0)
        };
        let far = PreviewPrimitive {
            color: [0.0, 0.0, 1.0],
            ..white(Vec3::new(-5.0, 0.0, -2.0), Vec3::new(5.0, 0.0, -2.0), 1.0)
        };
        for order in [[near, far], [far, near]] {
            let image = render_preview(&order, &camera, &options(2));
            let [r, _, b, _] = image.get_pixel(16, 16).0;
            assert!(r > 200 && b < 20, "got {r} {b}");
        }
    }

    #[test]
    fn shading_is_two_sided() {
        let camera = camera(16);
        let mut primitive = white(Vec3::new(-5.0, 0.0, 0.0), Vec3::new(5.0, 0.0, 0.0), 2.0);
        let front = render_preview(&[primitive], &camera, &options(1));
        primitive.normal = -Vec3::Z;
        let back = render_preview(&[primitive], &camera, &options(1));
        assert_eq!(front.get_pixel(8, 8), back.get_pixel(8, 8));
    }

    #[test]
    fn degenerate_input_does_not_panic() {
        let primitive = white(Vec3::ZERO, Vec3::X, 0.1);
        let zero = PreviewCamera {
            width: 0,
            height: 0,
            ..camera(8)
        };
        let image = render_preview(&[primitive], &zero, &options(2));
        assert_eq!((image.width(), image.height()), (0, 0));
        let wide_only = PreviewCamera { height: 0, ..camera(8) };
        assert_eq!(render_preview(&[primitive], &wide_only, &options(2)).width(), 0);

        let nan = [
            white(Vec3::NAN, Vec3::X, 0.1),
            white(Vec3::ZERO, Vec3::X, f32::NAN),
            PreviewPrimitive {
                opacity: f32::NAN,
                ..primitive
            },
            PreviewPrimitive {
                normal: Vec3::NAN,
                ..primitive
            },
            PreviewPrimitive {
                color: [f32::NAN; 3],
                ..primitive
            },
        ];
        let image = render_preview(&nan, &camera(8), &options(2));
        assert!(image.pixels().all(|p| p.0 == BLACK));

        let on_target = PreviewCamera {
            eye: Vec3::ZERO,
            ..camera(8)
        };
        render_preview(&[primitive], &on_target, &options(0));
        let nan_camera = PreviewCamera {
            eye: Vec3::NAN,
            vertical_fov: f32::NAN,
            ..camera(8)
        };
        render_preview(&[primitive], &nan_camera, &options(2));
    }

    #[test]
    fn segments_behind_the_eye_are_clipped() {
        let camera = camera(32);
        // Runs from behind the eye to far in front, through the image centre's column.
        let through = white(Vec3::new(0.0, -1.0, 20.0), Vec3::new(0.0, -1.0, -20.0), 0.2);
        let behind = white(Vec3::new(0.0, 0.0, 11.0), Vec3::new(1.0, 0.0, 12.0), 0.2);
        let image = render_preview(&[through, behind], &camera, &options(2));
        assert!(image.pixels().any(|p| p.0[0] > 0), "the visible part is drawn");
    }

    #[test]
    fn triangles_fill_their_area() {
        let camera = camera(64);
        let metres_per_pixel = camera.pixel_height_at(10.0);
        // A right triangle of legs 32 px, centred: half of a 32×32 square.
        let leg = 32.0 * metres_per_pixel;
        let triangle = PreviewTriangle {
            corners: [Vec3::ZERO, Vec3::new(leg, 0.0, 0.0), Vec3::new(0.0, leg, 0.0)],
            color: [1.0; 3],
        };
        let image = render_preview_scene(&[], &[triangle], &camera, &options(2));
        let covered: f32 = image.pixels().map(|p| srgb_to_linear(p.0[0])).sum();
        assert!((covered - 512.0).abs() < 16.0, "covered {covered} px");
        // Behind the eye: nothing drawn.
        let behind = PreviewTriangle {
            corners: triangle.corners.map(|c| c + Vec3::Z * 20.0),
            ..triangle
        };
        let image = render_preview_scene(&[], &[behind], &camera, &options(2));
        assert!(image.pixels().all(|p| p.0 == BLACK));
    }

    #[test]
    fn framing_keeps_the_bounds_in_view() {
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 4.0, 1.0));
        let camera = PreviewCamera::framing(lo, hi, 200, 100, 0.8);
        let projection = Projection::new(&camera, 1).unwrap();
        for corner in 0..8 {
            let p = Vec3::new(
                if corner & 1 == 0 { lo.x } else { hi.x },
                if corner & 2 == 0 { lo.y } else { hi.y },
                if corner & 4 == 0 { lo.z } else { hi.z },
            );
            let view = projection.view.transform_point3(p);
            let screen = projection.to_screen(view, -view.z);
            assert!(
                screen.x >= 0.0 && screen.x <= 200.0 && screen.y >= 0.0 && screen.y <= 100.0,
                "{p} → {screen}"
            );
        }
        assert!(camera.eye.z > hi.z);
    }
}
