//! How a line is lit: as the cylinder (or bundle of cylinders) it stands
//! for, not as a flat strip facing the viewer. CPU reference of the line
//! fragment shader's `cylinder_lighting` (`conifer_compact.wgsl`).
//!
//! A pixel covered by a thin cylinder sees the radiance of its visible half
//! averaged over the cylinder's projected width. With `s ∈ [−1, 1]` the
//! offset across that width, the surface normal there is
//! `n(s) = √(1 − s²)·t + s·b`, where `t` is the direction to the viewer
//! made perpendicular to the axis and `b = axis × t`; a uniform measure in
//! `s` is the pixel's average. The shader evaluates Bevy's BRDF, light by
//! light, at the four Gauss–Legendre nodes ([`ACROSS_NODES`]) of the part
//! of `s` that light reaches ([`lit_across`]): over the whole width, a
//! light from behind the cylinder lights a band at one edge that the
//! nodes miss, and where `n·L` turns negative the integrand has a kink no
//! four-point rule follows.
//!
//! ## A texel of many needles
//!
//! Far away one impostor texel stands for hundreds of needles pointing
//! every way, and no single cylinder is lit like them: lighting their mean
//! axis (sign-folded up, as the first impostors did) gave a silver fir's
//! flat two-rowed shoots a random axis, and the crown bands of light and
//! dark. A population of cylinders whose axes are spread evenly over the
//! sphere shows, weighted by projected area, the normals of a sphere
//! ([`sphere_lambert`]); a real texel lies between that and cylinders along
//! the crown's main directions. [`texel_shares`] fits each needle's
//! lighting, over suns above the horizon, as shares of a vertical
//! cylinder, a cylinder across the view and the sphere; the fit is linear,
//! so a texel's shares are its needles' area-weighted means and a mip
//! level's shares its texels' means.
//!
//! ## A merged line's bundle
//!
//! A merged line stands for needles spread about its chord: a fascicle's
//! needles fan out, a fir's two rows stand across their shoot, and a line
//! merged over a branch holds shoots pointing every way. Lit as one
//! cylinder along the chord, such a bundle is lit as if its needles lay
//! along it. A needle at angle `θ` to the chord is lit, fitted over
//! views, suns and its turn about the chord, as `a(θ)` of the chord's
//! cylinder and `1 − a(θ)` of a sphere; `a` runs from 1 along the chord to
//! about −0.4 across it (needles across the chord, turned every way about
//! it, are lit as a sphere less a share of the chord's cylinder).
//! [`bundle_cylinder_share`] takes `a ≈ 1 − β·sin²θ` ([`BUNDLE_SLOPE`]),
//! the least-squares fit in `cos²θ`, so a bundle's share depends on its
//! needles only through the area-weighted mean of `cos²θ`: its
//! [`AxisSpread`] (the second moments of the needles' directions, which
//! add over children and turn with a placement) seen along the chord.

use glam::{Mat3, Quat, Vec2, Vec3};
use std::f32::consts::PI;
use std::sync::OnceLock;

/// The four-point Gauss–Legendre rule on `[−1, 1]`: offsets across a
/// cylinder's projected width and their weights (summing to 2), as the
/// shader's `across_offset` and `across_weight`.
pub const ACROSS_NODES: [(f32, f32); 4] = [
    (-0.861_136_3, 0.347_854_85),
    (-0.339_981_04, 0.652_145_15),
    (0.339_981_04, 0.652_145_15),
    (0.861_136_3, 0.347_854_85),
];

/// The frame of a cylinder's visible half: the normal facing the viewer
/// and the sideways one (`axis × toward`), both unit vectors, as the
/// shader's `facing_axis` turns a line's cylinder and a prism's ring. A
/// cylinder seen along its axis gets the ring normal of
/// [`super::compact::ring_basis`].
pub fn visible_frame(axis: Vec3, to_viewer: Vec3) -> (Vec3, Vec3) {
    let axis = axis.try_normalize().unwrap_or(Vec3::Y);
    let across = to_viewer - axis * axis.dot(to_viewer);
    let toward = if across.length_squared() >= 1e-12 * to_viewer.length_squared().max(1e-30) {
        across.normalize()
    } else {
        super::compact::ring_basis(axis).0
    };
    (toward, axis.cross(toward))
}

/// The part `[s0, s1]` of a cylinder's projected width (offsets `s` across
/// it, as the module's `n(s)`) whose normals face unit `to_light`
/// (`n(s)·L ≥ 0`): `[−a/r, 1]` when the light is on the `b` side of the
/// cylinder, else `[−1, a/r]`, with `a = t·L`, `b = b·L`, `r = |(a, b)|`.
/// Empty (`[0, 0]`) for a light along the axis. As the shader's
/// `lit_across`.
pub fn lit_across(axis: Vec3, to_viewer: Vec3, to_light: Vec3) -> (f32, f32) {
    let (toward, side) = visible_frame(axis, to_viewer);
    let (a, b) = (toward.dot(to_light), side.dot(to_light));
    let r = Vec2::new(a, b).length();
    if r < 1e-6 {
        (0.0, 0.0)
    } else if b >= 0.0 {
        (-a / r, 1.0)
    } else {
        (-1.0, a / r)
    }
}

/// The average over a cylinder's projected width of `radiance(n)`, the
/// radiance leaving its surface where the normal is `n` under a light from
/// `to_light` (0 where `n` faces away from it), by the shader's four-point
/// rule over the part of the width the light reaches ([`lit_across`]).
pub fn across_average(axis: Vec3, to_viewer: Vec3, to_light: Vec3, radiance: impl Fn(Vec3) -> f32) -> f32 {
    band_average(axis, to_viewer, to_light, (-1.0, 1.0), radiance)
}

/// The average over the band `[s0, s1]` of a cylinder's projected width
/// (offsets `s` across it, as the module's `n(s)`, `−1 ≤ s0 < s1 ≤ 1`) of
/// `radiance(n)`, by the shader's four-point rule over the part of the band
/// the light reaches (its `band_normal`); 0 where the light reaches none
/// of it. Over the whole width (`[−1, 1]`) it is [`across_average`].
pub fn band_average(
    axis: Vec3,
    to_viewer: Vec3,
    to_light: Vec3,
    band: (f32, f32),
    radiance: impl Fn(Vec3) -> f32,
) -> f32 {
    let (toward, side) = visible_frame(axis, to_viewer);
    let (lit0, lit1) = lit_across(axis, to_viewer, to_light);
    let (s0, s1) = (band.0.max(lit0), band.1.min(lit1));
    let width = band.1 - band.0;
    if !(s1 > s0 && width > 0.0) {
        return 0.0;
    }
    let half = 0.5 * (s1 - s0);
    half / width
        * ACROSS_NODES
            .iter()
            .map(|&(x, w)| {
                let s = 0.5 * (s0 + s1) + half * x;
                w * radiance((1.0 - s * s).max(0.0).sqrt() * toward + s * side)
            })
            .sum::<f32>()
}

/// The exact average of the Lambert factor `max(n·L, 0)` over the band
/// `[s0, s1]` of a cylinder's projected width (offsets `s = sin θ` across
/// it, `θ` the normal's angle from the viewer's side toward `side`): `∫
/// max(cos(θ − θL), 0)·|L⊥| cos θ dθ / (s1 − s0)`, in closed form over the
/// lit part. Over `[−1, 1]` it is [`cylinder_lambert`].
pub fn band_lambert(axis: Vec3, to_viewer: Vec3, to_light: Vec3, band: (f32, f32)) -> f32 {
    let (toward, side) = visible_frame(axis, to_viewer);
    let (a, b) = (toward.dot(to_light), side.dot(to_light));
    let length = Vec2::new(a, b).length();
    let (lit0, lit1) = lit_across(axis, to_viewer, to_light);
    let (s0, s1) = (band.0.max(lit0).clamp(-1.0, 1.0), band.1.min(lit1).clamp(-1.0, 1.0));
    let width = band.1 - band.0;
    if !(s1 > s0 && width > 0.0 && length > 1e-6) {
        return 0.0;
    }
    // n(θ)·L = a cos θ + b sin θ; times ds = cos θ dθ:
    // ∫ (a cos²θ + b sin θ cos θ) dθ = a (θ/2 + sin 2θ / 4) − b cos 2θ / 4.
    let antiderivative = |s: f32| {
        let theta = s.asin();
        a * (0.5 * theta + 0.25 * (2.0 * theta).sin()) - 0.25 * b * (2.0 * theta).cos()
    };
    ((antiderivative(s1) - antiderivative(s0)) / width).max(0.0)
}

/// The exact average over a cylinder's projected width of the Lambert
/// factor `max(n·L, 0)`, for unit `to_light` `L` (Kajiya and Kay 1989,
/// integrated over the visible half): `|L⊥| · (sin φ + (π − φ) cos φ) / 4`,
/// where `L⊥` is the light direction perpendicular to the axis and `φ` the
/// angle between it and the viewer's. π/4 lit from the viewer, 0 from
/// behind; a strip facing the viewer would show `|L⊥| cos φ`, up to 4/π
/// brighter.
pub fn cylinder_lambert(axis: Vec3, to_viewer: Vec3, to_light: Vec3) -> f32 {
    let (toward, side) = visible_frame(axis, to_viewer);
    let axis = toward.cross(side);
    let across = to_light - axis * axis.dot(to_light);
    let length = across.length();
    if length < 1e-12 {
        return 0.0;
    }
    let phi = (across.dot(toward) / length).clamp(-1.0, 1.0).acos();
    length * (phi.sin() + (PI - phi) * phi.cos()) / 4.0
}

