//! The bake: from a [`TreeInput`] to a [`LodRecord`] (paper, §4–5.1).

use super::file::snap_normal;
use super::merge::{MergeLevel, MergeOptions, MergeProgress, merge_tree};
use super::metric::{MAX_PRISM_SIDES, MIN_PRISM_SIDES};
use super::needle::TreeInput;
use super::record::{BakeInfo, LodRecord, RecordInvalid};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Options of a bake.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BakeOptions {
    /// `Lmax`: most sides of a needle's prism, in `[3, 64]` (default 8).
    pub max_sides: u8,
    /// Line-merging options.
    pub merge: MergeOptions,
}

impl Default for BakeOptions {
    fn default() -> Self {
        Self {
            max_sides: 8,
            merge: MergeOptions::default(),
        }
    }
}

/// Why a bake failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BakeError {
    /// The input has no needles.
    #[error("the tree has no needles")]
    NoNeedles,
    /// A needle has a NaN, a radius ≤ 0 or a zero-length centerline.
    #[error("needle {index} is invalid (non-finite, radius ≤ 0 or zero length)")]
    InvalidNeedle {
        /// Index of the needle in the input.
        index: usize,
    },
    /// The wood mesh has an index out of range, a partial triangle, a
    /// normal count unlike its position count, or a non-finite number.
    #[error("the wood mesh is inconsistent (index out of range, partial triangle or non-finite number)")]
    InvalidWoodMesh,
    /// `max_sides` is outside `[3, 64]`.
    #[error("max sides {0} is outside [3, 64]")]
    MaxSides(u8),
    /// Merge weights negative, non-finite or all zero.
    #[error("merge weights must be finite, non-negative and not all zero")]
    Weights,
    /// More needles than a record can index.
    #[error("{0} needles: a record holds at most 2^31 − 1")]
    TooManyNeedles(usize),
    /// The result failed the record's own checks (a bug, reported, not a panic).
    #[error("internal: the baked record is inconsistent: {0}")]
    Inconsistent(#[from] RecordInvalid),
}

/// A stage of the bake, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BakeStage {
    /// Merging inside phyllotaxy groups.
    MergeGroups,
    /// Merging across the tree.
    MergeTree,
}

/// Receives progress of a bake.
pub trait BakeProgress: Sync {
    /// `done` of `total` steps of `stage` are finished.
    fn progress(&self, stage: BakeStage, done: usize, total: usize);
}

impl BakeProgress for () {
    fn progress(&self, _: BakeStage, _: usize, _: usize) {}
}

/// A [`BakeProgress`] that passes reports on to another and notes when each
/// stage last reported, so a bake's time splits into merge level 1 (groups),
/// level 2 (whole tree) and the rest (validation, record assembly).
pub struct StageTimer<'a> {
    inner: &'a dyn BakeProgress,
    start: Instant,
    last: std::sync::Mutex<[Option<f64>; 2]>,
}

/// Seconds of a bake's stages, from a [`StageTimer`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageSeconds {
    /// Level 1: merging inside phyllotaxy groups (with the needle sort before it).
    pub merge_groups: f64,
    /// Level 2: merging across the tree.
    pub merge_tree: f64,
    /// The rest of the bake: validation and building the record.
    pub record: f64,
}

impl<'a> StageTimer<'a> {
    /// Starts the clock now; reports go on to `inner`.
    pub fn new(inner: &'a dyn BakeProgress) -> Self {
        Self {
            inner,
            start: Instant::now(),
            last: std::sync::Mutex::new([None, None]),
        }
    }

    /// The split of `total` seconds (the whole bake, timed by the caller
    /// from [`StageTimer::new`]): each stage ends at its last report. A
    /// stage that never reported (no groups, one line) takes no time.
    pub fn seconds(&self, total: f64) -> StageSeconds {
        let last = *self.last.lock().unwrap_or_else(|e| e.into_inner());
        let groups_end = last[0].unwrap_or(0.0);
        let tree_end = last[1].unwrap_or(groups_end).max(groups_end);
        StageSeconds {
            merge_groups: groups_end,
            merge_tree: tree_end - groups_end,
            record: (total - tree_end).max(0.0),
        }
    }
}

