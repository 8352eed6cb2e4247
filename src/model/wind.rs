//! Wind, free of Bevy: one displacement field per tree, the CPU reference
//! of the vertex shader's `wind_displacement` (`conifer_compact.wgsl`).
//!
//! The field is a function of where a point sits in the tree (its
//! tree-local position) and of time, never of what is drawn there. A
//! needle's prism, its original line and every merged line that stands for
//! it therefore move together (merged-line ends are needle ends), and the
//! wood moves with the needles beside it: switching LOD never jumps.
//!
//! Three motions, summed, as foliage systems users know have them
//! (SpeedTree, UE's skeletal foliage wind):
//!
//! * **Trunk bend.** Along the wind, growing with the square of the height
//!   over the tree's base (a cantilever's first mode), a steady lean plus a
//!   sway at the tree's own frequency ([`WindShape::trunk_hz`], lower for
//!   taller trees).
//! * **Branch sway.** Up and down and along the wind, growing with the
//!   distance from the trunk to the power 1.5 (a longer branch is less
//!   stiff), at [`BRANCH_HZ_OVER_TRUNK`] times the trunk's frequency; its
//!   phase varies smoothly through the crown ([`BRANCH_WAVES`]), so
//!   branches a metre apart sway apart.
//! * **Shoot flutter.** Across the wind and up, small and fast
//!   ([`FLUTTER_HZ`]), scaled by [`Wind::turbulence`], with a phase that
//!   varies over tens of centimetres ([`FLUTTER_WAVES`]).
//!
//! Gusts scale all three between `1 − gustiness` and `1 + gustiness`; they
//! travel through a forest along the wind ([`GUST_WAVELENGTH`]), and each
//! tree sways at its own phase ([`TreeWindPhase::of_root`]), so a forest
//! does not sway in lockstep.
//!
//! Every displacement is at most [`wind_reach`]: culling and error spheres
//! grow by it, so no tree is culled or under-detailed while it sways.

use glam::{Mat4, Vec2, Vec3};
use std::f32::consts::TAU;

/// Wind over the trees: where it blows, how hard, how gusty and turbulent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wind {
    /// Where the wind blows to, horizontal (world x, z); normalised where
    /// used; zero: no wind.
    pub direction: Vec2,
    /// 0: calm; 1: a light breeze (a 20 m tree's top leans about 16 cm and sways ±10 cm);
    /// 3: a strong wind. Negative and NaN read as calm.
    pub strength: f32,
    /// How much gusts vary the strength, 0–1.
    pub gustiness: f32,
    /// How much shoots flutter, 0–1.
    pub turbulence: f32,
}

impl Wind {
    /// No wind.
    pub const CALM: Wind = Wind {
        direction: Vec2::X,
        strength: 0.0,
        gustiness: 0.0,
        turbulence: 0.0,
    };

    /// A light breeze along +x.
    pub const LIGHT_BREEZE: Wind = Wind {
        direction: Vec2::X,
        strength: 1.0,
        gustiness: 0.4,
        turbulence: 0.4,
    };

    /// The wind's direction, unit length (+x when `direction` is zero or
    /// not finite).
    pub fn unit_direction(&self) -> Vec2 {
        self.direction.try_normalize().unwrap_or(Vec2::X)
    }

    /// Strength, gustiness and turbulence as the field uses them: strength
    /// ≥ 0, the others in `[0, 1]`, NaN read as 0.
    pub fn clamped(&self) -> Wind {
        let unit = |v: f32| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        Wind {
            direction: self.unit_direction(),
            strength: if self.strength.is_nan() {
                0.0
            } else {
                self.strength.clamp(0.0, 100.0)
            },
            gustiness: unit(self.gustiness),
            turbulence: unit(self.turbulence),
        }
    }

    /// Whether the wind moves anything.
    pub fn is_calm(&self) -> bool {
        self.clamped().strength == 0.0
    }
}

impl Default for Wind {
    fn default() -> Self {
        Wind::LIGHT_BREEZE
    }
}

/// Top of a tree leaning at strength 1, steady part, over its height.
pub const TRUNK_LEAN: f32 = 0.008;
/// Top of a tree swaying at strength 1, amplitude, over its height.
pub const TRUNK_SWAY: f32 = 0.005;
/// A branch tip at the crown's radius swaying at strength 1, amplitude,
/// over the crown radius.
pub const BRANCH_SWAY: f32 = 0.015;
/// Shoot flutter at the crown's radius at strength and turbulence 1,
/// metres.
pub const FLUTTER: f32 = 0.015;
/// Branch frequency over the trunk's.
pub const BRANCH_HZ_OVER_TRUNK: f32 = 3.1;
/// Shoot flutter, Hz.
pub const FLUTTER_HZ: f32 = 3.7;
/// The two gust oscillators, Hz.
pub const GUST_HZ: [f32; 2] = [0.071, 0.173];
/// How far apart gusts pass through a forest along the wind, metres.
pub const GUST_WAVELENGTH: f32 = 60.0;
/// Branch phase through the crown, radians per tree metre (x, y, z): a
/// cycle every 6–9 m along an axis, so branches a metre apart sway about
/// 60° apart while a branch moves as one.
pub const BRANCH_WAVES: Vec3 = Vec3::new(0.7, 1.1, 0.9);
/// Flutter phase, radians per tree metre: a cycle every 1.3–1.9 m along an
/// axis.
pub const FLUTTER_WAVES: Vec3 = Vec3::new(4.1, 3.3, 4.7);
/// Distance from the trunk over the crown radius beyond which branch sway
/// and flutter stop growing.
pub const MAX_REACH_RATIO: f32 = 1.5;