/// The exact average over a sphere's projected disk of the Lambert factor
/// `max(n·L, 0)`, for unit `to_viewer` and `to_light`: the Lambert
/// sphere's phase function `2 (sin α + (π − α) cos α) / 3π`, where `α` is
/// the angle between the viewer and the light. 2/3 lit from the viewer, 0
/// from behind the sphere.
pub fn sphere_lambert(to_viewer: Vec3, to_light: Vec3) -> f32 {
    let alpha = to_viewer.dot(to_light).clamp(-1.0, 1.0).acos();
    2.0 * (alpha.sin() + (PI - alpha) * alpha.cos()) / (3.0 * PI)
}

/// The normal of the round cylinder a prism stands for, where one of its
/// fragments lies, as the shader's `round_prism_normal`: `normal` is the
/// prism's normal interpolated across a face (unit at the corners, not
/// normalized between them), `side` and `toward` the unit frame its ring
/// was turned to ([`visible_frame`]: across the view and facing it). A
/// corner's normal is its radial direction, so the normal's component
/// along `side` is interpolated as the fragment's offset across the width
/// over the radius, `s`; the cylinder's normal there is
/// `√(1 − s²)·toward + s·side`. Interpolated as it is, a prism of few sides
/// spends more of its width near its rim than a cylinder does (a triangle
/// seen corner-on: its last third of each face even turned away from the
/// viewer, past the rim), which a light from behind lights. A cap's normal
/// (along the axis) is kept.
pub fn round_prism_normal(normal: Vec3, side: Vec3, toward: Vec3) -> Vec3 {
    let s = normal.dot(side).clamp(-1.0, 1.0);
    let along = normal - s * side - normal.dot(toward) * toward;
    if along.length_squared() > 0.25 {
        return normal.normalize_or_zero();
    }
    (1.0 - s * s).max(0.0).sqrt() * toward + s * side
}

/// The view cosines `n·V` at which a cylinder's or a sphere's indirect
/// light is taken, each with its weight over a cylinder's projected width
/// and over a sphere's disk: `(cosine, cylinder weight, sphere weight)`,
/// each column of weights summing to 1. As the shader's `indirect_node`.
///
/// Bevy's split-sum ambient and environment light grow toward a
/// silhouette (Fresnel), so a pixel seeing a whole thin cylinder sees more
/// of it than its normal facing the viewer gets. With `φ` the normal's
/// angle from the viewer, `n·V = cos φ`; across a cylinder's width
/// `s = sin φ` is uniform, so its average is `∫₀^{π/2} g(cos φ) cos φ dφ`;
/// over a sphere's disk `∫₀^{π/2} g(cos φ) 2 sin φ cos φ dφ`. Both by the
/// four-point Gauss–Legendre rule in `φ` ([`ACROSS_NODES`] mapped onto
/// `[0, π/2]`), exact for smooth `g` to a few parts in 10⁴ and within 8 %
/// for the specular of Bevy's kinked polynomial `F_AB`, which the normal
/// facing the viewer misses by up to a third (unit tests).
pub fn indirect_nodes() -> [(f32, f32, f32); 4] {
    let quarter = std::f64::consts::FRAC_PI_4;
    let raw = ACROSS_NODES.map(|(x, w)| {
        let phi = (f64::from(x) + 1.0) * quarter;
        let w = f64::from(w) * quarter;
        (phi.cos(), w * phi.cos(), w * 2.0 * phi.sin() * phi.cos())
    });
    let cylinder: f64 = raw.iter().map(|r| r.1).sum();
    let sphere: f64 = raw.iter().map(|r| r.2).sum();
    raw.map(|(c, wc, ws)| (c as f32, (wc / cylinder) as f32, (ws / sphere) as f32))
}

/// The view cosines `n·V` at which the indirect light of a cylinder of
/// unit `axis` seen from `to_viewer` is taken, each with its weight over
/// the cylinder's projected width: [`indirect_nodes`]' cosines times
/// `sin β`, `β` the angle between the axis and the viewer. The normal at
/// angle `φ` from the one facing the viewer is `cos φ·toward + sin φ·side`
/// ([`visible_frame`]), and `to_viewer = cos β·axis + sin β·toward`, so
/// `n·V = sin β·cos φ`; across the width (along `side`, square to the
/// viewer) `sin φ` is still uniform. A needle seen along its length shows
/// the viewer its grazing, Fresnel-bright side only. As the shader's
/// `surface_indirect` (which shares the nodes' calls where `sin β` is
/// within 10⁻³ of 1).
pub fn cylinder_indirect_cosines(axis: Vec3, to_viewer: Vec3) -> [(f32, f32); 4] {
    let (toward, _) = visible_frame(axis.normalize_or(Vec3::Y), to_viewer);
    let tilt = toward.dot(to_viewer.normalize_or_zero()).clamp(0.0, 1.0);
    indirect_nodes().map(|(cosine, weight, _)| (cosine * tilt, weight))
}

/// Bevy's direct light on its standard material (a dielectric: Burley
/// diffuse, GGX specular with height-correlated Smith visibility, Schlick's
/// Fresnel with `F0 = 0.16·reflectance²` and Bevy's `f90`, and its
/// multiple-scattering energy compensation with the polynomial `F_AB`),
/// times `n·L`, for unit normal `n`, `to_viewer` and `to_light`:
/// `(diffuse, specular)`, the diffuse per unit diffuse colour (with its
/// `1/π`). What a surface of that material sends toward the viewer under a
/// light of unit irradiance; `(0, 0)` where `n` faces away from the light.
pub fn bevy_direct(
    n: Vec3,
    to_viewer: Vec3,
    to_light: Vec3,
    perceptual_roughness: f32,
    reflectance: f32,
) -> (f32, f32) {
    let n_dot_l = n.dot(to_light).clamp(0.0, 1.0);
    if n_dot_l <= 0.0 {
        return (0.0, 0.0);
    }
    let roughness = {
        let clamped = perceptual_roughness.clamp(0.089, 1.0);
        clamped * clamped
    };
    let a2 = roughness * roughness;
    let n_dot_v = n.dot(to_viewer).clamp(0.0001, 1.0);
    let h = (to_viewer + to_light).normalize_or(n);
    let (n_dot_h, l_dot_h) = (n.dot(h).clamp(0.0, 1.0), to_light.dot(h).clamp(0.0, 1.0));
    let k = roughness / (1.0 - n_dot_h * n_dot_h + (n_dot_h * roughness).powi(2));
    let distribution = k * k / PI;
    let visibility = 0.5
        / (n_dot_l * ((n_dot_v - a2 * n_dot_v) * n_dot_v + a2).sqrt()
            + n_dot_v * ((n_dot_l - a2 * n_dot_l) * n_dot_l + a2).sqrt());
    let f0 = 0.16 * reflectance * reflectance;
    let f90 = (3.0 * 16.5 * f0).clamp(0.0, 1.0);
    let fresnel = f0 + (f90 - f0) * (1.0 - l_dot_h).powi(5);
    let f_ab = bevy_f_ab(perceptual_roughness, n_dot_v);
    let specular = distribution * visibility * fresnel * (1.0 + f0 * (1.0 / (f_ab.x + f_ab.y) - 1.0));
    let burley_f90 = 0.5 + 2.0 * roughness * l_dot_h * l_dot_h;
    let scatter = |x: f32| 1.0 + (burley_f90 - 1.0) * (1.0 - x).powi(5);
    let diffuse = scatter(n_dot_l) * scatter(n_dot_v) / PI;
    (diffuse * n_dot_l, specular * n_dot_l)
}

/// Bevy's ambient light on its standard material (a dielectric) at view
/// cosine `n_dot_v`, as `ambient_light` in Bevy 0.19's `pbr_ambient.wgsl`
/// (split-sum `EnvBRDFApprox` with the polynomial `F_AB`, the diffuse at
/// roughness 1, the specular at the material's, its specular occlusion
/// from `F0 = 0.16·reflectance²`): `(diffuse, specular)`, the diffuse per
/// unit diffuse colour, both per unit ambient brightness. The diffuse does
/// not depend on the view; the specular grows toward a silhouette.
pub fn bevy_ambient(n_dot_v: f32, perceptual_roughness: f32, reflectance: f32) -> (f32, f32) {
    let n_dot_v = n_dot_v.clamp(0.0001, 1.0);
    let diffuse = bevy_f_ab(1.0, n_dot_v);
    let f0 = 0.16 * reflectance * reflectance;
    let specular = bevy_f_ab(perceptual_roughness, n_dot_v);
    let occlusion = (3.0 * 50.0 * 0.33 * f0).clamp(0.0, 1.0);
    (diffuse.x, diffuse.y + (f0 * specular.x + specular.y) * occlusion)
}

/// Bevy's polynomial scale and bias of `F0` in the split-sum specular
/// (`F_AB` without a DFG table).
fn bevy_f_ab(perceptual_roughness: f32, n_dot_v: f32) -> Vec2 {
    let r = [
        1.0 - perceptual_roughness,
        perceptual_roughness * -0.0275 + 0.0425,
        perceptual_roughness * -0.572 + 1.04,
        perceptual_roughness * 0.022 - 0.04,
    ];
    let a004 = (r[0] * r[0]).min((-9.28 * n_dot_v).exp2()) * r[0] + r[1];
    Vec2::new(-1.04 * a004 + r[2], 1.04 * a004 + r[3]).max(Vec2::splat(0.00005))
}

