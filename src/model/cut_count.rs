//! How many primitives the cut of a record holds at a spatial error, in
//! `O(Lmax · log n)` instead of a traversal: what a stats overlay or a
//! budget needs every frame for every tree.
//!
//! A node is in the cut at `e` iff `error ≤ e < parent_error`, so the lines
//! in the cut number `#{error ≤ e} − #{parent_error ≤ e}` (every node's
//! error is below its parent's): two binary searches in sorted arrays. A
//! needle is a prism while `e < 2R`, with [`prism_sides`] sides, which
//! grows with `R`: with the radii sorted, each side count is a contiguous
//! run found by binary search.

use super::metric::{line_error, prism_sides, relative_error};
use super::prism::prism_triangle_count;
use super::prototype::PrototypeRecord;
use super::record::{CutStats, LodRecord, NO_PARENT};

/// Primitive counts of a cut.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CutCounts {
    /// Needles drawn as prisms.
    pub prisms: u64,
    /// Triangles of those prisms.
    pub triangles: u64,
    /// Original lines drawn.
    pub lines_original: u64,
    /// Merged lines drawn.
    pub lines_merged: u64,
}

impl CutCounts {
    /// Lines drawn (original and merged).
    pub fn lines(&self) -> u64 {
        self.lines_original + self.lines_merged
    }

    /// Primitives, a line counted like a triangle (the paper's measure).
    pub fn primitives(&self) -> u64 {
        self.triangles + self.lines()
    }
}

impl From<&CutStats> for CutCounts {
    fn from(stats: &CutStats) -> Self {
        Self {
            prisms: stats.prisms,
            triangles: stats.triangles,
            lines_original: stats.lines_original,
            lines_merged: stats.lines_merged,
        }
    }
}

/// Sorted errors of a record, to count its cut at any spatial error.
#[derive(Clone, Debug, Default)]
pub struct CutCounter {
    /// Needle radii, ascending.
    radii: Vec<f32>,
    /// Original lines: their errors `2R` and their parents' errors, ascending.
    original: (Vec<f32>, Vec<f32>),
    /// Merged lines: errors and parents' errors, ascending.
    merged: (Vec<f32>, Vec<f32>),
    max_sides: u8,
}

impl CutCounter {
    /// The counter of `record`.
    pub fn new(record: &LodRecord) -> Self {
        let n = record.needle_count() as u32;
        let sorted = |nodes: std::ops::Range<u32>, f: &dyn Fn(u32) -> f32| {
            let mut v: Vec<f32> = nodes.map(f).collect();
            v.sort_by(f32::total_cmp);
            v
        };
        let all = record.node_count() as u32;
        Self {
            radii: sorted(0..n, &|k| record.needles[k as usize].radius),
            original: (
                sorted(0..n, &|k| record.node_error(k)),
                sorted(0..n, &|k| record.parent_error(k)),
            ),
            merged: (
                sorted(n..all, &|k| record.node_error(k)),
                sorted(n..all, &|k| record.parent_error(k)),
            ),
            max_sides: record.max_sides,
        }
    }

    /// The counter of the flattened `record`, equal to
    /// [`CutCounter::new`] of [`PrototypeRecord::flatten`], built without
    /// flattening it: each placement's errors are its prototype's scaled,
    /// the very products the flattened tree stores.
    pub fn from_prototypes(record: &PrototypeRecord) -> Self {
        // Each prototype's local parents (its root has none here).
        let parents: Vec<Vec<u32>> = record
            .prototypes
            .iter()
            .map(|prototype| {
                let mut parent = vec![NO_PARENT; prototype.needles.len() + prototype.merged.len()];
                let n = prototype.needles.len() as u32;
                for (k, line) in prototype.merged.iter().enumerate() {
                    for &c in &line.children {
                        parent[c as usize] = n + k as u32;
                    }
                }
                parent
            })
            .collect();
        let needles = record.needle_count() as usize;
        let mut radii = Vec::with_capacity(needles);
        let mut original = (Vec::with_capacity(needles), Vec::with_capacity(needles));
        let mut merged = (Vec::new(), Vec::new());
        let p_count = record.placements.len() as u32;
        let tree_error = |node: u32| match node {
            NO_PARENT => f32::INFINITY,
            node => record.tree_merged[(node - p_count) as usize].error,
        };
        for (p, placement) in record.placements.iter().enumerate() {
            let prototype = &record.prototypes[placement.prototype as usize];
            let parent = &parents[placement.prototype as usize];
            let n = prototype.needles.len() as u32;
            let root_parent = tree_error(record.tree_parent(p as u32));
            let error = |node: u32| prototype.node_error(node) * placement.scale;
            let parent_error = |node: u32| match parent[node as usize] {
                NO_PARENT => root_parent,
                up => error(up),
            };
            for (k, needle) in prototype.needles.iter().enumerate() {
                radii.push(needle.radius * placement.scale);
                original.0.push(error(k as u32));
                original.1.push(parent_error(k as u32));
            }
            for node in n..n + prototype.merged.len() as u32 {
                merged.0.push(error(node));
                merged.1.push(parent_error(node));
            }
        }
        for (k, line) in record.tree_merged.iter().enumerate() {
            merged.0.push(line.error);
            merged.1.push(tree_error(record.tree_parent(p_count + k as u32)));
        }
        for values in [
            &mut radii,
            &mut original.0,
            &mut original.1,
            &mut merged.0,
            &mut merged.1,
        ] {
            values.sort_by(f32::total_cmp);
        }
        Self {
            radii,
            original,
            merged,
            max_sides: record.max_sides,
        }
    }