/// Step, tree metres, of the differences from which a surface's normal is
/// turned by the field ([`turned_surface_normal`]): a hundredth of the
/// shortest flutter wavelength.
pub const NORMAL_STEP: f32 = 0.01;

/// What the field needs to know of a tree: its trunk axis and size, in the
/// tree's frame (record metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindShape {
    /// Trunk axis (tree-local x, z).
    pub axis: Vec2,
    /// Height of the tree's base.
    pub base: f32,
    /// Height from base to top (> 0).
    pub height: f32,
    /// Largest horizontal distance of the crown from the axis (> 0).
    pub crown_radius: f32,
}

impl WindShape {
    /// The shape of a tree whose bounding box is `min`–`max`, trunk at
    /// `axis` (x, z). Degenerate boxes get a height and radius of at least
    /// a millimetre.
    pub fn from_bounds(min: Vec3, max: Vec3, axis: Vec2) -> WindShape {
        let corners = [min.x - axis.x, max.x - axis.x];
        let depths = [min.z - axis.y, max.z - axis.y];
        let mut radius = 0f32;
        for x in corners {
            for z in depths {
                radius = radius.max(Vec2::new(x, z).length());
            }
        }
        WindShape {
            axis,
            base: if min.y.is_finite() { min.y } else { 0.0 },
            height: finite_at_least(max.y - min.y, 1e-3),
            crown_radius: finite_at_least(radius, 1e-3),
        }
    }

    /// The trunk's sway frequency, Hz: 0.3 Hz for a 20 m tree, as `1/√h`
    /// (slender cantilevers of one taper), within 0.15–1.0 Hz. Measured
    /// conifers sway at 0.2–0.5 Hz (Moore and Maguire 2004, "Natural
    /// sway frequencies and damping ratios of trees").
    pub fn trunk_hz(&self) -> f32 {
        (0.3 * (20.0 / self.height).sqrt()).clamp(0.15, 1.0)
    }
}

fn finite_at_least(v: f32, floor: f32) -> f32 {
    if v.is_finite() { v.max(floor) } else { floor }
}

/// The field's oscillators at one moment, radians in `[0, 2π)`: computed
/// in double precision from seconds, so the shader's sines stay exact
/// however long the game runs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WindClock {
    /// Trunk sway.
    pub trunk: f32,
    /// Branch sway.
    pub branch: f32,
    /// Shoot flutter.
    pub flutter: f32,
    /// The two gust oscillators.
    pub gust: [f32; 2],
}

impl WindClock {
    /// The oscillators of a tree of `shape` at `seconds`.
    pub fn at(seconds: f64, shape: &WindShape) -> WindClock {
        let seconds = if seconds.is_finite() { seconds } else { 0.0 };
        let phase = |hz: f32| ((f64::from(hz) * seconds).rem_euclid(1.0) * std::f64::consts::TAU) as f32;
        let trunk = shape.trunk_hz();
        WindClock {
            trunk: phase(trunk),
            branch: phase(trunk * BRANCH_HZ_OVER_TRUNK),
            flutter: phase(FLUTTER_HZ),
            gust: [phase(GUST_HZ[0]), phase(GUST_HZ[1])],
        }
    }

    /// The oscillators `step` seconds before these, on a tree of `shape`:
    /// each turns at a fixed rate, so they wind back by `2π · hz · step`
    /// (not wrapped; the field takes their sines). The CPU reference of
    /// the motion vector pass's `wind_clocks` (`conifer_compact.wgsl`),
    /// which places each vertex where the previous frame's wind held it.
    pub fn wound_back(self, step: f32, shape: &WindShape) -> WindClock {
        let turn = std::f32::consts::TAU * if step.is_finite() { step } else { 0.0 };
        let trunk = shape.trunk_hz();
        WindClock {
            trunk: self.trunk - turn * trunk,
            branch: self.branch - turn * trunk * BRANCH_HZ_OVER_TRUNK,
            flutter: self.flutter - turn * FLUTTER_HZ,
            gust: [self.gust[0] - turn * GUST_HZ[0], self.gust[1] - turn * GUST_HZ[1]],
        }
    }
}

/// The screen motion of a point from `before` (world, last frame) to `now`
/// (world, this frame), in Bevy's motion vector convention: this frame's
/// clip position minus last frame's, in UV units (x right, y down), each
/// through its frame's `clip_from_world`. The CPU reference of the motion
/// vector pass's fragment (`conifer_compact.wgsl`); zero where either
/// point is behind its camera.
pub fn motion_vector(clip_from_world: Mat4, previous_clip_from_world: Mat4, now: Vec3, before: Vec3) -> Vec2 {
    let (a, b) = (
        clip_from_world * now.extend(1.0),
        previous_clip_from_world * before.extend(1.0),
    );
    if !(a.w > 0.0 && b.w > 0.0) {
        return Vec2::ZERO;
    }
    (a.truncate().truncate() / a.w - b.truncate().truncate() / b.w) * Vec2::new(0.5, -0.5)
}

