//! Placing trees on terrain: blue-noise (Poisson-disk) positions over an
//! area, thinned by a density, lifted onto a height source, filtered by
//! slope, each with a random yaw, scale and species. Free of Bevy; the
//! plugin turns [`Placement`]s into `ConiferFoliage` entities
//! (`plugin::spawn_forest`).
//!
//! ```
//! use bevy_conifer_lod::scatter::{Scatter, HeightMap};
//! use glam::Vec2;
//!
//! let ground = HeightMap::from_fn(65, 65, Vec2::splat(-100.0), Vec2::splat(100.0), |p| 0.05 * p.x);
//! let trees = Scatter::new(Vec2::splat(-100.0), Vec2::splat(100.0), 6.0)
//!     .density(|p| if p.y > 0.0 { 1.0 } else { 0.3 })
//!     .height(ground)
//!     .max_slope_deg(30.0)
//!     .scale_range(0.8, 1.2)
//!     .species_weights(&[3.0, 1.0])
//!     .seed(7)
//!     .place();
//! assert!(trees.iter().all(|t| t.species < 2 && t.scale >= 0.8 && t.scale <= 1.2));
//! ```
//!
//! Guarantees (tested): no two placements closer than the minimum spacing
//! (horizontally); every placement inside the area, on the height source,
//! and no steeper than the slope limit; the same seed gives the same
//! placements; with density `d` the count is `d` times the full-density
//! count up to sampling noise.

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A source of ground height `y` at a horizontal position `(x, z)`.
pub trait HeightSource {
    /// Ground height at `p = (x, z)`; `None` where there is no ground
    /// (nothing is placed there).
    fn height_at(&self, p: Vec2) -> Option<f32>;
}

impl<F: Fn(Vec2) -> f32> HeightSource for F {
    fn height_at(&self, p: Vec2) -> Option<f32> {
        Some(self(p)).filter(|h| h.is_finite())
    }
}

/// A regular grid of samples over a rectangle, read bilinearly: a
/// heightmap, or a density map in `[0, 1]`.
#[derive(Clone, Debug, PartialEq)]
pub struct HeightMap {
    /// Samples along x.
    pub columns: usize,
    /// Samples along z.
    pub rows: usize,
    /// Corner `(x, z)` of sample `(0, 0)`.
    pub min: Vec2,
    /// Corner `(x, z)` of sample `(columns − 1, rows − 1)`.
    pub max: Vec2,
    /// `rows × columns` values, row-major (z outer, x inner).
    pub values: Vec<f32>,
}

impl HeightMap {
    /// Samples `f` on a `columns × rows` grid spanning `min..=max`.
    pub fn from_fn(columns: usize, rows: usize, min: Vec2, max: Vec2, f: impl Fn(Vec2) -> f32) -> Self {
        let (columns, rows) = (columns.max(2), rows.max(2));
        let mut values = Vec::with_capacity(columns * rows);
        for j in 0..rows {
            for i in 0..columns {
                let t = Vec2::new(i as f32 / (columns - 1) as f32, j as f32 / (rows - 1) as f32);
                values.push(f(min + (max - min) * t));
            }
        }
        Self {
            columns,
            rows,
            min,
            max,
            values,
        }
    }

    /// The value at grid sample `(i, j)`.
    pub fn get(&self, i: usize, j: usize) -> f32 {
        self.values[j.min(self.rows - 1) * self.columns + i.min(self.columns - 1)]
    }

    /// Bilinear value at `p`; `None` outside the rectangle, on a malformed
    /// map, or where a sample is not finite.
    pub fn sample(&self, p: Vec2) -> Option<f32> {
        if self.columns < 2 || self.rows < 2 || self.values.len() != self.columns * self.rows {
            return None;
        }
        let extent = self.max - self.min;
        let t = (p - self.min) / extent;
        if !(t.x >= 0.0 && t.x <= 1.0 && t.y >= 0.0 && t.y <= 1.0) {
            return None;
        }
        let gx = t.x * (self.columns - 1) as f32;
        let gz = t.y * (self.rows - 1) as f32;
        let (i, j) = ((gx as usize).min(self.columns - 2), (gz as usize).min(self.rows - 2));
        let (fx, fz) = (gx - i as f32, gz - j as f32);
        let top = self.get(i, j) * (1.0 - fx) + self.get(i + 1, j) * fx;
        let bottom = self.get(i, j + 1) * (1.0 - fx) + self.get(i + 1, j + 1) * fx;
        Some(top * (1.0 - fz) + bottom * fz).filter(|v| v.is_finite())
    }
}

