//! The LOD model, free of Bevy: what the paper computes, and the record it
//! writes.
//!
//! * [`needle`]: the input (needles, wood, material).
//! * [`metric`]: spatial error, prism side counts, line opacity.
//! * [`prism`]: prism tessellation of a needle.
//! * [`merge`]: the two-level line merging and its cost function.
//! * [`record`]: the LOD record (merge forest, error ranges) and the cut.
//! * [`prototype`]: a tree as shared prototypes placed many times (record format 3).
//! * [`cut_count`]: the cut's primitive counts at any error without a traversal.
//! * [`file`](mod@file): the binary record file.
//! * [`compact`]: the compact GPU arrays the plugin draws and the CPU reference of its passes.
//! * [`raster`]: how a line covers pixels (its strip's area in each).
//! * [`shading`]: how a line is lit, as the cylinder it stands for.
//! * [`calibration`]: line opacity calibrated against the needles' coverage, by pixel size.
//! * [`impostor`]: the far representation (a crown impostor of a few views).
//! * [`crown_shade`]: a crown's shade on itself past the shadow maps' range.
//! * [`look`]: how the whole tree looks from afar (its crown's see-through).
//! * [`color`]: colour within a tree (needles by age and side, bark by height).
//! * [`view`]: view-dependent detail inside a tree (bounding spheres, errors per placement).
//! * [`wind`]: wind, one displacement field per tree that every representation shares.

pub mod bake;
pub mod calibration;
pub mod color;
pub mod compact;
pub mod crown_shade;
pub mod cut_count;
pub mod file;
pub mod impostor;
pub mod look;
pub mod merge;
pub mod metric;
pub mod needle;
pub mod prism;
pub mod prototype;
pub mod quantize;
pub mod raster;
pub mod record;
pub mod shading;
pub mod view;
pub mod wind;

pub use bake::{
    BakeError, BakeOptions, BakeProgress, BakeStage, StageSeconds, StageTimer, bake, bake_impostor, bake_prototypes,
    paper_model,
};
pub use cut_count::{CutCounter, CutCounts};
pub use file::{
    RecordError, decode_prototype_record, decode_record, encode_prototype_record, encode_record, read_prototype_record,
    read_record, write_prototype_record, write_record,
};
pub use merge::{MergeCostRule, MergeErrorBound, MergeOptions, MergeWeights, PartnerSearch};
pub use metric::{PixelError, ViewParams, spatial_error};
pub use needle::*;
pub use prototype::{Placement, Prototype, PrototypeInput, PrototypeRecord};
pub use record::{Cut, CutStats, LodRecord, Representation};
pub use view::{Sphere, ViewPoint};