/// A tree's own phases, from where it stands.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TreeWindPhase {
    /// Added to the trunk, branch and flutter oscillators: a hash of the
    /// root's position (centimetres), in `[0, 2π)`.
    pub sway: f32,
    /// Added to the gust oscillators: `−2π · fract((root · wind) /
    /// GUST_WAVELENGTH)` (fract as WGSL's, `x − ⌊x⌋`), so gusts travel along
    /// the wind.
    pub gust: f32,
}

impl TreeWindPhase {
    /// The phases of a tree whose root stands at `root` (world x, z) in
    /// `wind`.
    pub fn of_root(root: Vec2, wind: &Wind) -> TreeWindPhase {
        let cell = |v: f32| {
            if v.is_finite() {
                (v * 100.0).floor() as i32 as u32
            } else {
                0
            }
        };
        let hash = pcg(cell(root.x) ^ pcg(cell(root.y)));
        let along = root.dot(wind.unit_direction());
        TreeWindPhase {
            sway: (hash >> 8) as f32 / (1u32 << 24) as f32 * TAU,
            gust: if along.is_finite() {
                -TAU * (along / GUST_WAVELENGTH).rem_euclid(1.0)
            } else {
                0.0
            },
        }
    }
}

/// PCG hash (Jarzynski and Olano, "Hash Functions for GPU Rendering",
/// JCGT 2020); the shader's `pcg`.
pub fn pcg(value: u32) -> u32 {
    let state = value.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// A point's displacement in the wind's frame, tree metres.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WindOffset {
    /// Along the wind.
    pub along: f32,
    /// Across it (the wind turned 90° to the left, seen from above).
    pub across: f32,
    /// Up.
    pub up: f32,
}

impl WindOffset {
    /// Its length.
    pub fn length(&self) -> f32 {
        Vec3::new(self.along, self.across, self.up).length()
    }

    /// The world displacement of a tree scaled by `scale` in wind
    /// `direction` (unit, world x, z).
    pub fn world(&self, direction: Vec2, scale: f32) -> Vec3 {
        let along = Vec3::new(direction.x, 0.0, direction.y);
        let across = Vec3::new(direction.y, 0.0, -direction.x);
        (along * self.along + across * self.across + Vec3::Y * self.up) * scale
    }
}

/// How gusts scale the wind at this tree now, in `[1 − g, 1 + g]`.
pub fn gust_factor(wind: &Wind, clock: &WindClock, phase: &TreeWindPhase) -> f32 {
    let w = wind.clamped();
    let g = 0.6 * (clock.gust[0] + phase.gust).sin() + 0.4 * (clock.gust[1] + 1.7 * phase.gust).sin();
    1.0 + w.gustiness * g
}

/// The displacement of the tree-local point `point` (record metres) of a
/// tree of `shape`, at `clock`, with its own `phase`: the trunk's bend
/// ([`trunk_offset`]) plus the branches' sway and the shoots' flutter
/// ([`sway_offset`]). The shader computes the same ([`WindOffset::world`]
/// turns it into world metres).
pub fn wind_offset(
    wind: &Wind,
    shape: &WindShape,
    clock: &WindClock,
    phase: &TreeWindPhase,
    point: Vec3,
) -> WindOffset {
    let Some(terms) = FieldTerms::at(wind, shape, clock, phase, point) else {
        return WindOffset::default();
    };
    let sway = terms.sway(shape, clock, phase, point);
    WindOffset {
        along: terms.trunk(shape, clock, phase) + sway.along,
        across: sway.across,
        up: sway.up,
    }
}

/// What every motion of the field needs of a point, computed once.
struct FieldTerms {
    /// The strength gusts make of the wind at this tree now.
    force: f32,
    /// The point's height over the tree's base over the tree's height.
    h: f32,
    /// Its distance from the trunk over the crown radius, capped at
    /// [`MAX_REACH_RATIO`].
    r: f32,
    /// The wind's turbulence, clamped.
    turbulence: f32,
}

impl FieldTerms {
    /// `None` in calm or for a point that is not finite.
    fn at(wind: &Wind, shape: &WindShape, clock: &WindClock, phase: &TreeWindPhase, point: Vec3) -> Option<Self> {
        let w = wind.clamped();
        if w.strength == 0.0 || !point.is_finite() {
            return None;
        }
        Some(FieldTerms {
            force: w.strength * gust_factor(&w, clock, phase),
            h: ((point.y - shape.base) / shape.height).clamp(0.0, 1.0),
            r: ((Vec2::new(point.x, point.z) - shape.axis).length() / shape.crown_radius).min(MAX_REACH_RATIO),
            turbulence: w.turbulence,
        })
    }

    /// The trunk's bend along the wind ([`trunk_offset`]).
    fn trunk(&self, shape: &WindShape, clock: &WindClock, phase: &TreeWindPhase) -> f32 {
        self.force * shape.height * self.h * self.h * (TRUNK_LEAN + TRUNK_SWAY * (clock.trunk + phase.sway).sin())
    }

    /// The branches' sway and the shoots' flutter ([`sway_offset`]).
    fn sway(&self, shape: &WindShape, clock: &WindClock, phase: &TreeWindPhase, point: Vec3) -> WindOffset {
        let r = self.r;
        let branch_amplitude = self.force * BRANCH_SWAY * shape.crown_radius * r * r.sqrt();
        let branch = clock.branch + phase.sway + point.dot(BRANCH_WAVES);
        let flutter_amplitude = self.force * self.turbulence * FLUTTER * r;
        let flutter = clock.flutter + phase.sway + point.dot(FLUTTER_WAVES);
        WindOffset {
            along: 0.5 * branch_amplitude * (branch + 1.0).sin(),
            across: flutter_amplitude * flutter.sin(),
            up: branch_amplitude * branch.sin() + 0.5 * flutter_amplitude * (flutter + 2.1).sin(),
        }
    }
}