impl BakeProgress for StageTimer<'_> {
    fn progress(&self, stage: BakeStage, done: usize, total: usize) {
        let now = self.start.elapsed().as_secs_f64();
        let slot = match stage {
            BakeStage::MergeGroups => 0,
            BakeStage::MergeTree => 1,
        };
        if let Ok(mut last) = self.last.lock() {
            last[slot] = Some(last[slot].map_or(now, |t: f64| t.max(now)));
        }
        self.inner.progress(stage, done, total);
    }
}

struct Adapter<'a>(&'a dyn BakeProgress);

impl MergeProgress for Adapter<'_> {
    fn merged(&self, level: MergeLevel, done: usize, total: usize) {
        let stage = match level {
            MergeLevel::Group => BakeStage::MergeGroups,
            MergeLevel::Tree => BakeStage::MergeTree,
        };
        self.0.progress(stage, done, total);
    }
}

/// Bakes a tree: validates the needles, sorts them by group (renumbering
/// groups `0..groups` in order of first appearance), snaps normals to the
/// record's storage precision, runs the two-level merge and builds the record.
pub fn bake(input: &TreeInput, options: &BakeOptions, progress: &dyn BakeProgress) -> Result<LodRecord, BakeError> {
    let start = Instant::now();
    if input.needles.is_empty() {
        return Err(BakeError::NoNeedles);
    }
    if input.needles.len() >= i32::MAX as usize {
        return Err(BakeError::TooManyNeedles(input.needles.len()));
    }
    if !(MIN_PRISM_SIDES..=MAX_PRISM_SIDES).contains(&options.max_sides) {
        return Err(BakeError::MaxSides(options.max_sides));
    }
    if !options.merge.weights.is_valid() {
        return Err(BakeError::Weights);
    }
    if let Some(index) = input.needles.iter().position(|n| !n.is_valid()) {
        return Err(BakeError::InvalidNeedle { index });
    }
    if !input.wood_mesh.is_valid() {
        return Err(BakeError::InvalidWoodMesh);
    }

    // Renumber groups by first appearance, then sort stably by group.
    let mut renumber = std::collections::HashMap::new();
    let mut needles = input.needles.clone();
    for needle in &mut needles {
        let next = renumber.len() as u32;
        needle.group = *renumber.entry(needle.group).or_insert(next);
        needle.normal = snap_normal(needle.normal);
    }
    needles.sort_by_key(|n| n.group);

    let forest = merge_tree(&needles, &options.merge, &Adapter(progress));
    let info = BakeInfo {
        weights: options.merge.weights,
        bake_seconds: None,
        source: input.name.clone(),
    };
    let mut wood_mesh = input.wood_mesh.clone();
    for normal in &mut wood_mesh.normals {
        *normal = snap_normal(*normal);
    }
    let mut record = LodRecord::from_parts(
        input.name.clone(),
        needles,
        forest.merged,
        input.wood.clone(),
        wood_mesh,
        input.material,
        options.max_sides,
        info,
    )?;
    record.bake.bake_seconds = Some(start.elapsed().as_secs_f64());
    Ok(record)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generate::{GenerateOptions, Species, generate};

    #[test]
    fn stage_timer_splits_the_bake_in_order() {
        let tree = generate(
            Species::NorwaySpruce,
            &GenerateOptions {
                seed: 3,
                target_needles: Some(4000),
            },
        );
        let timer = StageTimer::new(&());
        let record = bake(&tree, &BakeOptions::default(), &timer).unwrap();
        let total = timer.start.elapsed().as_secs_f64();
        let s = timer.seconds(total);
        assert!(!record.merged.is_empty());
        assert!(s.merge_groups > 0.0 && s.merge_tree > 0.0 && s.record >= 0.0, "{s:?}");
        assert!((s.merge_groups + s.merge_tree + s.record - total).abs() < 1e-9);
        // Nothing reported: everything is the record stage.
        let idle = StageTimer::new(&());
        assert_eq!(
            idle.seconds(2.0),
            StageSeconds {
                merge_groups: 0.0,
                merge_tree: 0.0,
                record: 2.0
            }
        );
    }
}
