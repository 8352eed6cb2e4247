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