/// The trunk's bend at `point`: along the wind, `force · H · h² · (lean +
/// sway · sin)`, the same for every point at one height. What the crown
/// impostor's quad takes at its corners (it leans with the trunk,
/// straight between them).
pub fn trunk_offset(
    wind: &Wind,
    shape: &WindShape,
    clock: &WindClock,
    phase: &TreeWindPhase,
    point: Vec3,
) -> WindOffset {
    let along = FieldTerms::at(wind, shape, clock, phase, point).map_or(0.0, |t| t.trunk(shape, clock, phase));
    WindOffset {
        along,
        across: 0.0,
        up: 0.0,
    }
}

/// The branches' sway and the shoots' flutter at `point`: [`wind_offset`]
/// without the trunk's bend.
pub fn sway_offset(
    wind: &Wind,
    shape: &WindShape,
    clock: &WindClock,
    phase: &TreeWindPhase,
    point: Vec3,
) -> WindOffset {
    FieldTerms::at(wind, shape, clock, phase, point)
        .map_or_else(WindOffset::default, |t| t.sway(shape, clock, phase, point))
}

/// Equal sections a wood segment is drawn in while the wind blows (one in
/// calm): the vertex shader moves each section's ends by the field, so a
/// branch bends along its length and not only at its ends, and the wood
/// stays with the needles it carries
/// ([`wood_bend_gap`] measures how far it strays).
pub const WOOD_SECTIONS: u32 = 4;

/// Pixels a section of a wood *line* is at least long: a line shorter
/// than about a pixel may light no pixel at all (the rasteriser's diamond
/// rule), and a far branch drawn in four such pieces lost most of its
/// coverage.
pub const WOOD_LINE_SECTION_PIXELS: f32 = 2.0;

/// Sections a wood segment `length` long (tree metres) drawn as a line is
/// cut into while the wind blows, where a pixel spans `metres_per_pixel`:
/// as many as keep each [`WOOD_LINE_SECTION_PIXELS`] long, one to
/// [`WOOD_SECTIONS`]; one for inputs that are not finite or not positive.
/// The vertex shader's wood lines.
pub fn wood_line_sections(length: f32, metres_per_pixel: f32) -> u32 {
    let fit = length / (WOOD_LINE_SECTION_PIXELS * metres_per_pixel);
    if fit.is_finite() && fit >= 1.0 {
        (fit as u32).min(WOOD_SECTIONS)
    } else {
        1
    }
}

/// How far the wood of the segment `start`–`end` (tree-local), drawn in
/// `sections` equal pieces each straight between its moved ends, strays
/// from where the field moves the points it stands for: the largest
/// `|f(p) − lerp(f(a), f(b), t)|` over the quarter points of every piece,
/// tree metres (0 in calm and for `sections` 0).
pub fn wood_bend_gap(
    wind: &Wind,
    shape: &WindShape,
    clock: &WindClock,
    phase: &TreeWindPhase,
    start: Vec3,
    end: Vec3,
    sections: u32,
) -> f32 {
    let field = |p: Vec3| wind_offset(wind, shape, clock, phase, p).world(wind.unit_direction(), 1.0);
    let mut gap = 0f32;
    for k in 0..sections {
        let (a, b) = (
            start.lerp(end, k as f32 / sections as f32),
            start.lerp(end, (k + 1) as f32 / sections as f32),
        );
        let (fa, fb) = (field(a), field(b));
        for t in [0.25f32, 0.5, 0.75] {
            gap = gap.max((field(a.lerp(b, t)) - fa.lerp(fb, t)).length());
        }
    }
    gap
}

/// `normal` turned by the rotation that takes the direction of `calm` to
/// that of `swayed` (Rodrigues' formula): a prism whose axis the wind
/// turned from `calm` to `swayed` (the difference of its moved ends) keeps
/// its side normals perpendicular to its axis and its caps along it. The
/// vertex shader's `turn_normal`. `normal` unchanged when either direction
/// is zero or they are (nearly) opposite.
pub fn turn_normal(normal: Vec3, calm: Vec3, swayed: Vec3) -> Vec3 {
    let (Some(a), Some(b)) = (calm.try_normalize(), swayed.try_normalize()) else {
        return normal;
    };
    let c = a.dot(b);
    if c <= -0.999 {
        return normal;
    }
    let v = a.cross(b);
    (normal * c + v.cross(normal) + v * (v.dot(normal) / (1.0 + c))).normalize_or(normal)
}

/// The normal of a surface at `point` (tree-local) once the field has
/// moved it: `cof(J)·normal`, `J` the field's Jacobian from differences
/// [`NORMAL_STEP`] apart (a surface's normals transform by the inverse
/// transpose of the map that moves it, and the cofactor is that up to
/// its determinant). The vertex shader's `swayed_surface_normal` (for an
/// imported wood mesh). `normal` unchanged in calm.
pub fn turned_surface_normal(
    wind: &Wind,
    shape: &WindShape,
    clock: &WindClock,
    phase: &TreeWindPhase,
    point: Vec3,
    normal: Vec3,
) -> Vec3 {
    let field = |p: Vec3| {
        let o = wind_offset(wind, shape, clock, phase, p);
        o.world(wind.unit_direction(), 1.0)
    };
    if wind.clamped().strength == 0.0 {
        return normal;
    }
    let d = field(point);
    let column = |axis: Vec3| axis + (field(point + axis * NORMAL_STEP) - d) / NORMAL_STEP;
    let (j0, j1, j2) = (column(Vec3::X), column(Vec3::Y), column(Vec3::Z));
    let turned = j1.cross(j2) * normal.x + j2.cross(j0) * normal.y + j0.cross(j1) * normal.z;
    turned.try_normalize().unwrap_or(normal)
}