impl HeightSource for HeightMap {
    fn height_at(&self, p: Vec2) -> Option<f32> {
        self.sample(p)
    }
}

/// One tree to place.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Base of the trunk, on the ground.
    pub position: Vec3,
    /// Rotation about the vertical axis, radians in `[0, 2π)` by default.
    pub yaw: f32,
    /// Uniform scale.
    pub scale: f32,
    /// Index into the species weights.
    pub species: usize,
    /// Ground slope at the position, degrees.
    pub slope_deg: f32,
}

/// A scatter: where, how dense, on what ground, and with what variety.
/// Build it with [`Scatter::new`] and the setters, then [`Scatter::place`].
pub struct Scatter<'a> {
    min: Vec2,
    max: Vec2,
    min_spacing: f32,
    density: Box<dyn Fn(Vec2) -> f32 + 'a>,
    height: Box<dyn HeightSource + 'a>,
    max_slope_deg: f32,
    yaw: (f32, f32),
    scale: (f32, f32),
    species_weights: Vec<f32>,
    seed: u64,
}

impl<'a> Scatter<'a> {
    /// Trees over the rectangle `min..max` of the ground plane (`(x, z)`,
    /// metres), no two closer than `min_spacing` metres. Defaults: density
    /// 1, flat ground at `y = 0`, no slope limit, any yaw, scale 1, one
    /// species, seed 0.
    pub fn new(min: Vec2, max: Vec2, min_spacing: f32) -> Self {
        Self {
            min,
            max,
            min_spacing,
            density: Box::new(|_| 1.0),
            height: Box::new(|_: Vec2| 0.0),
            max_slope_deg: 90.0,
            yaw: (0.0, std::f32::consts::TAU),
            scale: (1.0, 1.0),
            species_weights: vec![1.0],
            seed: 0,
        }
    }

    /// Probability in `[0, 1]` of keeping a blue-noise candidate at `(x, z)`
    /// (a density map: pass `move |p| map.sample(p).unwrap_or(0.0)`).
    pub fn density(mut self, density: impl Fn(Vec2) -> f32 + 'a) -> Self {
        self.density = Box::new(density);
        self
    }

    /// The ground: a closure `(x, z) → y`, a [`HeightMap`], or any
    /// [`HeightSource`].
    pub fn height(mut self, height: impl HeightSource + 'a) -> Self {
        self.height = Box::new(height);
        self
    }

    /// Steepest ground a tree stands on, degrees from horizontal.
    pub fn max_slope_deg(mut self, degrees: f32) -> Self {
        self.max_slope_deg = degrees;
        self
    }

    /// Yaw drawn uniformly in `[min, max)` radians.
    pub fn yaw_range(mut self, min: f32, max: f32) -> Self {
        self.yaw = (min, max);
        self
    }

    /// Scale drawn uniformly in `[min, max]`.
    pub fn scale_range(mut self, min: f32, max: f32) -> Self {
        self.scale = (min, max);
        self
    }

    /// Relative weights of the species; a placement's `species` indexes them.
    /// Non-positive or non-finite weights are never chosen.
    pub fn species_weights(mut self, weights: &[f32]) -> Self {
        self.species_weights = weights.to_vec();
        self
    }