/// Angles between the viewer and the light at which [`SphereLight`] is
/// tabulated: `k·π/(SPHERE_LIGHT_STEPS − 1)`, as the shader's table.
pub const SPHERE_LIGHT_STEPS: usize = 64;

/// Nodes of the product Gauss–Legendre rule [`lune_average`] takes in
/// each of its two angles.
const LUNE_NODES: usize = 32;

/// The average over a sphere's projected disk (seen from unit
/// `to_viewer`) of `radiance(n)`, where the light from unit `to_light`
/// reaches: the lune between the visible and the lit hemispheres. With
/// `φ` the longitude in the plane of the viewer and the light (0 facing the
/// viewer, `α` facing the light) and `t` the latitude from that plane, the
/// lune is `φ ∈ [α − π/2, π/2]` and the disk's measure is
/// `cos²t·cos φ dt dφ / π`; a product Gauss–Legendre rule of 32 × 32 nodes
/// puts its nodes where the light is (under a light from behind, the lit
/// part of the disk is a thin crescent at its rim, where a rule over the
/// whole disk has no node).
pub fn lune_average(to_viewer: Vec3, to_light: Vec3, radiance: impl Fn(Vec3) -> f32) -> f32 {
    lune_average_pair(to_viewer, to_light, |n| (radiance(n), 0.0)).0
}

/// [`lune_average`] of two radiances at once (one evaluation a node).
fn lune_average_pair(to_viewer: Vec3, to_light: Vec3, radiance: impl Fn(Vec3) -> (f32, f32)) -> (f32, f32) {
    let to_viewer = to_viewer.try_normalize().unwrap_or(Vec3::Z);
    let to_light = to_light.try_normalize().unwrap_or(to_viewer);
    let pole = to_viewer.cross(to_light);
    let pole = pole
        .try_normalize()
        .unwrap_or_else(|| super::compact::ring_basis(to_viewer).0);
    let toward_light = pole.cross(to_viewer);
    let alpha = to_viewer.dot(to_light).clamp(-1.0, 1.0).acos();
    let (phi0, phi1) = (alpha - PI / 2.0, PI / 2.0);
    if phi1 <= phi0 {
        return (0.0, 0.0);
    }
    let nodes = gauss_legendre(LUNE_NODES);
    let (mut first, mut second) = (0.0f64, 0.0f64);
    for &(x, w) in nodes {
        let phi = 0.5 * (phi0 + phi1) + 0.5 * (phi1 - phi0) * x as f32;
        let (sin_phi, cos_phi) = phi.sin_cos();
        let meridian = cos_phi * to_viewer + sin_phi * toward_light;
        for &(y, v) in nodes {
            let t = 0.5 * PI * y as f32;
            let (sin_t, cos_t) = t.sin_cos();
            let (a, b) = radiance(cos_t * meridian + sin_t * pole);
            let weight = w * v * f64::from(cos_t * cos_t * cos_phi);
            first += weight * f64::from(a);
            second += weight * f64::from(b);
        }
    }
    // dφ = (φ1 − φ0)/2 dx, dt = π/2 dy, over the measure's π.
    let scale = f64::from(phi1 - phi0) / 4.0;
    ((first * scale) as f32, (second * scale) as f32)
}

/// The `n`-point Gauss–Legendre rule on `[−1, 1]` (nodes and weights,
/// the weights summing to 2), by Newton's method on the Legendre
/// polynomial; [`LUNE_NODES`] points, computed once.
fn gauss_legendre(n: usize) -> &'static [(f64, f64)] {
    static RULE: OnceLock<Vec<(f64, f64)>> = OnceLock::new();
    assert_eq!(n, LUNE_NODES, "one rule is kept");
    RULE.get_or_init(|| {
        (0..n)
            .map(|i| {
                let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut derivative = 1.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0f64, x);
                    for k in 2..=n {
                        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                        p0 = p1;
                        p1 = p2;
                    }
                    derivative = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    let step = p1 / derivative;
                    x -= step;
                    if step.abs() < 1e-15 {
                        break;
                    }
                }
                (x, 2.0 / ((1.0 - x * x) * derivative * derivative))
            })
            .collect()
    })
}

/// How a sphere of Bevy's standard material is lit on average over its
/// projected disk, by the angle `α` between the viewer and a light of
/// unit irradiance: `diffuse[k]` (per unit diffuse colour) and
/// `specular[k]` at `α = k·π/(SPHERE_LIGHT_STEPS − 1)`, integrated over
/// the lit part of the disk ([`lune_average`] of [`bevy_direct`]).
/// Needles spread every way show, weighted by projected area, a sphere's
/// normals; the shader lights an impostor texel's and a merged line's
/// sphere share as `E·(diffuse colour·diffuse(α) + specular(α))` for each
/// light of irradiance `E`, one table lookup a light where it took Bevy's
/// BRDF at seven normals over the disk (which got none of a sphere's light
/// from behind, where needles glow: the lit crescent lies at the rim).
#[derive(Clone, Debug, PartialEq)]
pub struct SphereLight {
    /// Mean diffuse (Burley, with its `1/π`, times `n·L`) per unit diffuse
    /// colour.
    pub diffuse: [f32; SPHERE_LIGHT_STEPS],
    /// Mean specular (GGX times `n·L`).
    pub specular: [f32; SPHERE_LIGHT_STEPS],
}

impl SphereLight {
    /// The table for a material of `perceptual_roughness` and
    /// `reflectance` (Bevy's `StandardMaterial` terms).
    pub fn new(perceptual_roughness: f32, reflectance: f32) -> Self {
        let (mut diffuse, mut specular) = ([0.0; SPHERE_LIGHT_STEPS], [0.0; SPHERE_LIGHT_STEPS]);
        for k in 0..SPHERE_LIGHT_STEPS {
            let alpha = k as f32 * PI / (SPHERE_LIGHT_STEPS - 1) as f32;
            let to_light = Vec3::new(alpha.sin(), 0.0, alpha.cos());
            (diffuse[k], specular[k]) = lune_average_pair(Vec3::Z, to_light, |n| {
                bevy_direct(n, Vec3::Z, to_light, perceptual_roughness, reflectance)
            });
        }
        Self { diffuse, specular }
    }

    /// The sphere's mean `(diffuse, specular)` seen from unit `to_viewer`
    /// under a light from unit `to_light`, interpolated linearly in `α` as
    /// the shader's `sphere_light` does.
    pub fn at(&self, to_viewer: Vec3, to_light: Vec3) -> (f32, f32) {
        let alpha = to_viewer.dot(to_light).clamp(-1.0, 1.0).acos();
        let x = alpha / PI * (SPHERE_LIGHT_STEPS - 1) as f32;
        let k = (x as usize).min(SPHERE_LIGHT_STEPS - 2);
        let f = x - k as f32;
        (
            self.diffuse[k] + f * (self.diffuse[k + 1] - self.diffuse[k]),
            self.specular[k] + f * (self.specular[k + 1] - self.specular[k]),
        )
    }
}

/// How a texel's needles are lit, as shares (in `[0, 1]`, summing to at
/// most 1) of two cylinders and a sphere: `vertical` along the tree's
/// axis, `across` along the view's right; the rest is lit as a sphere
/// (needles spread every way).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TexelShares {
    /// Share lit as a vertical cylinder.
    pub vertical: f32,
    /// Share lit as a horizontal cylinder across the view.
    pub across: f32,
}

impl TexelShares {
    /// The shares clamped to be non-negative and sum to at most 1 (a
    /// needle's own fit may lie outside; a texel's mean is clamped). A NaN
    /// share is 0.
    pub fn clamped(self) -> Self {
        let (vertical, across) = (self.vertical.max(0.0), self.across.max(0.0));
        let sum = vertical + across;
        if sum > 1.0 {
            Self {
                vertical: vertical / sum,
                across: across / sum,
            }
        } else {
            Self { vertical, across }
        }
    }

    /// Share lit as a sphere: `1 − vertical − across`.
    pub fn sphere(self) -> f32 {
        (1.0 - self.vertical - self.across).max(0.0)
    }

    /// The Lambert factor the shares give, seen from unit `to_viewer` lit
    /// from unit `to_light`, with the frame's unit `up` and `right` (the
    /// CPU reference of the impostor's fragment, which takes Bevy's BRDF
    /// at the same normals).
    pub fn lambert(self, up: Vec3, right: Vec3, to_viewer: Vec3, to_light: Vec3) -> f32 {
        self.vertical * cylinder_lambert(up, to_viewer, to_light)
            + self.across * cylinder_lambert(right, to_viewer, to_light)
            + self.sphere() * sphere_lambert(to_viewer, to_light)
    }
}

/// Suns the shares are fitted over: directions above the horizon of a view
/// looking along `−z` (a Fibonacci spiral on the upper hemisphere).
pub const FIT_SUNS: usize = 64;

/// Directions a side of the fitted table holds ([`texel_shares`]).
const SHARE_TABLE_SIDE: usize = 64;