/// The largest displacement [`wind_offset`] can give in `shape` under
/// `wind` (tree metres), whatever the time, phase and point: the sum of
/// the three motions' largest.
pub fn wind_reach(wind: &Wind, shape: &WindShape) -> f32 {
    let w = wind.clamped();
    if w.strength == 0.0 {
        return 0.0;
    }
    // Rounding head room, so the bound holds in f32 on the GPU too.
    trunk_reach(wind, shape) * 1.001 + sway_reach(wind, shape)
}

/// The largest displacement [`trunk_offset`] can give in `shape` under
/// `wind` (tree metres): the top's lean and sway at the strongest gust.
pub fn trunk_reach(wind: &Wind, shape: &WindShape) -> f32 {
    let w = wind.clamped();
    let force = w.strength * (1.0 + w.gustiness);
    force * shape.height * (TRUNK_LEAN + TRUNK_SWAY)
}

/// How much wider and taller than the calm crown the impostor's quad is
/// on every side in `wind` (tree metres): its corners lean with the trunk,
/// and its fragments move the picture by the rest of the field
/// ([`crate::model::impostor::swayed_card_point`]): the sway
/// ([`sway_reach`]) and where the trunk's bend, a parabola in the height,
/// strays from the quad's straight lean between its corners (at most a
/// quarter of [`trunk_reach`]). The vertex shader's `impostor_sway_margin`.
pub fn impostor_margin(wind: &Wind, shape: &WindShape) -> f32 {
    sway_reach(wind, shape) + 0.25 * trunk_reach(wind, shape) * 1.001
}