    /// Seed: the same scatter with the same seed gives the same placements.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// The placements, in a deterministic order. Empty for an empty or
    /// non-finite area, a non-positive spacing, or no usable species weight.
    pub fn place(&self) -> Vec<Placement> {
        let extent = self.max - self.min;
        let weights: Vec<f32> = self
            .species_weights
            .iter()
            .map(|&w| if w.is_finite() && w > 0.0 { w } else { 0.0 })
            .collect();
        let total_weight: f32 = weights.iter().sum();
        let usable = extent.x > 0.0 && extent.y > 0.0 && extent.is_finite();
        let spaced = self.min_spacing > 0.0 && self.min_spacing.is_finite();
        if !usable
            || !spaced
            || total_weight <= 0.0
            // More than ~50 million candidates is a mistake, not a forest.
            || (extent.x as f64 * extent.y as f64) / (self.min_spacing as f64).powi(2) > 5e7
        {
            return Vec::new();
        }
        let candidates = poisson_disk(extent, self.min_spacing, self.seed);
        let mut rng = Pcg64Mcg::seed_from_u64(self.seed ^ 0x5ca7_7e12_f0e5_7000);
        let max_slope = self.max_slope_deg.clamp(0.0, 90.0);
        // Slope by central differences over a tenth of the spacing.
        let step = (self.min_spacing * 0.1).max(1e-3);
        let mut out = Vec::new();
        for point in candidates {
            let p = self.min + point;
            // Draw every random number for every candidate, so that one
            // filter's outcome never shifts the others' streams.
            let mut unit = || (rng.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0);
            let (keep, yaw_t, scale_t, species_t) = (unit(), unit(), unit(), unit());
            if !(p.x < self.max.x && p.y < self.max.y) {
                continue;
            }
            let density = (self.density)(p);
            // A NaN density keeps nothing.
            if keep.partial_cmp(&density) != Some(std::cmp::Ordering::Less) {
                continue;
            }
            let Some(y) = self.height.height_at(p) else { continue };
            let slope_deg = match self.slope_deg(p, step) {
                Some(s) => s,
                None => continue,
            };
            if slope_deg > max_slope {
                continue;
            }
            let mut pick = species_t * total_weight;
            let mut species = weights.len() - 1;
            for (k, &w) in weights.iter().enumerate() {
                if w > 0.0 && pick < w {
                    species = k;
                    break;
                }
                pick -= w;
            }
            while weights[species] <= 0.0 {
                species -= 1; // the last positive weight (rounding at the top end)
            }
            out.push(Placement {
                position: Vec3::new(p.x, y, p.y),
                yaw: self.yaw.0 + (self.yaw.1 - self.yaw.0) * yaw_t,
                scale: self.scale.0 + (self.scale.1 - self.scale.0) * scale_t,
                species,
                slope_deg,
            });
        }
        out
    }

    /// Ground slope at `p` in degrees (one-sided differences at the edges
    /// of the height source).
    fn slope_deg(&self, p: Vec2, step: f32) -> Option<f32> {
        let h = |q: Vec2| self.height.height_at(q);
        let centre = h(p)?;
        let derivative = |axis: Vec2| -> Option<f32> {
            match (h(p + axis * step), h(p - axis * step)) {
                (Some(a), Some(b)) => Some((a - b) / (2.0 * step)),
                (Some(a), None) => Some((a - centre) / step),
                (None, Some(b)) => Some((centre - b) / step),
                (None, None) => None,
            }
        };
        let gradient = Vec2::new(derivative(Vec2::X)?, derivative(Vec2::Y)?);
        Some(gradient.length().atan().to_degrees())
    }
}

/// Candidates tried around an active point before it retires (Bridson's `k`).
const POISSON_ATTEMPTS: u32 = 30;