/// The least-squares fit of a cylinder's lighting by the shares' basis
/// over [`FIT_SUNS`] suns (module docs).
struct ShareFit {
    suns: Vec<Vec3>,
    sphere: Vec<f32>,
    /// The vertical and the across cylinders' Lambert factors minus the
    /// sphere's, per sun.
    basis: [Vec<f64>; 2],
    /// The inverse of the basis' Gram matrix, row-major.
    inverse: [f64; 4],
}

impl ShareFit {
    fn new() -> Self {
        let suns: Vec<Vec3> = (0..FIT_SUNS)
            .map(|i| {
                let y = 1.0 - (i as f32 + 0.5) / FIT_SUNS as f32;
                let r = (1.0 - y * y).max(0.0).sqrt();
                let phi = i as f32 * 2.399_963_3;
                Vec3::new(r * phi.cos(), y, r * phi.sin())
            })
            .collect();
        let sphere: Vec<f32> = suns.iter().map(|&l| sphere_lambert(Vec3::Z, l)).collect();
        let mut fit = Self {
            suns,
            sphere,
            basis: [Vec::new(), Vec::new()],
            inverse: [0.0; 4],
        };
        fit.basis = [fit.residual(Vec3::Y), fit.residual(Vec3::X)];
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let (a11, a12, a22) = (
            dot(&fit.basis[0], &fit.basis[0]),
            dot(&fit.basis[0], &fit.basis[1]),
            dot(&fit.basis[1], &fit.basis[1]),
        );
        let det = a11 * a22 - a12 * a12;
        fit.inverse = [a22 / det, -a12 / det, -a12 / det, a11 / det];
        fit
    }

    /// A cylinder's Lambert factor minus the sphere's, per sun.
    fn residual(&self, axis: Vec3) -> Vec<f64> {
        self.suns
            .iter()
            .zip(&self.sphere)
            .map(|(&l, &s)| f64::from(cylinder_lambert(axis, Vec3::Z, l) - s))
            .collect()
    }

    /// The shares of a needle along unit `direction` (view frame).
    fn shares(&self, direction: Vec3) -> [f32; 2] {
        let r = self.residual(direction);
        let dot = |a: &[f64]| a.iter().zip(&r).map(|(x, y)| x * y).sum::<f64>();
        let (r1, r2) = (dot(&self.basis[0]), dot(&self.basis[1]));
        let [i11, i12, i21, i22] = self.inverse;
        [(i11 * r1 + i12 * r2) as f32, (i21 * r1 + i22 * r2) as f32]
    }
}

/// The fit's table: for directions on the upper hemisphere, mapped to a
/// square (hemi-octahedral), each one's least-squares shares.
fn share_table() -> &'static Vec<[f32; 2]> {
    static TABLE: OnceLock<Vec<[f32; 2]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let fit = ShareFit::new();
        let side = SHARE_TABLE_SIDE;
        (0..side * side)
            .map(|k| {
                let cell = Vec2::new((k % side) as f32, (k / side) as f32) / (side - 1) as f32 * 2.0 - 1.0;
                fit.shares(hemi_octahedral_direction(cell))
            })
            .collect()
    })
}

/// The unit direction on the upper hemisphere (`y ≥ 0`) at `cell` of the
/// square `[−1, 1]²` (hemi-octahedral map, Cigolle et al., JCGT 2014).
fn hemi_octahedral_direction(cell: Vec2) -> Vec3 {
    let (x, z) = (0.5 * (cell.x + cell.y), 0.5 * (cell.x - cell.y));
    Vec3::new(x, 1.0 - x.abs() - z.abs(), z).normalize()
}

/// The cell of the square `[−1, 1]²` of unit `direction` folded onto the
/// upper hemisphere (a cylinder's axis has no sign).
fn hemi_octahedral_cell(direction: Vec3) -> Vec2 {
    let d = if direction.y < 0.0 { -direction } else { direction };
    let p = Vec2::new(d.x, d.z) / (d.x.abs() + d.y.abs() + d.z.abs());
    Vec2::new(p.x + p.y, p.x - p.y)
}

/// A needle's shares (not clamped), for its unit `direction` in a view's
/// frame (`x` the view's right, `y` up, `z` toward the viewer): the
/// least-squares fit over [`FIT_SUNS`] suns above the horizon of its
/// cylinder's Lambert factor minus the sphere's, by the vertical and the
/// across cylinders' minus the sphere's (read from a 64 × 64 table,
/// bilinear; built on first use).
pub fn texel_shares(direction: Vec3) -> TexelShares {
    let table = share_table();
    let side = SHARE_TABLE_SIDE;
    let cell = (hemi_octahedral_cell(direction.try_normalize().unwrap_or(Vec3::Y)) + 1.0) * 0.5 * (side - 1) as f32;
    let cell = if cell.is_finite() {
        cell.clamp(Vec2::ZERO, Vec2::splat((side - 1) as f32))
    } else {
        Vec2::ZERO
    };
    let (x0, y0) = ((cell.x as usize).min(side - 2), (cell.y as usize).min(side - 2));
    let (fx, fy) = (cell.x - x0 as f32, cell.y - y0 as f32);
    let at = |x: usize, y: usize, i: usize| table[y * side + x][i];
    let lerp = |i: usize| {
        let top = at(x0, y0, i) + (at(x0 + 1, y0, i) - at(x0, y0, i)) * fx;
        let bottom = at(x0, y0 + 1, i) + (at(x0 + 1, y0 + 1, i) - at(x0, y0 + 1, i)) * fx;
        top + (bottom - top) * fy
    };
    TexelShares {
        vertical: lerp(0),
        across: lerp(1),
    }
}

/// The second moments of a bundle of needles' directions, each weighted
/// by its side area (`Σ aᵢ·tᵢtᵢᵀ`, and `Σ aᵢ`): what a merged line's
/// lighting needs of its needles ([`AxisSpread::alignment`]). Sums of
/// bundles are the moments of their union; a placed prototype's are its
/// own turned by the placement and scaled by its area's scale. 28 bytes:
/// the compact build keeps one per merged line while it runs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisSpread {
    /// `Σ aᵢ·tᵢtᵢᵀ`, symmetric, as `xx, yy, zz, xy, xz, yz`, m².
    pub moments: [f32; 6],
    /// `Σ aᵢ`, m².
    pub area: f32,
}

impl std::ops::Add for AxisSpread {
    type Output = Self;
    fn add(self, other: Self) -> Self {
        Self {
            moments: std::array::from_fn(|i| self.moments[i] + other.moments[i]),
            area: self.area + other.area,
        }
    }
}

impl AxisSpread {
    /// One needle from `base` to `tip` of side area `area` (nothing for a
    /// zero-length or non-finite needle, or a non-positive area).
    pub fn needle(base: Vec3, tip: Vec3, area: f32) -> Self {
        let t = tip - base;
        let length = t.length();
        if !(length > 0.0 && length.is_finite() && area > 0.0 && area.is_finite()) {
            return Self::default();
        }
        Self::from_matrix(
            Mat3::from_cols(t * t.x, t * t.y, t * t.z) * (area / (length * length)),
            area,
        )
    }

    fn from_matrix(m: Mat3, area: f32) -> Self {
        Self {
            moments: [m.x_axis.x, m.y_axis.y, m.z_axis.z, m.y_axis.x, m.z_axis.x, m.z_axis.y],
            area,
        }
    }

    fn matrix(&self) -> Mat3 {
        let [xx, yy, zz, xy, xz, yz] = self.moments;
        Mat3::from_cols(Vec3::new(xx, xy, xz), Vec3::new(xy, yy, yz), Vec3::new(xz, yz, zz))
    }

    /// The same bundle turned by unit `rotation` and its areas scaled by
    /// `area_scale` (a placement's scale squared).
    pub fn placed(self, rotation: Quat, area_scale: f32) -> Self {
        let r = Mat3::from_quat(rotation);
        Self::from_matrix(r * self.matrix() * r.transpose() * area_scale, self.area * area_scale)
    }

    /// The area-weighted mean of `cos²θ` between the needles and the unit
    /// direction of `chord`, in `[0, 1]`: 1 for needles along it, 1/3 for
    /// needles spread evenly over the sphere, 0 for needles across it. 1
    /// for an empty bundle or a zero chord (lit as one cylinder).
    pub fn alignment(&self, chord: Vec3) -> f32 {
        let length = chord.length();
        if !(self.area > 0.0 && length > 0.0 && length.is_finite()) {
            return 1.0;
        }
        let c = chord / length;
        let mean = c.dot(self.matrix() * c) / self.area;
        if mean.is_finite() { mean.clamp(0.0, 1.0) } else { 1.0 }
    }
}

/// `β` of [`bundle_cylinder_share`]: a needle at angle `θ` to a merged
/// line's chord is lit as `1 − β·sin²θ` of the chord's cylinder and the
/// rest as a sphere, the least-squares fit over views, suns and needles
/// spread evenly about the chord (the test `the_bundle_slope_is_the_fit`
/// computes it). The shader's `BUNDLE_SLOPE` (`conifer_compact.wgsl`).
pub const BUNDLE_SLOPE: f32 = 1.45;

/// The share of a merged line lit as the cylinder along its chord, for
/// needles of [`AxisSpread::alignment`] `alignment`: `1 − β·(1 −
/// alignment)`, from 1 (needles along the chord) down to `1 − β`
/// (needles across it); the rest is lit as a sphere.
pub fn bundle_cylinder_share(alignment: f32) -> f32 {
    1.0 - BUNDLE_SLOPE * (1.0 - valid_alignment(alignment))
}