/// The largest displacement [`sway_offset`] can give in `shape` under
/// `wind` (tree metres): branch sway and flutter at their largest.
pub fn sway_reach(wind: &Wind, shape: &WindShape) -> f32 {
    let w = wind.clamped();
    if w.strength == 0.0 {
        return 0.0;
    }
    let force = w.strength * (1.0 + w.gustiness);
    let branch = force * BRANCH_SWAY * shape.crown_radius * MAX_REACH_RATIO.powf(1.5) * 1.25f32.sqrt();
    let flutter = force * w.turbulence * FLUTTER * MAX_REACH_RATIO * 1.25f32.sqrt();
    // Rounding head room, so the bound holds in f32 on the GPU too.
    (branch + flutter) * 1.001
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape() -> WindShape {
        WindShape::from_bounds(Vec3::new(-3.0, 0.0, -2.5), Vec3::new(3.0, 20.0, 2.5), Vec2::ZERO)
    }

    proptest::proptest! {
        /// Winding the clocks back by a step gives the clocks of that
        /// moment, up to whole turns, for steps of a frame to a second.
        #[test]
        fn wound_back_clocks_are_the_earlier_clocks(seconds in 1.0f64..10_000.0, step in 0.0f32..1.0, height in 2.0f32..60.0) {
            let s = WindShape::from_bounds(Vec3::new(-3.0, 0.0, -2.5), Vec3::new(3.0, height, 2.5), Vec2::ZERO);
            let back = WindClock::at(seconds, &s).wound_back(step, &s);
            let earlier = WindClock::at(seconds - f64::from(step), &s);
            let same = |a: f32, b: f32| {
                let d = (a - b).rem_euclid(std::f32::consts::TAU);
                d.min(std::f32::consts::TAU - d) < 1e-3
            };
            proptest::prop_assert!(same(back.trunk, earlier.trunk), "{back:?} vs {earlier:?}");
            proptest::prop_assert!(same(back.branch, earlier.branch), "{back:?} vs {earlier:?}");
            proptest::prop_assert!(same(back.flutter, earlier.flutter), "{back:?} vs {earlier:?}");
            proptest::prop_assert!(same(back.gust[0], earlier.gust[0]) && same(back.gust[1], earlier.gust[1]));
        }
    }

    #[test]
    fn a_point_still_under_a_still_camera_does_not_move_and_a_pan_moves_it_against_the_pan() {
        let projection = Mat4::perspective_infinite_reverse_rh(1.0, 1.0, 0.1);
        let view = |x: f32| projection * Mat4::look_to_rh(Vec3::new(x, 0.0, 10.0), -Vec3::Z, Vec3::Y);
        let point = Vec3::new(0.5, 1.0, 0.0);
        assert_eq!(motion_vector(view(0.0), view(0.0), point, point), Vec2::ZERO);
        // The camera moves right: the point moves left on screen.
        let m = motion_vector(view(0.2), view(0.0), point, point);
        let expected = -0.2 / (10.0 * (0.5f32).tan()) * 0.5;
        assert!((m.x - expected).abs() < 1e-5 && m.y.abs() < 1e-6, "{m}");
        // The wind lifts the point: it moves up on screen (y is down).
        let lifted = motion_vector(view(0.0), view(0.0), point + Vec3::Y * 0.1, point);
        assert!(lifted.y < 0.0 && lifted.x.abs() < 1e-6, "{lifted}");
        // Behind the camera: no motion.
        assert_eq!(
            motion_vector(view(0.0), view(0.0), Vec3::new(0.0, 0.0, 20.0), point),
            Vec2::ZERO
        );
    }

    /// The shipped mature trees' wood in a light breeze and in a strong
    /// wind, over 20 moments: drawn in [`WOOD_SECTIONS`] sections it
    /// strays from the field far less than drawn straight between its
    /// segments' ends.
    #[test]
    fn wood_in_sections_bends_with_the_field() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/mature");
        let mut names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
        names.sort();
        assert_eq!(names.len(), 6);
        for path in names {
            let record = crate::model::file::read_prototype_record(&path).unwrap();
            let (mut lo, mut hi) = record.needle_bounds();
            for w in &record.wood {
                (lo, hi) = (lo.min(w.start).min(w.end), hi.max(w.start).max(w.end));
            }
            let foot = record
                .wood
                .iter()
                .map(|w| w.start)
                .min_by(|a, b| a.y.total_cmp(&b.y))
                .unwrap();
            let shape = WindShape::from_bounds(lo, hi, Vec2::new(foot.x, foot.z));
            for strength in [1.0f32, 2.5] {
                let wind = Wind {
                    strength,
                    ..Wind::LIGHT_BREEZE
                };
                let phase = TreeWindPhase::of_root(Vec2::new(3.0, 7.0), &wind);
                let (mut straight, mut sections) = (0f32, 0f32);
                for moment in 0..20 {
                    let clock = WindClock::at(f64::from(moment) * 0.37, &shape);
                    for w in &record.wood {
                        let gap = |n| wood_bend_gap(&wind, &shape, &clock, &phase, w.start, w.end, n);
                        straight = straight.max(gap(1));
                        sections = sections.max(gap(WOOD_SECTIONS));
                    }
                }
                println!(
                    "{}: strength {strength}: wood strays up to {straight:.4} m straight, {sections:.4} m in {WOOD_SECTIONS} sections",
                    path.file_stem().unwrap().to_string_lossy()
                );
                assert!(sections <= 0.25 * straight, "{sections} against {straight}");
            }
        }
    }

    #[test]
    fn wood_line_sections_stay_two_pixels_long() {
        assert_eq!(wood_line_sections(1.0, 0.1), WOOD_SECTIONS);
        assert_eq!(wood_line_sections(0.5, 0.1), 2);
        assert_eq!(wood_line_sections(0.3, 0.1), 1);
        assert_eq!(wood_line_sections(0.1, 0.1), 1);
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(wood_line_sections(1.0, bad), 1);
        }
        for n in 1..=WOOD_SECTIONS {
            let length = 0.37 * n as f32 * WOOD_LINE_SECTION_PIXELS + 1e-4;
            assert!(length / wood_line_sections(length, 0.37) as f32 >= WOOD_LINE_SECTION_PIXELS * 0.37);
        }
    }

    #[test]
    fn calm_moves_nothing_and_reaches_nothing() {
        let s = shape();
        let clock = WindClock::at(12.5, &s);
        for wind in [
            Wind::CALM,
            Wind {
                strength: f32::NAN,
                ..Wind::LIGHT_BREEZE
            },
            Wind {
                strength: -2.0,
                ..Wind::LIGHT_BREEZE
            },
        ] {
            assert!(wind.is_calm());
            assert_eq!(wind_reach(&wind, &s), 0.0);
            let o = wind_offset(&wind, &s, &clock, &TreeWindPhase::default(), Vec3::new(1.0, 15.0, 0.5));
            assert_eq!(o, WindOffset::default());
        }
    }

    #[test]
    fn the_trunk_foot_stays_and_the_top_leans_downwind() {
        let s = shape();
        let wind = Wind {
            gustiness: 0.0,
            turbulence: 0.0,
            ..Wind::LIGHT_BREEZE
        };
        let phase = TreeWindPhase::default();
        for t in 0..40 {
            let clock = WindClock::at(t as f64 * 0.37, &s);
            let foot = wind_offset(&wind, &s, &clock, &phase, Vec3::ZERO);
            assert!(foot.length() < 1e-6, "{foot:?}");
            let top = wind_offset(&wind, &s, &clock, &phase, Vec3::new(0.0, 20.0, 0.0));
            // Lean 0.8 % of 20 m, swaying ±0.5 %: always downwind.
            assert!(top.along > 0.05 && top.along < 0.27, "{top:?}");
            assert!(top.across.abs() < 1e-6 && top.up.abs() < 1e-6);
        }
    }

    #[test]
    fn a_branch_tip_moves_more_than_its_base() {
        let s = shape();
        let wind = Wind::LIGHT_BREEZE;
        let phase = TreeWindPhase::of_root(Vec2::new(3.0, 7.0), &wind);
        let mut near = 0f32;
        let mut tip = 0f32;
        for t in 0..200 {
            let clock = WindClock::at(t as f64 * 0.05, &s);
            let trunk = wind_offset(&wind, &s, &clock, &phase, Vec3::new(0.0, 10.0, 0.0));
            let at = |x: f32| {
                let o = wind_offset(&wind, &s, &clock, &phase, Vec3::new(x, 10.0, 0.0));
                Vec3::new(o.along - trunk.along, o.across, o.up).length()
            };
            near = near.max(at(0.3));
            tip = tip.max(at(3.0));
        }
        assert!(tip > 5.0 * near, "tip {tip}, near {near}");
        assert!(tip > 0.05, "{tip}");
    }

    #[test]
    fn trees_apart_sway_apart() {
        let wind = Wind::LIGHT_BREEZE;
        let phases: Vec<f32> = (0..32)
            .map(|i| TreeWindPhase::of_root(Vec2::new(i as f32 * 7.3, (i * i) as f32 * 0.9), &wind).sway)
            .collect();
        assert!(phases.iter().all(|p| (0.0..TAU).contains(p)));
        let mean = phases.iter().sum::<f32>() / 32.0;
        assert!((mean - std::f32::consts::PI).abs() < 1.0, "{mean}");
        let mut sorted = phases.clone();
        sorted.sort_by(f32::total_cmp);
        sorted.dedup();
        assert_eq!(sorted.len(), 32);
    }

    #[test]
    fn gusts_travel_downwind() {
        // A tree GUST_WAVELENGTH/4 downwind sees the gust a quarter period
        // later.
        let wind = Wind::LIGHT_BREEZE;
        let here = TreeWindPhase::of_root(Vec2::ZERO, &wind);
        let there = TreeWindPhase::of_root(Vec2::new(GUST_WAVELENGTH / 4.0, 0.0), &wind);
        let d = (here.gust - there.gust).rem_euclid(TAU);
        assert!((d - TAU / 4.0).abs() < 1e-4, "{d}");
    }

    #[test]
    fn the_clock_is_exact_after_a_day() {
        // A quarter period after a day's seconds, the trunk is a quarter
        // turn on: f32 seconds would have lost it (86,400 s has 8 ms steps).
        let s = shape();
        let day = 86_400.0;
        let quarter = 0.25 / f64::from(s.trunk_hz());
        let turned = (WindClock::at(day + quarter, &s).trunk - WindClock::at(day, &s).trunk).rem_euclid(TAU);
        assert!((turned - TAU / 4.0).abs() < 1e-4, "{turned}");
        assert!(WindClock::at(f64::NAN, &s) == WindClock::at(0.0, &s));
    }

    #[test]
    fn taller_trees_sway_slower() {
        let low = WindShape { height: 5.0, ..shape() };
        let tall = WindShape {
            height: 40.0,
            ..shape()
        };
        assert!(tall.trunk_hz() < shape().trunk_hz() && shape().trunk_hz() < low.trunk_hz());
        assert!((shape().trunk_hz() - 0.3).abs() < 1e-6);
    }

    #[test]
    fn a_degenerate_box_gives_a_usable_shape() {
        let s = WindShape::from_bounds(Vec3::splat(1.0), Vec3::splat(1.0), Vec2::ONE);
        assert!(s.height > 0.0 && s.crown_radius > 0.0);
        let n = WindShape::from_bounds(Vec3::splat(f32::NAN), Vec3::splat(f32::NAN), Vec2::ZERO);
        assert!(n.height > 0.0 && n.crown_radius > 0.0 && n.base == 0.0);
    }

    proptest::proptest! {
        #[test]
        fn no_point_moves_beyond_the_reach(
            x in -6.0f32..6.0, y in -2.0f32..25.0, z in -6.0f32..6.0,
            seconds in 0.0f64..1e6, root_x in -1e3f32..1e3, root_z in -1e3f32..1e3,
            strength in 0.0f32..4.0, gustiness in 0.0f32..1.0, turbulence in 0.0f32..1.0,
        ) {
            let s = shape();
            let wind = Wind { direction: Vec2::new(0.3, -1.0), strength, gustiness, turbulence };
            let clock = WindClock::at(seconds, &s);
            let phase = TreeWindPhase::of_root(Vec2::new(root_x, root_z), &wind);
            let o = wind_offset(&wind, &s, &clock, &phase, Vec3::new(x, y, z));
            proptest::prop_assert!(o.length() <= wind_reach(&wind, &s), "{} > {}", o.length(), wind_reach(&wind, &s));
            // The parts: the trunk's bend along the wind, the sway within
            // its own reach (the impostor's margin), summing to the whole.
            let point = Vec3::new(x, y, z);
            let trunk = trunk_offset(&wind, &s, &clock, &phase, point);
            let sway = sway_offset(&wind, &s, &clock, &phase, point);
            proptest::prop_assert!(trunk.across == 0.0 && trunk.up == 0.0);
            proptest::prop_assert!(sway.length() <= sway_reach(&wind, &s), "{} > {}", sway.length(), sway_reach(&wind, &s));
            proptest::prop_assert_eq!(trunk.along + sway.along, o.along);
            proptest::prop_assert_eq!((sway.across, sway.up), (o.across, o.up));
        }

        /// A crown impostor's quad leans with the trunk at its corners
        /// (heights `below` and `above` a point), straight between them:
        /// what the field moves the point by beyond that lean stays within
        /// the quad's margin.
        #[test]
        fn the_field_beyond_a_straight_lean_stays_within_the_impostors_margin(
            x in -6.0f32..6.0, y in 0.0f32..20.0, z in -6.0f32..6.0,
            below in 0.0f32..20.0, above in 0.0f32..20.0, seconds in 0.0f64..1e4,
            strength in 0.0f32..4.0, gustiness in 0.0f32..1.0, turbulence in 0.0f32..1.0,
        ) {
            let s = shape();
            let wind = Wind { direction: Vec2::new(0.3, -1.0), strength, gustiness, turbulence };
            let clock = WindClock::at(seconds, &s);
            let phase = TreeWindPhase::of_root(Vec2::new(4.0, 9.0), &wind);
            let (bottom, top) = (below.min(y), above.max(y));
            let lean = |h: f32| trunk_offset(&wind, &s, &clock, &phase, Vec3::new(0.0, h, 0.0)).along;
            let t = if top > bottom { (y - bottom) / (top - bottom) } else { 0.0 };
            let straight = lean(bottom) + (lean(top) - lean(bottom)) * t;
            let o = wind_offset(&wind, &s, &clock, &phase, Vec3::new(x, y, z));
            let beyond = Vec3::new(o.along - straight, o.across, o.up).length();
            proptest::prop_assert!(beyond <= impostor_margin(&wind, &s), "{} > {}", beyond, impostor_margin(&wind, &s));
        }

        #[test]
        fn the_field_is_smooth_so_a_needle_keeps_its_length(
            x in -3.0f32..3.0, y in 0.0f32..20.0, z in -3.0f32..3.0, seconds in 0.0f64..1e4,
        ) {
            // Two ends 5 cm apart move at most a centimetre apart in a
            // light breeze: a prism, its line and its merged lines keep
            // the needle's shape.
            let s = shape();
            let wind = Wind::LIGHT_BREEZE;
            let clock = WindClock::at(seconds, &s);
            let phase = TreeWindPhase::default();
            let a = Vec3::new(x, y, z);
            let b = a + Vec3::new(0.03, 0.03, 0.0283);
            let oa = wind_offset(&wind, &s, &clock, &phase, a);
            let ob = wind_offset(&wind, &s, &clock, &phase, b);
            let d = WindOffset { along: oa.along - ob.along, across: oa.across - ob.across, up: oa.up - ob.up };
            proptest::prop_assert!(d.length() < 0.01, "{}", d.length());
        }
    }

    #[test]
    fn a_turned_prism_keeps_its_normals_perpendicular_and_its_caps_along_its_axis() {
        let calm = Vec3::Y;
        for swayed in [
            Vec3::new(0.1, 1.0, 0.0),
            Vec3::new(-0.3, 0.9, 0.2),
            Vec3::new(0.0, 2.0, 0.0),
        ] {
            let axis = swayed.normalize();
            for k in 0..8 {
                let angle = k as f32 * std::f32::consts::TAU / 8.0;
                let side = Vec3::new(angle.cos(), 0.0, angle.sin());
                let turned = turn_normal(side, calm, swayed);
                assert!(turned.dot(axis).abs() < 1e-5, "{turned} vs {axis}");
                assert!((turned.length() - 1.0).abs() < 1e-5);
            }
            assert!(turn_normal(Vec3::Y, calm, swayed).distance(axis) < 1e-5);
            assert!(turn_normal(-Vec3::Y, calm, swayed).distance(-axis) < 1e-5);
        }
        // Calm, zero or opposite axes: unchanged.
        assert_eq!(turn_normal(Vec3::X, Vec3::Y, Vec3::Y), Vec3::X);
        assert_eq!(turn_normal(Vec3::X, Vec3::ZERO, Vec3::Y), Vec3::X);
        assert_eq!(turn_normal(Vec3::X, Vec3::Y, -Vec3::Y), Vec3::X);
    }

    #[test]
    fn a_leaning_trunks_upwind_side_turns_up_by_its_slope() {
        // No gusts, no flutter; on the axis the branch sway is zero, so the
        // trunk's side there turns by the lean's slope, 2·force·h·(lean +
        // sway·sin) (the derivative of the cantilever's h² bend).
        let wind = Wind {
            direction: Vec2::X,
            strength: 3.0,
            gustiness: 0.0,
            turbulence: 0.0,
        };
        let shape = WindShape {
            axis: Vec2::ZERO,
            base: 0.0,
            height: 20.0,
            crown_radius: 4.0,
        };
        let clock = WindClock::at(1.7, &shape);
        let phase = TreeWindPhase::default();
        for y in [5.0f32, 10.0, 18.0] {
            let h = y / shape.height;
            let slope = 2.0 * wind.strength * h * (TRUNK_LEAN + TRUNK_SWAY * clock.trunk.sin());
            let upwind = turned_surface_normal(&wind, &shape, &clock, &phase, Vec3::new(0.0, y, 0.0), -Vec3::X);
            let expected = slope / (1.0 + slope * slope).sqrt();
            assert!((upwind.y - expected).abs() < 2e-3, "{y} m: {upwind} vs slope {slope}");
            let downwind = turned_surface_normal(&wind, &shape, &clock, &phase, Vec3::new(0.0, y, 0.0), Vec3::X);
            assert!((downwind.y + expected).abs() < 2e-3, "{y} m: {downwind}");
            // A normal along the wind's axis of rotation (across) stays.
            let across = turned_surface_normal(&wind, &shape, &clock, &phase, Vec3::new(0.0, y, 0.0), Vec3::Z);
            assert!(across.distance(Vec3::Z) < 2e-3, "{across}");
        }
        let calm = turned_surface_normal(&Wind::CALM, &shape, &clock, &phase, Vec3::new(0.0, 9.0, 0.0), -Vec3::X);
        assert_eq!(calm, -Vec3::X);
    }
}