/// Blue-noise points in `[0, extent)` with no two closer than `spacing`, and
/// no room left for another (Bridson, *Fast Poisson Disk Sampling in
/// Arbitrary Dimensions*, SIGGRAPH 2007 sketch): a background grid of cells
/// of side `spacing/√2` holds at most one point each, so a candidate is
/// checked against the 5×5 cells around it. `O(n)`.
///
/// Written here rather than taken from `fast_poisson`: that crate pulls a
/// k-d tree and fixed-point crates whose features change shared
/// dependencies of Bevy and force a full rebuild of it, for 50 lines.
fn poisson_disk(extent: Vec2, spacing: f32, seed: u64) -> Vec<Vec2> {
    let cell = spacing / std::f32::consts::SQRT_2;
    let columns = (extent.x / cell).ceil().max(1.0) as usize;
    let rows = (extent.y / cell).ceil().max(1.0) as usize;
    let mut grid: Vec<u32> = vec![u32::MAX; columns * rows];
    let cell_of = |p: Vec2| ((p.x / cell) as usize).min(columns - 1) + ((p.y / cell) as usize).min(rows - 1) * columns;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut unit = move || (rng.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0);
    let mut points = Vec::new();
    let mut active = Vec::new();
    let first = Vec2::new(unit() * extent.x, unit() * extent.y);
    grid[cell_of(first)] = 0;
    points.push(first);
    active.push(0u32);
    let spacing_squared = spacing * spacing;
    while !active.is_empty() {
        let slot = ((unit() * active.len() as f32) as usize).min(active.len() - 1);
        let centre = points[active[slot] as usize];
        let mut placed = false;
        for _ in 0..POISSON_ATTEMPTS {
            // Uniform by area in the annulus [r, 2r].
            let radius = spacing * (1.0 + 3.0 * unit()).sqrt();
            let angle = std::f32::consts::TAU * unit();
            let candidate = centre + Vec2::new(angle.cos(), angle.sin()) * radius;
            if !(candidate.x >= 0.0 && candidate.y >= 0.0 && candidate.x < extent.x && candidate.y < extent.y) {
                continue;
            }
            let (cx, cy) = ((candidate.x / cell) as usize, (candidate.y / cell) as usize);
            let mut free = true;
            'search: for y in cy.saturating_sub(2)..(cy + 3).min(rows) {
                for x in cx.saturating_sub(2)..(cx + 3).min(columns) {
                    let other = grid[x + y * columns];
                    if other != u32::MAX && points[other as usize].distance_squared(candidate) < spacing_squared {
                        free = false;
                        break 'search;
                    }
                }
            }
            if free {
                grid[cell_of(candidate)] = points.len() as u32;
                active.push(points.len() as u32);
                points.push(candidate);
                placed = true;
                break;
            }
        }
        if !placed {
            active.swap_remove(slot);
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn min_distance(points: &[Placement]) -> f32 {
        let mut best = f32::INFINITY;
        for (i, a) in points.iter().enumerate() {
            for b in &points[i + 1..] {
                let d = Vec2::new(a.position.x - b.position.x, a.position.z - b.position.z).length();
                best = best.min(d);
            }
        }
        best
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        #[test]
        fn spacing_area_and_determinism(seed in any::<u64>(), spacing in 2.0f32..8.0, w in 20.0f32..80.0, d in 20.0f32..80.0) {
            let min = Vec2::new(-w / 2.0, 10.0);
            let max = min + Vec2::new(w, d);
            let scatter = Scatter::new(min, max, spacing).height(|p: Vec2| 0.1 * p.x).seed(seed);
            let trees = scatter.place();
            prop_assert!(!trees.is_empty());
            prop_assert!(min_distance(&trees) >= spacing * 0.999);
            for t in &trees {
                prop_assert!(t.position.x >= min.x && t.position.x < max.x);
                prop_assert!(t.position.z >= min.y && t.position.z < max.y);
                prop_assert!((t.position.y - 0.1 * t.position.x).abs() < 1e-4);
                prop_assert!(t.yaw >= 0.0 && t.yaw < std::f32::consts::TAU + 1e-4);
            }
            prop_assert_eq!(trees, scatter.place());
        }
    }

    #[test]
    fn different_seeds_differ() {
        let a = Scatter::new(Vec2::ZERO, Vec2::splat(50.0), 3.0).seed(1).place();
        let b = Scatter::new(Vec2::ZERO, Vec2::splat(50.0), 3.0).seed(2).place();
        assert_ne!(a, b);
    }

    #[test]
    fn count_follows_density() {
        let area = Vec2::splat(200.0);
        let full = Scatter::new(Vec2::ZERO, area, 4.0).seed(3).place().len() as f32;
        // Blue noise at spacing r packs about 0.6–0.75 points per r²·(√3/2)… check loosely.
        let expected_full = 200.0 * 200.0 / (4.0f32 * 4.0);
        assert!(full > 0.45 * expected_full && full < 0.9 * expected_full, "{full}");
        for density in [0.1f32, 0.5, 0.8] {
            let n = Scatter::new(Vec2::ZERO, area, 4.0)
                .density(move |_| density)
                .seed(3)
                .place()
                .len() as f32;
            // Binomial thinning: within 4 standard deviations.
            let sigma = (full * density * (1.0 - density)).sqrt();
            assert!(
                (n - density * full).abs() <= 4.0 * sigma + 1.0,
                "{density}: {n} of {full}"
            );
        }
        // A density map: nothing where it is zero.
        let map = HeightMap::from_fn(201, 3, Vec2::ZERO, area, |p| if p.x < 100.0 { 1.0 } else { 0.0 });
        let trees = Scatter::new(Vec2::ZERO, area, 4.0)
            .density(move |p| map.sample(p).unwrap_or(0.0))
            .place();
        assert!(trees.iter().all(|t| t.position.x < 100.0));
        assert!(
            (trees.len() as f32 - 0.5 * full).abs() < 0.05 * full,
            "{} of {full}",
            trees.len()
        );
    }

    #[test]
    fn slope_limit_is_kept() {
        // A ridge: flat for x < 0, a 45° flank for x ≥ 0.
        let ground = |p: Vec2| p.x.max(0.0);
        let trees = Scatter::new(Vec2::splat(-50.0), Vec2::splat(50.0), 2.0)
            .height(ground)
            .max_slope_deg(30.0)
            .place();
        assert!(!trees.is_empty());
        for t in &trees {
            assert!(t.slope_deg <= 30.0);
            assert!(t.position.x < 0.5, "on the flank at {}", t.position.x);
        }
        // A heightmap of the same ridge gives the same slopes.
        let map = HeightMap::from_fn(101, 101, Vec2::splat(-50.0), Vec2::splat(50.0), ground);
        let on_map = Scatter::new(Vec2::splat(-50.0), Vec2::splat(50.0), 2.0)
            .height(map)
            .max_slope_deg(30.0)
            .place();
        assert!(on_map.iter().all(|t| t.position.x < 1.5 && t.slope_deg <= 30.0));
    }

    #[test]
    fn species_follow_their_weights() {
        let trees = Scatter::new(Vec2::ZERO, Vec2::splat(300.0), 3.0)
            .species_weights(&[3.0, 0.0, 1.0, f32::NAN])
            .scale_range(0.5, 2.0)
            .seed(9)
            .place();
        let mut counts = [0usize; 4];
        for t in &trees {
            counts[t.species] += 1;
            assert!(t.scale >= 0.5 && t.scale <= 2.0);
        }
        assert_eq!(counts[1], 0);
        assert_eq!(counts[3], 0);
        let share = counts[0] as f32 / trees.len() as f32;
        assert!((share - 0.75).abs() < 0.03, "{share}");
    }

    #[test]
    fn bad_input_gives_nothing() {
        assert!(Scatter::new(Vec2::ZERO, Vec2::ZERO, 1.0).place().is_empty());
        assert!(Scatter::new(Vec2::ZERO, Vec2::splat(10.0), 0.0).place().is_empty());
        assert!(Scatter::new(Vec2::ZERO, Vec2::splat(10.0), f32::NAN).place().is_empty());
        assert!(
            Scatter::new(Vec2::ZERO, Vec2::splat(f32::INFINITY), 1.0)
                .place()
                .is_empty()
        );
        assert!(Scatter::new(Vec2::ZERO, Vec2::splat(1e6), 0.01).place().is_empty());
        assert!(
            Scatter::new(Vec2::ZERO, Vec2::splat(10.0), 1.0)
                .species_weights(&[])
                .place()
                .is_empty()
        );
        // No ground: nothing placed.
        let hole = |p: Vec2| if p.x < 5.0 { f32::NAN } else { 0.0 };
        let trees = Scatter::new(Vec2::ZERO, Vec2::splat(10.0), 1.0).height(hole).place();
        assert!(trees.iter().all(|t| t.position.x >= 5.0));
    }
}