/// `alignment` in `[0, 1]`; a NaN is 1 (lit as one cylinder).
fn valid_alignment(alignment: f32) -> f32 {
    if alignment.is_nan() {
        1.0
    } else {
        alignment.clamp(0.0, 1.0)
    }
}

/// Steps of a stored alignment: it is kept in 4 bits of a merged line
/// ([`super::compact`]).
pub const ALIGNMENT_STEPS: u32 = 15;

/// `alignment` rounded to its 4-bit code (`0..=ALIGNMENT_STEPS`).
pub fn alignment_code(alignment: f32) -> u32 {
    (valid_alignment(alignment) * ALIGNMENT_STEPS as f32).round() as u32
}

/// The alignment a 4-bit code stands for (the shader's decoding).
pub fn alignment_from_code(code: u32) -> f32 {
    code.min(ALIGNMENT_STEPS) as f32 / ALIGNMENT_STEPS as f32
}

/// The Lambert factor of a merged line along `chord` whose needles have
/// alignment `alignment`, seen from unit `to_viewer`, lit from unit
/// `to_light`: its cylinder share of the chord's cylinder, the rest of a
/// sphere, never below 0 (the CPU reference of the line fragment shader
/// under `LineLighting::Bundle`).
pub fn bundle_lambert(chord: Vec3, alignment: f32, to_viewer: Vec3, to_light: Vec3) -> f32 {
    let share = bundle_cylinder_share(alignment);
    (share * cylinder_lambert(chord, to_viewer, to_light) + (1.0 - share) * sphere_lambert(to_viewer, to_light))
        .max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn direction() -> impl Strategy<Value = Vec3> {
        (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0)
            .prop_filter("not zero", |(x, y, z)| x * x + y * y + z * z > 0.01)
            .prop_map(|(x, y, z)| Vec3::new(x, y, z).normalize())
    }

    /// Bevy's BRDF times `n·L` (Burley diffuse of albedo 0.05, GGX
    /// specular with height-correlated Smith visibility and Schlick's
    /// Fresnel, F0 0.04, perceptual roughness 0.6): what a needle's surface
    /// sends toward `v` under a unit light from `l`.
    fn bevy_radiance(n: Vec3, v: Vec3, l: Vec3) -> f32 {
        let n_dot_l = n.dot(l);
        if n_dot_l <= 0.0 {
            return 0.0;
        }
        let roughness = 0.6f32 * 0.6;
        let a2 = roughness * roughness;
        let n_dot_v = n.dot(v).max(1e-4);
        let h = (v + l).normalize_or(n);
        let (n_dot_h, l_dot_h) = (n.dot(h).max(0.0), l.dot(h).max(0.0));
        let d = n_dot_h * n_dot_h * (a2 - 1.0) + 1.0;
        let distribution = a2 / (PI * d * d);
        let visibility = 0.5
            / (n_dot_l * (n_dot_v * n_dot_v * (1.0 - a2) + a2).sqrt()
                + n_dot_v * (n_dot_l * n_dot_l * (1.0 - a2) + a2).sqrt());
        let fresnel = 0.04 + 0.96 * (1.0 - l_dot_h).powi(5);
        let f90 = 0.5 + 2.0 * roughness * l_dot_h * l_dot_h;
        let burley = (1.0 + (f90 - 1.0) * (1.0 - n_dot_l).powi(5)) * (1.0 + (f90 - 1.0) * (1.0 - n_dot_v).powi(5)) / PI;
        (0.05 * burley + distribution * visibility * fresnel) * n_dot_l
    }

    /// Numbers in `[−1, 1]` from a xorshift generator seeded with `state`.
    fn xorshift(mut state: u32) -> impl FnMut() -> f32 {
        move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f32 / u32::MAX as f32 * 2.0 - 1.0
        }
    }

    /// Needles in 500 directions lit from behind (15° up, the eval's back
    /// sun): the four nodes over the lit part of the width give the
    /// dense integral's light to 3 % (1.029 of it); over the whole width
    /// they gave about half (0.527: the specular rim lies in the edge band).
    #[test]
    fn four_lit_normals_catch_a_cylinder_lit_from_behind() {
        let (viewer, low) = (Vec3::Z, 15f32.to_radians());
        let light = Vec3::new(0.0, low.sin(), -low.cos());
        let (mut dense, mut lit, mut whole) = (0.0f64, 0.0f64, 0.0f64);
        let mut next = xorshift(0x2545_f491);
        for _ in 0..500 {
            let axis = Vec3::new(next(), next(), next()).normalize_or(Vec3::Y);
            let radiance = |n: Vec3| bevy_radiance(n, viewer, light);
            let (toward, side) = visible_frame(axis, viewer);
            let steps = 4000;
            dense += (0..steps)
                .map(|k| {
                    let s = -1.0 + (k as f32 + 0.5) * 2.0 / steps as f32;
                    f64::from(radiance((1.0 - s * s).sqrt() * toward + s * side))
                })
                .sum::<f64>()
                / f64::from(steps);
            lit += f64::from(across_average(axis, viewer, light, radiance));
            whole += 0.5
                * ACROSS_NODES
                    .iter()
                    .map(|&(s, w)| f64::from(w * radiance((1.0 - s * s).sqrt() * toward + s * side)))
                    .sum::<f64>();
        }
        println!(
            "lit from behind: lit-part rule {:.3}, whole-width rule {:.3} of the dense integral",
            lit / dense,
            whole / dense
        );
        assert!((lit / dense - 1.0).abs() < 0.05, "{}", lit / dense);
        assert!(whole / dense < 0.75, "{}", whole / dense);
    }

    proptest! {
        /// Anywhere on a side face of a prism whose ring faces the viewer
        /// (any face not turned away), the round normal is the cylinder's
        /// at the fragment's offset across the width (its position along
        /// `side` over the radius), facing the viewer; on a cap it is the
        /// axis.
        #[test]
        fn a_prism_is_shaded_as_its_round_cylinder(
            sides in 3u32..16,
            face in 0u32..16,
            t in 0.0f32..=1.0,
            axis in (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0),
            viewer in (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0),
        ) {
            let axis = Vec3::new(axis.0, axis.1, axis.2);
            let viewer = Vec3::new(viewer.0, viewer.1, viewer.2);
            prop_assume!(axis.length() > 0.1 && viewer.length() > 0.1);
            let axis = axis.normalize();
            let viewer = viewer.normalize();
            prop_assume!(axis.cross(viewer).length() > 0.05);
            let (toward, side) = visible_frame(axis, viewer);
            // Corners of the ring (as `prism_vertex`: the first toward the
            // viewer), on the visible half.
            let corner = |k: u32| {
                let angle = std::f32::consts::TAU * k as f32 / sides as f32;
                toward * angle.cos() + side * angle.sin()
            };
            // Any face in front (a triangle's faces reach past the rim).
            let in_front: Vec<u32> = (0..sides)
                .filter(|&k| (corner(k) + corner(k + 1)).dot(toward) > 0.0)
                .collect();
            let k = in_front[face as usize % in_front.len()];
            let (a, b) = (corner(k), corner(k + 1));
            let normal = a.lerp(b, t);
            let position = a.lerp(b, t); // radius 1, centre 0
            let round = round_prism_normal(normal, side, toward);
            let s = position.dot(side);
            prop_assert!((round.length() - 1.0).abs() < 1e-4);
            prop_assert!((round.dot(side) - s).abs() < 1e-4);
            prop_assert!((round.dot(toward) - (1.0 - s * s).max(0.0).sqrt()).abs() < 2e-3);
            prop_assert!(round.dot(axis).abs() < 1e-4);
            prop_assert!((round_prism_normal(axis, side, toward) - axis).length() < 1e-5);
        }
    }

    /// Dense averages of `g(n·V)` over a cylinder's projected width and a
    /// sphere's disk.
    fn dense_view_averages(g: impl Fn(f32) -> f32) -> (f32, f32) {
        let n = 200_000;
        let (mut cylinder, mut sphere) = (0.0f64, 0.0f64);
        for i in 0..n {
            let u = (i as f32 + 0.5) / n as f32;
            let s = 2.0 * u - 1.0;
            cylinder += f64::from(g((1.0 - s * s).sqrt()));
            sphere += f64::from(g(u.sqrt()));
        }
        ((cylinder / f64::from(n)) as f32, (sphere / f64::from(n)) as f32)
    }

    fn node_averages(g: impl Fn(f32) -> f32) -> (f32, f32) {
        indirect_nodes().iter().fold((0.0, 0.0), |(c, s), &(cosine, wc, ws)| {
            (c + wc * g(cosine), s + ws * g(cosine))
        })
    }

    #[test]
    fn indirect_nodes_average_over_a_cylinder_and_a_sphere() {
        let nodes = indirect_nodes();
        assert!((nodes.iter().map(|n| n.1).sum::<f32>() - 1.0).abs() < 1e-6);
        assert!((nodes.iter().map(|n| n.2).sum::<f32>() - 1.0).abs() < 1e-6);
        // Smooth functions of the cosine: a constant, its square, Schlick's
        // Fresnel factor.
        for g in [|_: f32| 1.0, |c: f32| c * c, |c: f32| (1.0 - c).powi(5)] {
            let (cylinder, sphere) = dense_view_averages(g);
            let (nodes_cylinder, nodes_sphere) = node_averages(g);
            assert!(
                (nodes_cylinder - cylinder).abs() <= 2e-3 * cylinder.max(0.01),
                "{nodes_cylinder} {cylinder}"
            );
            assert!(
                (nodes_sphere - sphere).abs() <= 2e-3 * sphere.max(0.01),
                "{nodes_sphere} {sphere}"
            );
        }
        // Bevy's ambient specular `F0·A + B` (F0 0.04: reflectance 0.5),
        // kinked where `exp2(−9.28 n·V)` meets `(1 − roughness)²`.
        for roughness in [0.3f32, 0.5, 0.6, 0.8, 1.0] {
            let g = |c: f32| {
                let ab = bevy_f_ab(roughness, c);
                0.04 * ab.x + ab.y
            };
            let (cylinder, sphere) = dense_view_averages(g);
            let (nodes_cylinder, nodes_sphere) = node_averages(g);
            let facing = g(1.0);
            println!(
                "roughness {roughness}: cylinder {cylinder:.5} nodes {nodes_cylinder:.5}, sphere {sphere:.5} nodes {nodes_sphere:.5}, facing {facing:.5}"
            );
            assert!((nodes_cylinder / cylinder - 1.0).abs() < 0.08);
            assert!((nodes_sphere / sphere - 1.0).abs() < 0.08);
        }
    }

    /// Seen along its axis, a cylinder's nodes still average `g(n·V)` over
    /// its visible half: against a dense sum over the half-circle of normals
    /// `cos φ·toward + sin φ·side`, weighted by the projected width, for
    /// Bevy's ambient specular. The cosines of a cylinder seen square-on
    /// (the nodes before the tilt) miss it by 43 % at 30° and 63 % at 15°.
    #[test]
    fn tilted_cylinders_take_their_indirect_light_at_their_own_cosines() {
        let roughness = 0.6f32;
        let g = |c: f32| {
            let ab = bevy_f_ab(roughness, c.max(1e-4));
            0.04 * ab.x + ab.y
        };
        let axis = Vec3::new(0.3, 0.9, -0.2).normalize();
        let mut worst_square_on = 0.0f32;
        for degrees in [90.0f32, 70.0, 50.0, 30.0, 15.0] {
            // A viewer at `degrees` from the axis.
            let (_, side) = visible_frame(axis, Vec3::Z);
            let across = axis.cross(side).normalize();
            let viewer = (axis * degrees.to_radians().cos() + across * degrees.to_radians().sin()).normalize();
            let (toward, side) = visible_frame(axis, viewer);
            let n = 100_000;
            let mut dense = 0.0f64;
            let mut width = 0.0f64;
            for i in 0..n {
                let phi = ((i as f64 + 0.5) / n as f64 - 0.5) * std::f64::consts::PI;
                let normal = toward * phi.cos() as f32 + side * phi.sin() as f32;
                dense += f64::from(g(normal.dot(viewer))) * phi.cos();
                width += phi.cos();
            }
            let dense = (dense / width) as f32;
            let nodes: f32 = cylinder_indirect_cosines(axis, viewer)
                .iter()
                .map(|&(c, w)| w * g(c))
                .sum();
            let square_on: f32 = indirect_nodes().iter().map(|&(c, w, _)| w * g(c)).sum();
            println!("{degrees}°: dense {dense:.5}, nodes {nodes:.5}, square-on nodes {square_on:.5}");
            assert!((nodes / dense - 1.0).abs() < 0.08, "{degrees}°: {nodes} vs {dense}");
            worst_square_on = worst_square_on.max(1.0 - square_on / dense);
        }
        assert!(worst_square_on > 0.4, "{worst_square_on}");
    }

    /// Bevy's ambient light, worked by hand from `F_AB`'s polynomial: at
    /// roughness 1 its scale is `−1.04·0.015 + 0.468 = 0.4524` at every
    /// view cosine and its bias clamps to `5·10⁻⁵`; a surface without
    /// reflectance has no specular past that bias (its occlusion is 0),
    /// and the specular of `F0 = 0.04` at roughness 0.6 grows toward a
    /// silhouette, from `0.04·(−1.04·a + 0.6968) + (1.04·a − 0.0268)`
    /// facing the viewer, `a = 0.4·min(0.16, 2^−9.28) + 0.026`.
    #[test]
    fn bevy_ambient_is_bevys_split_sum() {
        for k in 0..=10 {
            let n_dot_v = k as f32 / 10.0;
            let (diffuse, specular) = bevy_ambient(n_dot_v, 0.6, 0.0);
            assert!((diffuse - 0.4524).abs() < 1e-5, "{n_dot_v}: {diffuse}");
            assert!((specular - 0.00005).abs() < 1e-7, "{n_dot_v}: {specular}");
        }
        let facing = bevy_ambient(1.0, 0.6, 0.5).1;
        let a = 0.4 * 0.16f32.min((-9.28f32).exp2()) + 0.026;
        let expected = 0.04 * (-1.04 * a + 0.6968) + (1.04 * a - 0.0268) + 0.00005;
        assert!((facing - expected).abs() < 1e-5, "{facing} against {expected}");
        let grazing = bevy_ambient(0.05, 0.6, 0.5).1;
        assert!(grazing > 1.5 * facing, "{grazing} against {facing}");
    }

    /// `bevy_direct` is the test's independent model of Bevy's BRDF
    /// (Burley of albedo 0.05 plus GGX, F0 0.04) to 5 % (the model
    /// leaves out Bevy's multiple-scattering compensation), over random
    /// normals, viewers and lights.
    #[test]
    fn bevy_direct_is_bevys_brdf() {
        let mut next = xorshift(0x9e37_79b9);
        let mut compared = 0;
        for _ in 0..2000 {
            let [n, v, l] = [(); 3].map(|_| Vec3::new(next(), next(), next()).normalize_or(Vec3::Y));
            if n.dot(v) < 0.05 {
                continue;
            }
            let (diffuse, specular) = bevy_direct(n, v, l, 0.6, 0.5);
            let model = bevy_radiance(n, v, l);
            let ours = 0.05 * diffuse + specular;
            assert!(
                (ours - model).abs() <= 0.05 * model + 1e-7,
                "{ours} vs {model} at n {n}, v {v}, l {l}"
            );
            compared += 1;
        }
        assert!(compared > 500, "{compared}");
    }

    /// A sphere's mean light by the table against a dense grid over its
    /// projected disk (400 × 400 pixels), with Bevy's BRDF at roughness
    /// 0.6, under the eval's suns and three more behind it: within 2 %
    /// (1.1 % from behind, where the grid's own steps are coarse across
    /// the lit crescent; nearly straight behind, where the crescent is 3°
    /// wide, within 2 % of a tenth of the front's light). From behind (15°
    /// up, the eval's back sun) the sphere still sends 0.33 of what it sends lit from the front: the specular
    /// glow of its lit rim, which seven normals over the disk missed
    /// entirely.
    #[test]
    fn the_sphere_table_catches_a_sphere_lit_from_behind() {
        let viewer = Vec3::Z;
        let low = 15f32.to_radians();
        let suns = [
            ("front", Vec3::new(4.0, 8.0, 6.0).normalize()),
            ("side", Vec3::new(low.cos(), low.sin(), 0.0)),
            ("back", Vec3::new(0.0, low.sin(), -low.cos())),
            ("back side", Vec3::new(0.7, 0.3, -0.6).normalize()),
            ("high behind", Vec3::new(0.0, 0.9, -0.4).normalize()),
            ("grazing", Vec3::new(0.05, 0.0, -1.0).normalize()),
        ];
        let table = SphereLight::new(0.6, 0.5);
        let mut front = 0.0;
        for (name, light) in suns {
            let (mut dense, mut count) = (0.0f64, 0u32);
            let steps = 400;
            for i in 0..steps {
                for j in 0..steps {
                    let x = -1.0 + (i as f32 + 0.5) * 2.0 / steps as f32;
                    let y = -1.0 + (j as f32 + 0.5) * 2.0 / steps as f32;
                    if x * x + y * y >= 1.0 {
                        continue;
                    }
                    let n = Vec3::new(x, y, (1.0 - x * x - y * y).sqrt());
                    let (d, s) = bevy_direct(n, viewer, light, 0.6, 0.5);
                    dense += f64::from(0.05 * d + s);
                    count += 1;
                }
            }
            let dense = (dense / f64::from(count)) as f32;
            let (d, s) = table.at(viewer, light);
            let ours = 0.05 * d + s;
            if name == "front" {
                front = ours;
            }
            let lune = lune_average(viewer, light, |n| {
                let (d, s) = bevy_direct(n, viewer, light, 0.6, 0.5);
                0.05 * d + s
            });
            println!(
                "{name}: table {ours:.6}, lune rule {lune:.6}, dense {dense:.6}, ratio {:.4}",
                ours / dense
            );
            assert!(
                (ours - dense).abs() < 0.02 * dense.max(0.1 * front),
                "{name}: {ours} vs {dense}"
            );
            if name == "back" {
                assert!(ours > 0.25 * front, "back {ours} vs front {front}");
            }
        }
    }

    #[test]
    fn lambert_average_has_the_known_values() {
        let (axis, viewer) = (Vec3::Y, Vec3::Z);
        assert!((cylinder_lambert(axis, viewer, Vec3::Z) - PI / 4.0).abs() < 1e-6);
        assert!(cylinder_lambert(axis, viewer, -Vec3::Z).abs() < 1e-6);
        assert!(cylinder_lambert(axis, viewer, Vec3::Y).abs() < 1e-6);
        // From the side, half the visible width is lit: ∫ cos over a quarter.
        assert!((cylinder_lambert(axis, viewer, Vec3::X) - 0.25).abs() < 1e-6);
    }

    proptest! {
        /// The shader's four normals over the lit part of the width average
        /// the Lambert factor to within 0.006 of the exact integral (the
        /// `√(1 − s²)` of a cylinder lit from the viewer is the worst; the
        /// rule over the whole width was held to 0.03, for the kink where
        /// `n·L` turns negative), and a line lit like a strip facing the viewer
        /// would be up to 4/π brighter.
        #[test]
        fn four_normals_average_the_cylinder(axis in direction(), viewer in direction(), light in direction()) {
            let exact = cylinder_lambert(axis, viewer, light);
            let quadrature = across_average(axis, viewer, light, |n| n.dot(light).max(0.0));
            prop_assert!((quadrature - exact).abs() < 0.006, "{quadrature} vs {exact}");
            let (s0, s1) = lit_across(axis, viewer, light);
            prop_assert!(-1.0 <= s0 && s0 <= s1 && s1 <= 1.0, "[{s0}, {s1}]");
            let (toward, _) = visible_frame(axis, viewer);
            prop_assert!(toward.dot(light).max(0.0) <= exact * 4.0 / PI + 0.03);
        }
    }

    /// A band of a cylinder's width is lit as the part of its round
    /// surface it covers: the closed form agrees with a fine sum over the
    /// band, the whole width is the cylinder's mean, two halves average to
    /// it, and the shader's four-point rule is within 1 % of the closed form.
    #[test]
    fn a_band_of_a_cylinder_is_lit_as_its_part_of_the_surface() {
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32
        };
        for _ in 0..200 {
            let unit = |x: f32, y: f32, z: f32| Vec3::new(x - 0.5, y - 0.5, z - 0.5).normalize_or(Vec3::Y);
            let (axis, to_viewer, to_light) = (
                unit(next(), next(), next()),
                unit(next(), next(), next()),
                unit(next(), next(), next()),
            );
            let (a, b) = (2.0 * next() - 1.0, 2.0 * next() - 1.0);
            let band = (a.min(b), a.max(b));
            if band.1 - band.0 < 0.05 {
                continue;
            }
            let exact = band_lambert(axis, to_viewer, to_light, band);
            let (toward, side) = visible_frame(axis, to_viewer);
            let n = 20_000;
            let fine = (0..n)
                .map(|i| {
                    let s = band.0 + (band.1 - band.0) * (i as f32 + 0.5) / n as f32;
                    ((1.0 - s * s).max(0.0).sqrt() * toward + s * side)
                        .dot(to_light)
                        .max(0.0)
                })
                .sum::<f32>()
                / n as f32;
            assert!((exact - fine).abs() < 2e-4, "{exact} vs {fine}");
            let rule = band_average(axis, to_viewer, to_light, band, |n| n.dot(to_light).max(0.0));
            assert!((rule - exact).abs() < 0.01 * exact.max(0.05), "{rule} vs {exact}");
            let whole = band_lambert(axis, to_viewer, to_light, (-1.0, 1.0));
            assert!((whole - cylinder_lambert(axis, to_viewer, to_light)).abs() < 1e-5);
            let halves = 0.5
                * (band_lambert(axis, to_viewer, to_light, (-1.0, 0.0))
                    + band_lambert(axis, to_viewer, to_light, (0.0, 1.0)));
            assert!((halves - whole).abs() < 1e-5, "{halves} vs {whole}");
            let average = band_average(axis, to_viewer, to_light, (-1.0, 1.0), |n| n.dot(to_light).max(0.0));
            let across = across_average(axis, to_viewer, to_light, |n| n.dot(to_light).max(0.0));
            assert!((average - across).abs() < 1e-6, "{average} vs {across}");
        }
        // An upright trunk seen from +z, lit from its right: its right
        // edge's band is bright, its left edge's dark.
        let light = Vec3::new(1.0, 0.2, 0.3).normalize();
        let left = band_lambert(Vec3::Y, Vec3::Z, light, (-1.0, -0.8));
        let right = band_lambert(Vec3::Y, Vec3::Z, light, (0.8, 1.0));
        assert!(left < 0.05 && right > 0.5, "{left} {right}");
    }

    #[test]
    fn sphere_lambert_has_the_known_values() {
        assert!((sphere_lambert(Vec3::Z, Vec3::Z) - 2.0 / 3.0).abs() < 1e-6);
        assert!(sphere_lambert(Vec3::Z, -Vec3::Z).abs() < 1e-6);
        // Half moon: 2 / 3π.
        assert!((sphere_lambert(Vec3::Z, Vec3::X) - 2.0 / (3.0 * PI)).abs() < 1e-6);
    }

    /// Cylinders with axes spread evenly over the sphere, weighted by their
    /// projected length, are lit as a sphere (to the spiral's precision).
    #[test]
    fn evenly_spread_cylinders_are_lit_as_a_sphere() {
        let n = 8192;
        let axes: Vec<Vec3> = (0..n)
            .map(|i| {
                let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - y * y).sqrt();
                let phi = i as f32 * 2.399_963_3;
                Vec3::new(r * phi.cos(), y, r * phi.sin())
            })
            .collect();
        let viewer = Vec3::Z;
        for light in [
            Vec3::Z,
            Vec3::new(1.0, 1.0, 1.0).normalize(),
            Vec3::X,
            Vec3::new(0.0, 0.3, -1.0).normalize(),
        ] {
            let (mut sum, mut weight) = (0.0, 0.0);
            for &axis in &axes {
                let w = (1.0 - axis.dot(viewer).powi(2)).max(0.0).sqrt();
                sum += w * cylinder_lambert(axis, viewer, light);
                weight += w;
            }
            let sphere = sphere_lambert(viewer, light);
            assert!(
                (sum / weight - sphere).abs() < 0.003,
                "{light}: {} vs {sphere}",
                sum / weight
            );
        }
    }

    #[test]
    fn a_vertical_needle_is_the_vertical_share_and_one_across_the_across_share() {
        let up = texel_shares(Vec3::Y);
        assert!((up.vertical - 1.0).abs() < 1e-3 && up.across.abs() < 1e-3, "{up:?}");
        for across in [Vec3::X, -Vec3::X] {
            let shares = texel_shares(across);
            assert!(
                shares.vertical.abs() < 1e-3 && (shares.across - 1.0).abs() < 1e-3,
                "{shares:?}"
            );
        }
        assert_eq!(texel_shares(Vec3::Y), texel_shares(-Vec3::Y));
        let shares = texel_shares(Vec3::NAN);
        assert!(shares.vertical.is_finite() && shares.across.is_finite());
        assert_eq!(
            TexelShares {
                vertical: f32::NAN,
                across: 0.0
            }
            .clamped(),
            TexelShares {
                vertical: 0.0,
                across: 0.0
            }
        );
        assert_eq!(
            TexelShares {
                vertical: 3.0,
                across: 1.0
            }
            .clamped(),
            TexelShares {
                vertical: 0.75,
                across: 0.25
            }
        );
    }

    proptest! {
        /// The lune rule averages the sphere's Lambert factor to within
        /// 1e-4 of the exact phase function, from every side.
        #[test]
        fn the_lune_rule_averages_the_sphere(viewer in direction(), light in direction()) {
            let exact = sphere_lambert(viewer, light);
            let quadrature = lune_average(viewer, light, |n| n.dot(light).max(0.0));
            prop_assert!((quadrature - exact).abs() < 1e-4, "{quadrature} vs {exact}");
        }

        /// The table, interpolated between its angles, gives a sphere's
        /// mean light to within 0.5 % of its brightest (diffuse and
        /// specular from the viewer's side): the shader's lookup stands for
        /// the integral at every angle, not only at the tabulated ones.
        /// The diffuse holds to 0.1 % of its own brightest, the specular to
        /// 6 % of its own: its largest error is in the last step before a
        /// light straight behind the sphere, where grazing Fresnel spikes
        /// between two entries (5.3 % of the brightest specular at
        /// roughness 0.2, 178.7°, scanned every 0.045°; 0.25 % of the
        /// brightest light).
        #[test]
        fn the_sphere_table_interpolates_the_integral(
            viewer in direction(),
            light in direction(),
            roughness in 0.2f32..1.0,
        ) {
            let table = SphereLight::new(roughness, 0.5);
            let (diffuse, specular) = table.at(viewer, light);
            let exact_diffuse = lune_average(viewer, light, |n| bevy_direct(n, viewer, light, roughness, 0.5).0);
            let exact_specular = lune_average(viewer, light, |n| bevy_direct(n, viewer, light, roughness, 0.5).1);
            let brightest = |values: &[f32]| values.iter().copied().fold(0.0f32, f32::max);
            let brightest_light = brightest(&table.diffuse) + brightest(&table.specular);
            prop_assert!((diffuse - exact_diffuse).abs() < 1e-3 * brightest(&table.diffuse), "{diffuse} vs {exact_diffuse}");
            prop_assert!((specular - exact_specular).abs() < 5e-3 * brightest_light, "{specular} vs {exact_specular}");
            prop_assert!((specular - exact_specular).abs() < 0.06 * brightest(&table.specular), "{specular} vs {exact_specular}");
        }

        /// The table's bilinear shares light a needle as the direct fit
        /// does, to 0.01 of the Lambert factor under every fitted sun, but
        /// within 16° of the view axis: a needle pointing nearly at the
        /// viewer shows its upper or its lower side as it tips, and its
        /// fit jumps there (its projected area, its weight in a texel, is
        /// under a quarter of a needle seen side on). The shares
        /// themselves are compared through their lighting: a needle
        /// tipped toward the viewer fits shares far outside `[0, 1]`
        /// (−1.6 at 37°) whose basis lights nearly alike, so their own
        /// difference says little.
        #[test]
        fn the_table_lights_as_the_fit(axis in direction()) {
            prop_assume!(axis.z.abs() < 0.96);
            let fit = ShareFit::new();
            let [vertical, across] = fit.shares(axis);
            let table = texel_shares(axis);
            for (index, &sun) in fit.suns.iter().enumerate() {
                let lit = |v: f32, a: f32| {
                    fit.sphere[index] + v * fit.basis[0][index] as f32 + a * fit.basis[1][index] as f32
                };
                let (direct, tabled) = (lit(vertical, across), lit(table.vertical, table.across));
                prop_assert!((direct - tabled).abs() < 0.01,
                    "sun {sun}: {tabled} vs {direct} ({table:?} vs {vertical} {across})");
            }
        }
    }

    /// Unit directions spread evenly over the sphere (a Fibonacci spiral).
    fn sphere_spiral(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - y * y).max(0.0).sqrt();
                let phi = i as f32 * 2.399_963_3;
                Vec3::new(r * phi.cos(), y, r * phi.sin())
            })
            .collect()
    }

    /// A needle at `theta` to the z axis, turned `phi` about it.
    fn tilted(theta: f32, phi: f32) -> Vec3 {
        Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
    }

    /// `BUNDLE_SLOPE` is the least-squares `β` of `a(θ) = 1 − β·sin²θ`:
    /// over views and suns spread evenly over the sphere and needles spread
    /// evenly about the chord (weight `sin θ`), it minimises the summed
    /// squared difference between a needle's Lambert factor and
    /// `a·cylinder(chord) + (1 − a)·sphere`.
    #[test]
    fn the_bundle_slope_is_the_fit() {
        let chord = Vec3::Z;
        let directions = sphere_spiral(40);
        let pairs: Vec<(Vec3, Vec3, f64)> = directions
            .iter()
            .flat_map(|&v| directions.iter().map(move |&l| (v, l)))
            .map(|(v, l)| (v, l, f64::from(cylinder_lambert(chord, v, l) - sphere_lambert(v, l))))
            .collect();
        let (mut numerator, mut denominator) = (0.0f64, 0.0f64);
        let thetas = 36;
        for i in 0..thetas {
            let theta = (i as f32 + 0.5) / thetas as f32 * PI / 2.0;
            let (sin2, weight) = (f64::from(theta.sin().powi(2)), f64::from(theta.sin()));
            for j in 0..12 {
                let t = tilted(theta, j as f32 * PI / 6.0 + 0.1);
                for &(v, l, chord_residual) in &pairs {
                    let needle_residual = f64::from(cylinder_lambert(t, v, l) - sphere_lambert(v, l));
                    numerator += weight * (chord_residual - needle_residual) * sin2 * chord_residual;
                    denominator += weight * sin2 * sin2 * chord_residual * chord_residual;
                }
            }
        }
        let beta = numerator / denominator;
        println!("least-squares bundle slope: {beta:.4}");
        assert!(
            (beta - f64::from(BUNDLE_SLOPE)).abs() < 0.02,
            "fit {beta} vs {BUNDLE_SLOPE}"
        );
    }

    #[test]
    fn alignment_of_known_bundles() {
        let along = AxisSpread::needle(Vec3::ZERO, Vec3::Z, 1.0);
        assert_eq!(along.alignment(Vec3::Z), 1.0);
        assert_eq!(along.alignment(-Vec3::Z * 3.0), 1.0);
        assert!(along.alignment(Vec3::X) < 1e-6);
        let even = sphere_spiral(4096).into_iter().fold(AxisSpread::default(), |sum, t| {
            sum + AxisSpread::needle(Vec3::ONE, Vec3::ONE + t, 0.5)
        });
        for chord in [Vec3::X, Vec3::Y, Vec3::new(1.0, -2.0, 0.5)] {
            assert!(
                (even.alignment(chord) - 1.0 / 3.0).abs() < 2e-3,
                "{}",
                even.alignment(chord)
            );
        }
        // Two rows across the shoot, as a fir's: across the chord along the shoot.
        let rows = AxisSpread::needle(Vec3::ZERO, Vec3::X, 1.0) + AxisSpread::needle(Vec3::ZERO, -Vec3::X, 1.0);
        assert!(rows.alignment(Vec3::Z) < 1e-6);
        // Weighted by area.
        let mixed = AxisSpread::needle(Vec3::ZERO, Vec3::Z, 3.0) + AxisSpread::needle(Vec3::ZERO, Vec3::X, 1.0);
        assert!((mixed.alignment(Vec3::Z) - 0.75).abs() < 1e-6);
        // Nothing to light by: one cylinder.
        for empty in [
            AxisSpread::default(),
            AxisSpread::needle(Vec3::ZERO, Vec3::ZERO, 1.0),
            AxisSpread::needle(Vec3::ZERO, Vec3::NAN, 1.0),
            AxisSpread::needle(Vec3::ZERO, Vec3::X, 0.0),
        ] {
            assert_eq!(empty.alignment(Vec3::Y), 1.0);
        }
        assert_eq!(mixed.alignment(Vec3::ZERO), 1.0);
        assert_eq!(mixed.alignment(Vec3::NAN), 1.0);
        assert_eq!(bundle_cylinder_share(1.0), 1.0);
        assert!((bundle_cylinder_share(0.0) - (1.0 - BUNDLE_SLOPE)).abs() < 1e-6);
        assert_eq!(bundle_cylinder_share(f32::NAN), 1.0);
        assert_eq!(alignment_code(f32::NAN), ALIGNMENT_STEPS);
        assert_eq!(alignment_from_code(99), 1.0);
    }

    proptest! {
        /// A placed bundle's alignment along its placed chord is the
        /// prototype's along its own, and its area scales.
        #[test]
        fn placement_keeps_the_alignment(
            a in direction(), b in direction(), chord in direction(), axis in direction(),
            angle in -3.0f32..3.0, scale in 0.1f32..10.0,
        ) {
            let spread = AxisSpread::needle(Vec3::ZERO, a, 0.3) + AxisSpread::needle(Vec3::ONE, Vec3::ONE + b, 0.7);
            let rotation = Quat::from_axis_angle(axis, angle);
            let placed = spread.placed(rotation, scale * scale);
            prop_assert!((placed.alignment(rotation * chord) - spread.alignment(chord)).abs() < 1e-4);
            prop_assert!((placed.area - spread.area * scale * scale).abs() < 1e-5 * placed.area.max(1.0));
        }

        /// The 4-bit code keeps an alignment to half a step.
        #[test]
        fn the_alignment_code_rounds_to_half_a_step(alignment in 0.0f32..=1.0) {
            let decoded = alignment_from_code(alignment_code(alignment));
            prop_assert!((decoded - alignment).abs() <= 0.5 / ALIGNMENT_STEPS as f32 + 1e-6);
        }
    }

    /// Needles fanned about a chord, as a fascicle's or a fir's two rows,
    /// are lit closer to their own mean by the bundle (its alignment's
    /// share of the chord's cylinder, the rest a sphere) than by the
    /// chord's cylinder alone: mean |error| of the Lambert factor over
    /// views and suns spread over the sphere.
    #[test]
    fn a_fanned_bundle_is_lit_closer_to_its_needles_than_its_chord() {
        let directions = sphere_spiral(48);
        let chord = Vec3::Z;
        for (name, needles) in [
            // A cone of needles 40° round the chord.
            (
                "cone 40°",
                (0..12).map(|j| tilted(0.7, j as f32 * PI / 6.0)).collect::<Vec<_>>(),
            ),
            // Two rows standing across the chord, 70° to it.
            (
                "two rows",
                vec![
                    tilted(1.22, 0.0),
                    tilted(1.22, PI),
                    tilted(1.22, 0.1),
                    tilted(1.22, PI + 0.1),
                ],
            ),
            // Shoots every way.
            ("every way", sphere_spiral(64)),
        ] {
            let spread = needles.iter().fold(AxisSpread::default(), |sum, &t| {
                sum + AxisSpread::needle(Vec3::ZERO, t, 1.0)
            });
            let alignment = spread.alignment(chord);
            let (mut chord_error, mut bundle_error, mut count) = (0.0f32, 0.0f32, 0);
            for &v in &directions {
                for &l in &directions {
                    let exact = needles.iter().map(|&t| cylinder_lambert(t, v, l)).sum::<f32>() / needles.len() as f32;
                    chord_error += (cylinder_lambert(chord, v, l) - exact).abs();
                    bundle_error += (bundle_lambert(chord, alignment, v, l) - exact).abs();
                    count += 1;
                }
            }
            let (chord_error, bundle_error) = (chord_error / count as f32, bundle_error / count as f32);
            println!("{name}: alignment {alignment:.3}, mean |error| chord {chord_error:.4}, bundle {bundle_error:.4}");
            assert!(
                bundle_error < 0.6 * chord_error,
                "{name}: {bundle_error} vs {chord_error}"
            );
        }
    }
}
