//! # bevy_conifer_lod
//!
//! Continuous level of detail for coniferous foliage, after Deng, Zhang, Gay
//! and Lei, *Continuous LOD Model of Coniferous Foliage*, IJVR 6(4), 2007.
//!
//! Close needles are drawn as round prisms whose side count follows the
//! viewer's distance; needles thinner than a pixel become translucent lines;
//! far lines merge hierarchically, so a distant tree costs a few thousand
//! lines or fewer.
//!
//! Data flows one way:
//!
//! ```text
//! input (generate / import) → bake (model::bake) → record file (model::file)
//!        → asset → GPU
//! ```
//!
//! * [`model`]: the Bevy-free LOD model: needles, error math, prisms, the
//!   merge forest, the cut, and the binary record file.
//! * [`generate`]: deterministic procedural conifers (our default input).
//! * [`preview`]: a small CPU rasterizer for preview pictures.
//! * [`import`]: trees from glTF files (needles found, split, fitted, grouped).
//! * [`export`]: glTF files of LOD cuts and of tree inputs.
//! * [`scatter`]: blue-noise placement of trees on terrain.
//! * `plugin` (feature `plugin`): the Bevy plugin.
//! * `bench` (feature `eval`): `conifer bench`, cost against needles,
//!   instances and views.
//! * `eval` (feature `eval`): `conifer eval`, the plugin measured against a
//!   supersampled reference and its peers.
#![deny(missing_docs)]

pub mod export;
pub mod generate;
pub mod import;
pub mod model;
pub mod preview;
pub mod scatter;

#[cfg(feature = "eval")]
pub mod bench;
#[cfg(feature = "cli")]
pub mod cli;
#[cfg(feature = "eval")]
pub mod eval;
#[cfg(feature = "plugin")]
pub mod plugin;

/// The types a Bevy user needs: `use bevy_conifer_lod::prelude::*;`.
#[cfg(feature = "plugin")]
pub mod prelude {
    pub use crate::generate::{Age, Preset, Species};
    pub use crate::plugin::{
        ConiferFoliage, ConiferLodDebug, ConiferLodDebugPlugin, ConiferLodOverride, ConiferLodPlugin, ConiferLodSet,
        ConiferLodSettings, ConiferLodState, ConiferLodStats, ConiferPresets, ConiferSpecies, ConiferWind, ErrorScope,
        LineLighting, LineOpacity, LineOrder, LineRaster, PresetCache, WoodLineOrder, conifer_lod_keys, spawn_forest,
    };
}

/// The README's Rust blocks, compiled (and the `no_run` one type-checked)
/// as doc tests: the snippet a new user copies cannot rot.
#[cfg(all(doctest, feature = "plugin"))]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