    /// The smallest merged-line error, where the first merged line can
    /// enter a cut (`None` without merged lines).
    pub fn min_merged_error(&self) -> Option<f32> {
        self.merged.0.first().copied()
    }

    /// The counts of the cut at spatial error `e` (equal to
    /// [`LodRecord::cut_stats`] of [`LodRecord::cut`]). A NaN or negative
    /// `e` counts as 0.
    pub fn count(&self, e: f32) -> CutCounts {
        // At e = ∞ the cut is the roots, whose parent error is ∞: clamp to the largest finite.
        let e = if e.is_nan() { 0.0 } else { e.clamp(0.0, f32::MAX) };
        let at_most = |v: &[f32]| v.partition_point(|&x| x <= e) as u64;
        let in_cut = |(errors, parents): &(Vec<f32>, Vec<f32>)| at_most(errors) - at_most(parents).min(at_most(errors));
        // Needles with e < 2R are prisms: the radii above e / 2.
        let first_prism = self.radii.partition_point(|&r| e >= line_error(r));
        let prisms = &self.radii[first_prism..];
        let mut triangles = 0u64;
        let mut start = 0;
        while start < prisms.len() {
            let sides = prism_sides(relative_error(e, prisms[start]), self.max_sides);
            // Side counts grow with the radius: the run of this count ends
            // at the first needle with more sides.
            let end = start
                + prisms[start..].partition_point(|&r| prism_sides(relative_error(e, r), self.max_sides) <= sides);
            triangles += (end - start) as u64 * prism_triangle_count(sides) as u64;
            start = end;
        }
        CutCounts {
            prisms: prisms.len() as u64,
            triangles,
            // An original line is in the cut only when it is not a prism.
            lines_original: in_cut(&self.original),
            lines_merged: in_cut(&self.merged),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};
    use crate::model::{BakeOptions, bake};

    /// Built from the prototypes, the counter holds the flattened tree's
    /// sorted errors, bit for bit.
    #[test]
    fn the_prototypes_counter_is_the_flattened_tree_s() {
        for species in [Species::ScotsPine, Species::NorwaySpruce] {
            let input = crate::generate::generate_prototypes(
                species,
                &GenerateOptions {
                    seed: 4,
                    target_needles: Some(20_000),
                    age: crate::generate::Age::Mature,
                },
            );
            let record = crate::model::bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
            let flat = CutCounter::new(&record.flatten().unwrap());
            let placed = CutCounter::from_prototypes(&record);
            assert!(placed.merged.0.len() > 1000, "{species:?}");
            assert_eq!(placed.radii, flat.radii, "{species:?}");
            assert_eq!(placed.original, flat.original, "{species:?}");
            assert_eq!(placed.merged, flat.merged, "{species:?}");
        }
    }

    #[test]
    fn counts_equal_the_traversal() {
        for species in [Species::ScotsPine, Species::LawsonCypress] {
            let tree = generate(
                species,
                &GenerateOptions {
                    seed: 2,
                    target_needles: Some(5000),
                    age: crate::generate::Age::Young,
                },
            );
            let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
            let counter = CutCounter::new(&record);
            let mut probes: Vec<f32> = (0..record.node_count() as u32)
                .step_by(7)
                .flat_map(|k| {
                    [
                        record.node_error(k),
                        record.node_error(k) * 1.0001,
                        record.node_error(k) * 0.6,
                    ]
                })
                .collect();
            probes.extend([0.0, -1.0, 1e-5, 1e9, f32::INFINITY]);
            for e in probes {
                let expected = CutCounts::from(&record.cut_stats(&record.cut(e.max(0.0))));
                assert_eq!(counter.count(e), expected, "{species:?} at e = {e}");
            }
        }
    }
}
