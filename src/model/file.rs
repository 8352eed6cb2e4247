//! The binary record file (`.conifer`).
//!
//! ```text
//! offset  size  field
//! 0       8     magic  b"CONIFLOD"
//! 8       4     format version, u32 little-endian (FORMAT_VERSION)
//! 12      8     payload length in bytes, u64 little-endian
//! 20      4     CRC-32 (IEEE) of the payload, u32 little-endian
//! 24      …     payload: postcard (serde) encoding of the record
//! ```
//!
//! The payload (format 3) is a tree of shared prototypes placed many times
//! ([`PrototypeRecord`]); it stores only what cannot be derived:
//!
//! * each prototype's needles as cylinders: base, tip, radius (f32) and the
//!   normal in 4 bytes (octahedral, 16 bits a coordinate); prisms are
//!   rebuilt at load time, original lines are the needles' centerlines;
//! * each merged line (a prototype's level-1 lines, and the level-2 lines
//!   over the placements) as its two children (varint distances back from
//!   its own id), one byte saying which two of the children's four ends it
//!   keeps, and its error (f32);
//! * each placement as its prototype id (varint) and, unless it is the
//!   identity, its rotation (the three smaller quaternion components, 20
//!   bits each), translation (24 bits an axis, 7.6 µm apart) and scale
//!   (f32) ([`super::quantize::RotationCode`],
//!   [`super::quantize::TranslationCode`]);
//! * wood segments, material and bake information;
//! * the wood mesh of imported trees: positions (f32), normals (4-byte
//!   octahedral) and indices as zigzag varint differences from the previous
//!   index (neighbouring triangles share nearby vertices: 1–2 bytes each);
//! * after that payload (format 5), the material's extra colours and the
//!   placements' needle ages as runs of one age (a byte and a varint
//!   length; neighbouring shoots are mostly of an age);
//! * after those (format 7), the crown impostor the record was baked with,
//!   if any ([`super::impostor::CrownImpostor`]): its frame, and its texels
//!   as four planes (coverage, wood, and the two lighting shares times
//!   coverage), deflated (a quarter
//!   of their size on the mature records; the plugin no longer bakes it at
//!   load);
//! * after that (format 9), the line opacity scales by pixel size the
//!   record was calibrated with, if any
//!   ([`super::calibration::LineCalibration`]: two pixel sizes and eight
//!   scales, f32).
//! * after that (format 10), with the impostor, how much of its wood the
//!   needles leave in sight by height and depth in the crown
//!   ([`super::impostor::WoodVisibility`], a byte a share).
//! * after that (format 11), with the line calibration, the wood lines'
//!   opacity scales at its pixel sizes and four opacities
//!   ([`super::calibration::LineCalibration::wood_scales`], 32 f32).
//!
//! A flat record ([`LodRecord`], an imported tree) is written as every group
//! a prototype placed once ([`PrototypeRecord::from_flat`]); reading gives
//! either view ([`decode_record`] flattens).
//!
//! Version 15 adds how the impostor's direct light is scaled so that its
//! texels are lit as the needles its views show
//! ([`super::impostor::ViewLightScale`]: 91 `f32`s by the light's
//! direction, with the impostor); an older impostor is lit as its shares
//! say (every scale 1), and `conifer upgrade` measures the scales into the
//! file.
//! Version 14 adds the mix of needle ages and sides the impostor's views
//! see first ([`super::color::NeedleMix::seen`]: six `f32`s, with the
//! impostor), which colours the far crown; an older impostor's crown takes
//! its needles' area mean, as it was drawn, and `conifer upgrade`
//! measures the mix into the file.
//! Version 13 adds the impostor's crown density (how its needles fill
//! it by height and distance from the axis, where its shadow samples go:
//! [`super::impostor::CrownDensity`]); an older impostor reads with its
//! needles even through the crown, as it was drawn, and `conifer upgrade`
//! measures the density into the file.
//! Version 12 keeps 11's layout; its impostor texels and line
//! calibration are measured against the needles' capped silhouettes (each
//! prism's end caps seen at its slant, [`super::look::PieceEnds`]), where
//! 11's left the caps out: an older file reads as it is, `conifer upgrade`
//! bakes both again.
//! Version 11 adds the wood lines' scales to the line calibration (an
//! older file's reads with every wood scale 1, as it was drawn;
//! `conifer upgrade` calibrates the file again).
//! Version 10 adds the impostor's wood visibility: an older file's
//! impostor is dropped (the plugin bakes it at load, `conifer upgrade`
//! into the file).
//! Version 9 adds the line calibration (older files read without one:
//! every line keeps its opacity; `conifer upgrade` calibrates them).
//! Version 8 stores each impostor texel's lighting as shares of two
//! cylinders and a sphere where version 7 stored one mean needle axis: a
//! version 7 file reads without its impostor, as a version 6 file does.
//! Version 7 adds the crown impostor (version 6 files read without one:
//! the plugin bakes it at load, `conifer upgrade` bakes it into the file).
//! Version 6 stores placements on codes (format 5 stored `f32`s: 34 bytes
//! a placement, 23–24 now); version 5 added needle ages and the colours by
//! age, side and height; version 4 files read as one colour per tree,
//! every needle mature.
//! Version 3 added prototypes and placements. Version 2 files (flat, with
//! the wood mesh) are still read and converted; version 1 files are refused
//! with [`RecordError::UnsupportedVersion`] (re-bake them).
//!
//! Decoding checks everything: a truncated, corrupted, wrong-version,
//! malformed or NaN-carrying file, an unknown prototype id, or placements
//! standing for more needles than a record holds give a [`RecordError`],
//! never a panic or an allocation beyond the file's own size (plus the
//! flattened tree, bounded by [`super::prototype::MAX_PLACED_NEEDLES`]).

use super::calibration::{CALIBRATION_STEPS, LineCalibration, WOOD_OPACITY_NODES};
use super::color::{NEEDLE_AGE_CLASSES, NeedleMix};
use super::impostor::{CrownDensity, CrownImpostor, VIEW_LIGHT_SCALE_RANGE, ViewLightScale, WoodVisibility};
use super::merge::{EndpointId, MergeWeights, MergedLine};
use super::needle::{FoliageMaterial, Needle, WoodSegment};
use super::prism::TriangleMesh;
use super::prototype::{MAX_PLACED_NEEDLES, Placement, Prototype, PrototypeRecord};
use super::quantize::{
    PositionGrid, RotationCode, TranslationCode, log_decode, log_encode_at_least, log_encode_nearest, placement_codes,
};
use super::record::{BakeInfo, LodRecord, RecordInvalid};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::path::Path;
use std::sync::Arc;

/// First eight bytes of every record file.
pub const MAGIC: [u8; 8] = *b"CONIFLOD";

/// Format version written.
pub const FORMAT_VERSION: u32 = 15;

/// The oldest format version still read (converted on load).
pub const OLDEST_READ_VERSION: u32 = 2;

/// Size of the fixed header before the payload.
pub const HEADER_BYTES: usize = 24;

/// What to do about a record of format `found`, which this build (reading
/// `OLDEST_READ_VERSION..=supported`) cannot read.
fn unsupported_version_advice(found: &u32, supported: &u32) -> String {
    if found > supported {
        format!(
            "record format version {found} is newer than this build of bevy_conifer_lod reads (versions {OLDEST_READ_VERSION} to {supported}): update bevy_conifer_lod, or re-bake the tree with this version's `conifer bake`"
        )
    } else {
        format!(
            "record format version {found} is too old for this build (it reads versions {OLDEST_READ_VERSION} to {supported}): re-bake the tree with this version's `conifer bake`"
        )
    }
}

/// Why a record could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Reading or writing the file failed.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
    /// The data does not start with the record magic number.
    #[error("not a conifer LOD record (bad magic number)")]
    NotARecord,
    /// The file was written by another format version.
    #[error("{}", unsupported_version_advice(.found, .supported))]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Newest version this build reads (and the one it writes).
        supported: u32,
    },
    /// The file ends before the header or payload does.
    #[error("record is truncated: {expected} bytes expected, {found} present")]
    Truncated {
        /// Bytes the header announces (header included).
        expected: u64,
        /// Bytes present.
        found: u64,
    },
    /// Bytes follow the payload.
    #[error("record has {0} unexpected bytes after its payload")]
    TrailingBytes(u64),
    /// The payload's checksum does not match: the file is corrupted.
    #[error("record is corrupted: checksum {computed:#010x} does not match the stored {stored:#010x}")]
    ChecksumMismatch {
        /// Checksum in the header.
        stored: u32,
        /// Checksum of the payload read.
        computed: u32,
    },
    /// The payload does not decode.
    #[error("record payload is malformed: {0}")]
    Malformed(String),
    /// The payload decodes but breaks an invariant of the record.
    #[error("record is invalid: {0}")]
    Invalid(#[from] RecordInvalid),
}

#[derive(Serialize, Deserialize)]
struct MergedEntry {
    /// `id − child` for both children (≥ 1).
    back: [u32; 2],
    /// Bits 0–1: index of end 0 among the children's four ends
    /// `[c0.end0, c0.end1, c1.end0, c1.end1]`; bits 2–3: end 1.
    ends: u8,
    error: f32,
}

/// The wood mesh as stored.
#[derive(Default, Serialize, Deserialize)]
struct StoredMesh {
    positions: Vec<[f32; 3]>,
    normals: Vec<[u8; 4]>,
    /// `index[k] − index[k − 1]` (the first relative to 0), zigzag varints.
    index_steps: Vec<i64>,
}

/// Indices as `index[k] − index[k − 1]` (the first relative to 0).
fn index_steps(indices: &[u32]) -> Vec<i64> {
    let mut previous = 0i64;
    indices
        .iter()
        .map(|&i| {
            let step = i as i64 - previous;
            previous = i as i64;
            step
        })
        .collect()
}

/// The indices of [`index_steps`]' output; an index leaving `u32` is a bad mesh.
fn indices_from_steps(steps: &[i64]) -> Result<Vec<u32>, RecordError> {
    let mut previous = 0i64;
    let mut indices = Vec::with_capacity(steps.len());
    for &step in steps {
        previous = previous
            .checked_add(step)
            .filter(|i| (0..=u32::MAX as i64).contains(i))
            .ok_or(RecordInvalid::BadWoodMesh)?;
        indices.push(previous as u32);
    }
    Ok(indices)
}

impl StoredMesh {
    fn decode(self) -> Result<TriangleMesh, RecordError> {
        Ok(TriangleMesh {
            positions: self.positions.into_iter().map(Vec3::from).collect(),
            normals: self.normals.into_iter().map(decode_normal).collect(),
            indices: indices_from_steps(&self.index_steps)?,
        })
    }
}

/// The wood mesh as format 4 stores it: positions on a [`PositionGrid`]
/// over the mesh (three 16-bit codes), the rest as format 3.
#[derive(Serialize, Deserialize)]
struct QuantizedMesh {
    grid: ([i32; 3], i8),
    positions: Vec<[u8; 6]>,
    normals: Vec<[u8; 4]>,
    index_steps: Vec<i64>,
}

impl QuantizedMesh {
    /// `mesh`, whose positions lie on `grid`
    /// ([`PrototypeRecord::quantized`]).
    fn encode(mesh: &TriangleMesh, grid: &PositionGrid) -> Self {
        Self {
            grid: grid.to_codes(),
            positions: mesh.positions.iter().map(|&p| grid_bytes(grid.encode(p))).collect(),
            normals: mesh.normals.iter().map(|&n| encode_normal(n)).collect(),
            index_steps: index_steps(&mesh.indices),
        }
    }

    fn decode(self) -> Result<TriangleMesh, RecordError> {
        let grid = PositionGrid::from_codes(self.grid.0, self.grid.1).ok_or(RecordInvalid::BadWoodMesh)?;
        Ok(TriangleMesh {
            positions: self.positions.into_iter().map(|p| grid.decode(grid_codes(p))).collect(),
            normals: self.normals.into_iter().map(decode_normal).collect(),
            indices: indices_from_steps(&self.index_steps)?,
        })
    }
}

/// The material as formats 2–4 store it: one needle and one bark colour.
#[derive(Clone, Copy, Serialize, Deserialize)]
struct StoredMaterial {
    needle_color: [f32; 4],
    wood_color: [f32; 4],
    roughness: f32,
    reflectance: f32,
}

impl From<&FoliageMaterial> for StoredMaterial {
    fn from(m: &FoliageMaterial) -> Self {
        Self {
            needle_color: m.needle_color,
            wood_color: m.wood_color,
            roughness: m.roughness,
            reflectance: m.reflectance,
        }
    }
}

impl From<StoredMaterial> for FoliageMaterial {
    fn from(m: StoredMaterial) -> Self {
        FoliageMaterial::uniform(m.needle_color, m.wood_color, m.roughness, m.reflectance)
    }
}

/// What format 5 adds after the payload: the material's colours by age,
/// side and height, and the placements' needle ages, in order, as runs
/// `(age, placements)`.
/// The crown impostor as stored (format 7, after the appearance): its
/// frame, and its texels as four planes (coverage, wood, axis x, axis z),
/// each view after view, row after row, deflated at the best compression.
/// (Differences from the texel to the left or above deflate 5–10 % larger
/// on the mature records: a crown's texels are noisy.)
#[derive(Serialize, Deserialize)]
struct StoredImpostor {
    views: u32,
    columns: u32,
    rows: u32,
    axis: [f32; 2],
    half_width: f32,
    bottom: f32,
    texel: f32,
    planes: Vec<u8>,
}

/// Most views a stored impostor may have.
const MAX_STORED_VIEWS: u32 = 64;

/// Most texel bytes a stored impostor may inflate to (views × rows ×
/// columns × 4): 64 views of 512 × 1,024 texels.
const MAX_STORED_IMPOSTOR_BYTES: u64 = 64 * 512 * 1024 * 4;

impl StoredImpostor {
    fn encode(impostor: &CrownImpostor) -> Result<Self, RecordError> {
        let mut planes = Vec::with_capacity(4 * impostor.texels.len());
        for channel in 0..4 {
            planes.extend(impostor.texels.iter().map(|texel| texel[channel]));
        }
        let mut deflater = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
        deflater.write_all(&planes)?;
        Ok(Self {
            views: impostor.views,
            columns: impostor.columns,
            rows: impostor.rows,
            axis: impostor.axis.to_array(),
            half_width: impostor.half_width,
            bottom: impostor.bottom,
            texel: impostor.texel,
            planes: deflater.finish()?,
        })
    }

    fn decode(self) -> Result<CrownImpostor, RecordError> {
        let malformed = |what: &str| RecordError::Malformed(format!("impostor: {what}"));
        if !(1..=MAX_STORED_VIEWS).contains(&self.views) || self.rows == 0 || self.columns == 0 {
            return Err(malformed("no texels or too many views"));
        }
        // At most 64 × (2³² − 1)² × 4 < 2⁷²: checked.
        let texel_bytes = (u64::from(self.views) * 4)
            .checked_mul(u64::from(self.rows) * u64::from(self.columns))
            .filter(|&bytes| bytes <= MAX_STORED_IMPOSTOR_BYTES)
            .ok_or_else(|| malformed("too many texels"))?;
        let frame = [self.axis[0], self.axis[1], self.half_width, self.bottom, self.texel];
        let positive = self.texel > 0.0 && self.half_width > 0.0;
        if !(positive && frame.iter().all(|v| v.is_finite())) {
            return Err(malformed("its frame is not finite and positive"));
        }
        let mut planes = Vec::with_capacity(texel_bytes as usize);
        flate2::read::DeflateDecoder::new(self.planes.as_slice())
            .take(texel_bytes + 1)
            .read_to_end(&mut planes)
            .map_err(|e| malformed(&format!("texels do not inflate ({e})")))?;
        if planes.len() as u64 != texel_bytes {
            return Err(malformed("texels of another size than its frame"));
        }
        let texel_count = planes.len() / 4;
        let plane = |channel: usize, k: usize| planes[channel * texel_count + k];
        let texels = (0..texel_count)
            .map(|k| [plane(0, k), plane(1, k), plane(2, k), plane(3, k)])
            .collect();
        Ok(CrownImpostor {
            views: self.views,
            columns: self.columns,
            rows: self.rows,
            axis: glam::Vec2::from_array(self.axis),
            half_width: self.half_width,
            bottom: self.bottom,
            texel: self.texel,
            texels,
            wood_visibility: Default::default(),
            crown_density: Default::default(),
            seen_needles: None,
            view_light_scale: None,
        })
    }
}

#[derive(Serialize, Deserialize)]
struct StoredAppearance {
    young_needle_color: [f32; 4],
    needle_underside_color: [f32; 4],
    upper_wood_color: [f32; 4],
    upper_wood_heights: [f32; 2],
    age_runs: Vec<(u8, u32)>,
}

impl StoredAppearance {
    fn encode(record: &PrototypeRecord) -> Self {
        let m = &record.material;
        Self {
            young_needle_color: m.young_needle_color,
            needle_underside_color: m.needle_underside_color,
            upper_wood_color: m.upper_wood_color,
            upper_wood_heights: m.upper_wood_heights,
            age_runs: record.placements.iter().fold(Vec::new(), |mut runs, p| {
                match runs.last_mut() {
                    Some((age, run)) if *age == p.needle_age && *run < u32::MAX => *run += 1,
                    _ => runs.push((p.needle_age, 1)),
                }
                runs
            }),
        }
    }

    /// `material` with these colours, and `placements` with these ages.
    fn apply(self, material: &mut FoliageMaterial, placements: &mut [Placement]) -> Result<(), RecordError> {
        let ages: u64 = self.age_runs.iter().map(|&(_, run)| u64::from(run)).sum();
        if ages != placements.len() as u64 {
            return Err(RecordError::Malformed(format!(
                "{ages} needle ages for {} placements",
                placements.len()
            )));
        }
        material.young_needle_color = self.young_needle_color;
        material.needle_underside_color = self.needle_underside_color;
        material.upper_wood_color = self.upper_wood_color;
        material.upper_wood_heights = self.upper_wood_heights;
        let ages = self
            .age_runs
            .iter()
            .flat_map(|&(age, run)| std::iter::repeat_n(age, run as usize));
        for (placement, age) in placements.iter_mut().zip(ages) {
            placement.needle_age = age;
        }
        Ok(())
    }
}

/// The payload of a format 2 file: one flat tree.
#[derive(Serialize, Deserialize)]
struct PayloadV2 {
    name: String,
    source: String,
    bake_seconds: Option<f64>,
    weights: [f32; 3],
    max_sides: u8,
    material: StoredMaterial,
    group_sizes: Vec<u32>,
    needles: StoredNeedles,
    merged: Vec<MergedEntry>,
    wood: Vec<[f32; 8]>,
    wood_mesh: StoredMesh,
}

/// The payload of a format 3 or 4 file: prototypes and placements. Format
/// 3 ([`PayloadV3`]) stores needles, errors and the wood mesh as `f32`,
/// format 4 ([`Payload`]) quantized ([`super::quantize`]); decoding turns
/// either into [`DecodedPayload`].
#[derive(Serialize, Deserialize)]
struct PrototypePayload<Prototypes, Merged, Mesh> {
    name: String,
    source: String,
    bake_seconds: Option<f64>,
    weights: [f32; 3],
    max_sides: u8,
    material: StoredMaterial,
    prototypes: Prototypes,
    placements: Vec<StoredPlacement>,
    tree_merged: Vec<Merged>,
    wood: Vec<[f32; 8]>,
    wood_mesh: Mesh,
}

/// A format 3 payload.
type PayloadV3 = PrototypePayload<StoredPrototypes, MergedEntry, StoredMesh>;

/// A format 4 payload.
type Payload = PrototypePayload<QuantizedPrototypes, QuantizedMergedEntry, QuantizedMesh>;

/// A format 3 or 4 payload with its numbers decoded, before its checks.
type DecodedPayload = PrototypePayload<DecodedPrototypes, MergedEntry, TriangleMesh>;

/// Every prototype's needle count, the needles one after the other, and
/// their level-1 merged lines, decoded.
struct DecodedPrototypes {
    needle_counts: Vec<u32>,
    needles: Vec<Needle>,
    merged: Vec<MergedEntry>,
}

impl<P, E, W> PrototypePayload<P, E, W> {
    /// The same payload with its prototypes, merged lines and wood mesh
    /// converted.
    fn convert<P2, E2, W2>(
        self,
        prototypes: impl FnOnce(P) -> Result<P2, RecordError>,
        merged: impl Fn(E) -> E2,
        mesh: impl FnOnce(W) -> Result<W2, RecordError>,
    ) -> Result<PrototypePayload<P2, E2, W2>, RecordError> {
        Ok(PrototypePayload {
            name: self.name,
            source: self.source,
            bake_seconds: self.bake_seconds,
            weights: self.weights,
            max_sides: self.max_sides,
            material: self.material,
            prototypes: prototypes(self.prototypes)?,
            placements: self.placements,
            tree_merged: self.tree_merged.into_iter().map(merged).collect(),
            wood: self.wood,
            wood_mesh: mesh(self.wood_mesh)?,
        })
    }
}

/// Format 4's prototypes: each one's grid, then as format 3 with codes.
#[derive(Serialize, Deserialize)]
struct QuantizedPrototypes {
    needle_counts: Vec<u32>,
    /// Per prototype: its grid's origin in [`super::quantize::GRID_ORIGIN_UNIT`]s
    /// (zigzag varints) and its step's power of two.
    grids: Vec<([i32; 3], i8)>,
    needles: QuantizedNeedles,
    merged: Vec<QuantizedMergedEntry>,
}

/// Needles as format 4 stores them, 18 bytes each: ends as three 16-bit
/// grid codes, the radius as a 16-bit logarithmic code, the normal as the
/// octahedral code (all little-endian bytes, so postcard writes them as
/// they are rather than as varints).
#[derive(Serialize, Deserialize)]
struct QuantizedNeedles {
    bases: Vec<[u8; 6]>,
    tips: Vec<[u8; 6]>,
    radii: Vec<[u8; 2]>,
    normals: Vec<[u8; 4]>,
}

/// A merged line as format 4 stores it: the error as a logarithmic code.
#[derive(Serialize, Deserialize)]
struct QuantizedMergedEntry {
    back: [u32; 2],
    ends: u8,
    error: [u8; 2],
}

fn grid_bytes(codes: [u16; 3]) -> [u8; 6] {
    let [a, b] = codes[0].to_le_bytes();
    let [c, d] = codes[1].to_le_bytes();
    let [e, f] = codes[2].to_le_bytes();
    [a, b, c, d, e, f]
}

fn grid_codes(bytes: [u8; 6]) -> [u16; 3] {
    [
        u16::from_le_bytes([bytes[0], bytes[1]]),
        u16::from_le_bytes([bytes[2], bytes[3]]),
        u16::from_le_bytes([bytes[4], bytes[5]]),
    ]
}

impl QuantizedMergedEntry {
    /// `entry` with its (already quantized) error as its code.
    fn encode(entry: MergedEntry) -> Result<Self, RecordError> {
        let code =
            log_encode_at_least(entry.error).ok_or(RecordInvalid::NonFinite("merged line errors (above 100 km)"))?;
        Ok(Self {
            back: entry.back,
            ends: entry.ends,
            error: code.to_le_bytes(),
        })
    }

    fn decode(&self) -> MergedEntry {
        MergedEntry {
            back: self.back,
            ends: self.ends,
            error: log_decode(u16::from_le_bytes(self.error)),
        }
    }
}

/// Every prototype's needles, one after the other, and their level-1
/// merged lines (a prototype of `n` needles has `n − 1`, so only the needle
/// counts are stored).
#[derive(Serialize, Deserialize)]
struct StoredPrototypes {
    needle_counts: Vec<u32>,
    needles: StoredNeedles,
    merged: Vec<MergedEntry>,
}

/// Needles as stored: four parallel arrays (a nested struct encodes as its
/// fields in order, so format 2's payload keeps its layout).
#[derive(Serialize, Deserialize)]
struct StoredNeedles {
    bases: Vec<[f32; 3]>,
    tips: Vec<[f32; 3]>,
    radii: Vec<f32>,
    normals: Vec<[u8; 4]>,
}

/// A placement as stored: the identity costs a byte or its prototype id.
#[derive(Serialize, Deserialize)]
enum StoredPlacement {
    /// The prototype after the previous placement's (the first: prototype
    /// 0), as it is: a flat tree's groups cost a byte each.
    NextIdentity,
    /// A prototype as it is.
    Identity(u32),
    /// A prototype rotated, scaled and moved, every number an `f32` (format
    /// 3–5; in format 6 a translation beyond
    /// [`super::quantize::MAX_GRID_TRANSLATION`]).
    Similarity(StoredSimilarity<[f32; 4], [f32; 3]>),
    /// A prototype rotated, scaled and moved, rotation and translation on
    /// their codes (format 6): 23–24 bytes instead of 34–35.
    Quantized(StoredSimilarity<[u8; 8], [u8; 9]>),
}

/// A placement's prototype and transform as stored, its rotation and
/// translation as `Rotation` and `Translation` (a newtype variant of a
/// struct encodes as the struct variant formats 3–5 wrote).
#[derive(Serialize, Deserialize)]
struct StoredSimilarity<Rotation, Translation> {
    prototype: u32,
    rotation: Rotation,
    translation: Translation,
    scale: f32,
}

impl<Rotation: Copy, Translation: Copy> StoredSimilarity<Rotation, Translation> {
    /// The placement, its rotation and translation decoded by `rotation`
    /// and `translation`.
    fn placement(
        &self,
        rotation: impl Fn(Rotation) -> glam::Quat,
        translation: impl Fn(Translation) -> Vec3,
    ) -> Placement {
        Placement {
            rotation: rotation(self.rotation),
            translation: translation(self.translation),
            scale: self.scale,
            ..Placement::identity(self.prototype)
        }
    }
}

impl StoredPlacement {
    /// `previous`: the prototype of the placement before, if any.
    fn encode(p: &Placement, previous: Option<u32>) -> Self {
        if p.is_identity() {
            return if previous.map_or(0, |k| k.wrapping_add(1)) == p.prototype {
                Self::NextIdentity
            } else {
                Self::Identity(p.prototype)
            };
        }
        // On codes when the placement is already snapped to them (a bake's
        // is), so that writing and reading stays exact.
        let on_codes = placement_codes(p).filter(|(r, t)| r.decode() == p.rotation && t.decode() == p.translation);
        match on_codes {
            Some((rotation, translation)) => Self::Quantized(StoredSimilarity {
                prototype: p.prototype,
                rotation: rotation.to_bytes(),
                translation: translation.to_bytes(),
                scale: p.scale,
            }),
            None => Self::Similarity(StoredSimilarity {
                prototype: p.prototype,
                rotation: p.rotation.to_array(),
                translation: p.translation.to_array(),
                scale: p.scale,
            }),
        }
    }

    fn decode(&self, previous: Option<u32>) -> Placement {
        match self {
            Self::NextIdentity => Placement::identity(previous.map_or(0, |k| k.wrapping_add(1))),
            Self::Identity(prototype) => Placement::identity(*prototype),
            Self::Similarity(stored) => stored.placement(glam::Quat::from_array, Vec3::from),
            Self::Quantized(stored) => stored.placement(
                |r| RotationCode::from_bytes(r).decode(),
                |t| TranslationCode::from_bytes(t).decode(),
            ),
        }
    }
}

/// Merged lines as stored: children as distances back from the line's own
/// id (`first_id + k`), ends as a selector among the children's four.
/// `ends_of(node, earlier)` gives a node's ends, `earlier` being the merged
/// lines before it.
fn encode_merged(
    lines: &[MergedLine],
    first_id: u32,
    ends_of: impl Fn(u32, &[MergedLine]) -> [EndpointId; 2],
) -> Result<Vec<MergedEntry>, RecordError> {
    let mut entries = Vec::with_capacity(lines.len());
    for (k, line) in lines.iter().enumerate() {
        let id = first_id + k as u32;
        let [c0, c1] = line.children;
        let candidates = [ends_of(c0, &lines[..k]), ends_of(c1, &lines[..k])].concat();
        let find = |end: EndpointId| candidates.iter().position(|&c| c == end);
        let (Some(e0), Some(e1)) = (find(line.ends[0]), find(line.ends[1])) else {
            return Err(RecordInvalid::BadReference(k).into());
        };
        if c0 >= id || c1 >= id {
            return Err(RecordInvalid::BadReference(k).into());
        }
        entries.push(MergedEntry {
            back: [id - c0, id - c1],
            ends: (e0 | (e1 << 2)) as u8,
            error: line.error,
        });
    }
    Ok(entries)
}

/// Inverse of [`encode_merged`]; `ends_of` may refuse a node (an unknown
/// id) with `None`.
fn decode_merged(
    entries: &[MergedEntry],
    first_id: u64,
    ends_of: impl Fn(u32, &[MergedLine]) -> Option<[EndpointId; 2]>,
) -> Result<Vec<MergedLine>, RecordError> {
    let mut merged: Vec<MergedLine> = Vec::with_capacity(entries.len());
    for (k, entry) in entries.iter().enumerate() {
        let id = first_id + k as u64;
        if entry.back.iter().any(|&b| b == 0 || b as u64 > id) || entry.ends >> 4 != 0 {
            return Err(RecordInvalid::BadReference(k).into());
        }
        let children = entry.back.map(|b| (id - b as u64) as u32);
        let (Some(a), Some(b)) = (ends_of(children[0], &merged), ends_of(children[1], &merged)) else {
            return Err(RecordInvalid::BadReference(k).into());
        };
        let candidates = [a, b].concat();
        merged.push(MergedLine {
            ends: [
                candidates[(entry.ends & 3) as usize],
                candidates[(entry.ends >> 2) as usize],
            ],
            children,
            error: entry.error,
        });
    }
    Ok(merged)
}

impl StoredNeedles {
    /// Format 3's needle arrays (written only by the tests' format 3 files).
    #[cfg(test)]
    fn encode(needles: &[Needle]) -> Self {
        Self {
            bases: needles.iter().map(|x| x.base.to_array()).collect(),
            tips: needles.iter().map(|x| x.tip.to_array()).collect(),
            radii: needles.iter().map(|x| x.radius).collect(),
            normals: needles.iter().map(|x| encode_normal(x.normal)).collect(),
        }
    }

    /// The needles, needle `i` in group `group(i)`.
    fn decode(&self, group: impl Fn(usize) -> u32) -> Result<Vec<Needle>, RecordError> {
        let n = self.bases.len();
        if self.tips.len() != n || self.radii.len() != n || self.normals.len() != n {
            return Err(RecordError::Malformed("needle arrays differ in length".into()));
        }
        Ok((0..n)
            .map(|i| Needle {
                base: Vec3::from(self.bases[i]),
                tip: Vec3::from(self.tips[i]),
                radius: self.radii[i],
                normal: decode_normal(self.normals[i]),
                group: group(i),
            })
            .collect())
    }
}

fn encode_wood(wood: &[WoodSegment]) -> Vec<[f32; 8]> {
    wood.iter()
        .map(|s| {
            let (a, b) = (s.start, s.end);
            [a.x, a.y, a.z, b.x, b.y, b.z, s.start_radius, s.end_radius]
        })
        .collect()
}

fn decode_wood(wood: &[[f32; 8]]) -> Vec<WoodSegment> {
    wood.iter()
        .map(|w| WoodSegment {
            start: Vec3::new(w[0], w[1], w[2]),
            end: Vec3::new(w[3], w[4], w[5]),
            start_radius: w[6],
            end_radius: w[7],
        })
        .collect()
}

fn decode_bake_info(weights: [f32; 3], bake_seconds: Option<f64>, source: String) -> Result<BakeInfo, RecordError> {
    if !weights.iter().all(|w| w.is_finite()) {
        return Err(RecordInvalid::NonFinite("merge weights").into());
    }
    let [direction, distance, needle_count] = weights;
    Ok(BakeInfo {
        weights: MergeWeights {
            direction,
            distance,
            needle_count,
        },
        bake_seconds,
        source,
    })
}

/// Octahedral encoding of a unit vector in 2 × 16 bits
/// (Cigolle et al., *A Survey of Efficient Representations for Independent
/// Unit Vectors*, JCGT 2014). A zero or non-finite vector encodes +Z.
pub fn encode_normal(normal: Vec3) -> [u8; 4] {
    // f64 arithmetic makes decode → encode exact for every code.
    let [nx, ny, nz] = normal.to_array().map(f64::from);
    let l1 = nx.abs() + ny.abs() + nz.abs();
    let (mut x, mut y) = if l1 > 0.0 && l1.is_finite() {
        (nx / l1, ny / l1)
    } else {
        (0.0, 0.0)
    };
    if nz < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * if ox >= 0.0 { 1.0 } else { -1.0 };
        y = (1.0 - ox.abs()) * if oy >= 0.0 { 1.0 } else { -1.0 };
    }
    let quantize = |v: f64| (((v.clamp(-1.0, 1.0) * 0.5 + 0.5) * 65535.0).round() as u16).to_le_bytes();
    let [x0, x1] = quantize(x);
    let [y0, y1] = quantize(y);
    [x0, x1, y0, y1]
}

/// Inverse of [`encode_normal`]: a unit vector.
pub fn decode_normal(code: [u8; 4]) -> Vec3 {
    let unquantize = |lo: u8, hi: u8| u16::from_le_bytes([lo, hi]) as f64 / 65535.0 * 2.0 - 1.0;
    let (x, y) = (unquantize(code[0], code[1]), unquantize(code[2], code[3]));
    let z = 1.0 - x.abs() - y.abs();
    let t = (-z).max(0.0);
    let x = x + if x >= 0.0 { -t } else { t };
    let y = y + if y >= 0.0 { -t } else { t };
    let length = (x * x + y * y + z * z).sqrt();
    Vec3::new((x / length) as f32, (y / length) as f32, (z / length) as f32)
}

/// The normal as the record stores it: `decode_normal(encode_normal(n))`.
/// Bakes snap normals so that writing and reading a record is exact.
pub fn snap_normal(normal: Vec3) -> Vec3 {
    decode_normal(encode_normal(normal))
}

fn node_ends(needles: usize, merged: &[MergedLine], node: u32) -> Option<[EndpointId; 2]> {
    if (node as usize) < needles {
        Some([2 * node, 2 * node + 1])
    } else {
        merged.get(node as usize - needles).map(|m| m.ends)
    }
}

/// Encodes a tree of prototypes into the bytes of a record file (format 4).
/// The record is quantized first: decoding the bytes gives
/// [`PrototypeRecord::quantized`]`(record)`, and for a baked record (already
/// quantized) the record itself.
pub fn encode_prototype_record(record: &PrototypeRecord) -> Result<Vec<u8>, RecordError> {
    let quantized = record.quantized_on_grids()?;
    let record = &quantized.record;
    let mut grids = Vec::with_capacity(record.prototypes.len());
    let mut needles = QuantizedNeedles {
        bases: Vec::new(),
        tips: Vec::new(),
        radii: Vec::new(),
        normals: Vec::new(),
    };
    let mut merged = Vec::new();
    for (prototype, grid) in record.prototypes.iter().zip(&quantized.prototype_grids) {
        grids.push(grid.to_codes());
        for needle in &prototype.needles {
            needles.bases.push(grid_bytes(grid.encode(needle.base)));
            needles.tips.push(grid_bytes(grid.encode(needle.tip)));
            let radius = log_encode_nearest(needle.radius).ok_or(RecordInvalid::NonFinite("needle radii"))?;
            needles.radii.push(radius.to_le_bytes());
            needles.normals.push(encode_normal(needle.normal));
        }
        let n = prototype.needles.len();
        for entry in encode_merged(&prototype.merged, n as u32, |c, earlier| {
            node_ends(n, earlier, c).unwrap_or([u32::MAX; 2])
        })? {
            merged.push(QuantizedMergedEntry::encode(entry)?);
        }
    }
    let prototypes = QuantizedPrototypes {
        needle_counts: record.prototypes.iter().map(|p| p.needles.len() as u32).collect(),
        grids,
        needles,
        merged,
    };
    let mut previous = None;
    let placements = record
        .placements
        .iter()
        .map(|p| {
            let stored = StoredPlacement::encode(p, previous);
            previous = Some(p.prototype);
            stored
        })
        .collect();
    let p_count = record.placements.len() as u32;
    let tree_merged = encode_merged(&record.tree_merged, p_count, |c, earlier| {
        if c < p_count {
            placed_root_ends(record, c as usize)
        } else {
            earlier.get((c - p_count) as usize).map_or([u32::MAX; 2], |m| m.ends)
        }
    })?
    .into_iter()
    .map(QuantizedMergedEntry::encode)
    .collect::<Result<Vec<_>, _>>()?;
    let w = record.bake.weights;
    let payload = Payload {
        name: record.name.clone(),
        source: record.bake.source.clone(),
        bake_seconds: record.bake.bake_seconds,
        weights: [w.direction, w.distance, w.needle_count],
        max_sides: record.max_sides,
        material: StoredMaterial::from(&record.material),
        prototypes,
        placements,
        tree_merged,
        wood: encode_wood(&record.wood),
        wood_mesh: QuantizedMesh::encode(&record.wood_mesh, &quantized.mesh_grid),
    };
    let mut body = postcard::to_allocvec(&payload).map_err(|e| RecordError::Malformed(e.to_string()))?;
    body.extend(
        postcard::to_allocvec(&StoredAppearance::encode(record)).map_err(|e| RecordError::Malformed(e.to_string()))?,
    );
    let impostor = record.impostor.as_deref().map(StoredImpostor::encode).transpose()?;
    body.extend(postcard::to_allocvec(&impostor).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let calibration = record.line_calibration.as_ref().map(StoredLineCalibration::from);
    body.extend(postcard::to_allocvec(&calibration).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let wood_visibility = record.impostor.as_deref().map(|i| i.wood_visibility.to_bytes());
    body.extend(postcard::to_allocvec(&wood_visibility).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let wood_scales = record.line_calibration.as_ref().map(|c| c.wood_scales);
    body.extend(postcard::to_allocvec(&wood_scales).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let crown_density = record.impostor.as_deref().map(|i| i.crown_density.to_bytes());
    body.extend(postcard::to_allocvec(&crown_density).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let seen_needles = record
        .impostor
        .as_deref()
        .and_then(|i| i.seen_needles)
        .map(|mix| mix.to_array());
    body.extend(postcard::to_allocvec(&seen_needles).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let view_light_scale = record
        .impostor
        .as_deref()
        .and_then(|i| i.view_light_scale)
        .map(|scale| scale.to_vec());
    body.extend(postcard::to_allocvec(&view_light_scale).map_err(|e| RecordError::Malformed(e.to_string()))?);
    let mut bytes = Vec::with_capacity(HEADER_BYTES + body.len());
    bytes.extend_from_slice(&MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(body.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(&body).to_le_bytes());
    bytes.extend_from_slice(&body);
    Ok(bytes)
}

/// Tree-wide endpoint ids of placement `p`'s root line.
fn placed_root_ends(record: &PrototypeRecord, placement: usize) -> [EndpointId; 2] {
    let prototype = &record.prototypes[record.placements[placement].prototype as usize];
    let first = 2 * record.needle_offset(placement) as u32;
    prototype.node_ends(prototype.root()).map(|e| first + e)
}

/// Encodes a flat record into the bytes of a record file: every group a
/// prototype placed once ([`PrototypeRecord::from_flat`]).
pub fn encode_record(record: &LodRecord) -> Result<Vec<u8>, RecordError> {
    encode_prototype_record(&PrototypeRecord::from_flat(record)?)
}

/// Checks the header and checksum; returns the format version and payload.
fn checked_payload(bytes: &[u8]) -> Result<(u32, &[u8]), RecordError> {
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
        if bytes.len() < MAGIC.len() && MAGIC.starts_with(bytes) {
            return Err(RecordError::Truncated {
                expected: HEADER_BYTES as u64,
                found: bytes.len() as u64,
            });
        }
        return Err(RecordError::NotARecord);
    }
    if bytes.len() < HEADER_BYTES {
        return Err(RecordError::Truncated {
            expected: HEADER_BYTES as u64,
            found: bytes.len() as u64,
        });
    }
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let version = u32_at(8);
    if !(OLDEST_READ_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(RecordError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let payload_len = u64::from_le_bytes(bytes[12..20].try_into().expect("8 bytes"));
    let available = (bytes.len() - HEADER_BYTES) as u64;
    if payload_len > available {
        return Err(RecordError::Truncated {
            expected: (HEADER_BYTES as u64).saturating_add(payload_len),
            found: bytes.len() as u64,
        });
    }
    if payload_len < available {
        return Err(RecordError::TrailingBytes(available - payload_len));
    }
    let body = &bytes[HEADER_BYTES..];
    let stored = u32_at(20);
    let computed = crc32fast::hash(body);
    if stored != computed {
        return Err(RecordError::ChecksumMismatch { stored, computed });
    }
    Ok((version, body))
}

/// Decodes the bytes of a record file as a tree of prototypes (a format 2
/// file is converted: every group a prototype placed once).
pub fn decode_prototype_record(bytes: &[u8]) -> Result<PrototypeRecord, RecordError> {
    let (version, body) = checked_payload(bytes)?;
    if version == 2 {
        return Ok(PrototypeRecord::from_flat(&decode_v2(body)?)?);
    }
    decode_prototypes(version, body)
}

/// Decodes the bytes of a record file as a flat record (placements expanded).
pub fn decode_record(bytes: &[u8]) -> Result<LodRecord, RecordError> {
    let (version, body) = checked_payload(bytes)?;
    if version == 2 {
        return decode_v2(body);
    }
    Ok(decode_prototypes(version, body)?.flatten()?)
}

/// The tree of prototypes a format 3–7 payload holds, with what formats 5
/// and 7 store after it.
fn decode_prototypes(version: u32, body: &[u8]) -> Result<PrototypeRecord, RecordError> {
    let (payload, after) = decode_payload(version, body)?;
    let mut record = payload_to_prototype_record(payload, after.appearance)?;
    record.impostor = after.impostor.map(Arc::new);
    record.line_calibration = after.line_calibration;
    Ok(record)
}

/// A line calibration as formats 9 and later store it in place: the
/// needle lines' table (format 11 adds the wood's after the wood
/// visibility).
#[derive(Serialize, Deserialize)]
struct StoredLineCalibration {
    first_pixel: f32,
    last_pixel: f32,
    scales: [f32; CALIBRATION_STEPS],
}

impl From<&LineCalibration> for StoredLineCalibration {
    fn from(c: &LineCalibration) -> Self {
        Self {
            first_pixel: c.first_pixel,
            last_pixel: c.last_pixel,
            scales: c.scales,
        }
    }
}

/// What formats 5, 7, 9, 10 and 11 store after the payload.
#[derive(Default)]
struct AfterPayload {
    /// Format 5: colours by age, side and height, needle ages.
    appearance: Option<StoredAppearance>,
    /// Format 7 (read from format 8): the crown impostor.
    impostor: Option<CrownImpostor>,
    /// Format 9: the line calibration.
    line_calibration: Option<LineCalibration>,
}

/// A format 3–10 payload, and what formats 5, 7, 9 and 10 store after it.
fn decode_payload(version: u32, body: &[u8]) -> Result<(DecodedPayload, AfterPayload), RecordError> {
    let malformed = |e: postcard::Error| RecordError::Malformed(e.to_string());
    if version == 3 {
        let p: PayloadV3 = postcard::from_bytes(body).map_err(malformed)?;
        check_placement_codes(version, &p.placements)?;
        let decoded = p.convert(
            |stored| {
                Ok(DecodedPrototypes {
                    needles: stored.needles.decode(|_| 0)?,
                    needle_counts: stored.needle_counts,
                    merged: stored.merged,
                })
            },
            |entry| entry,
            StoredMesh::decode,
        )?;
        return Ok((decoded, AfterPayload::default()));
    }
    let (p, rest): (Payload, &[u8]) = postcard::take_from_bytes(body).map_err(malformed)?;
    check_placement_codes(version, &p.placements)?;
    let (appearance, rest) = if version >= 5 {
        let (appearance, rest) = postcard::take_from_bytes::<StoredAppearance>(rest).map_err(malformed)?;
        (Some(appearance), rest)
    } else {
        (None, rest)
    };
    let (impostor, rest) = if version >= 7 {
        let (stored, rest) = postcard::take_from_bytes::<Option<StoredImpostor>>(rest).map_err(malformed)?;
        // Checked; before format 10 dropped below (format 7's last two
        // planes are mean axes, not shares, and formats 8 and 9 lack the
        // wood visibility): the plugin bakes the impostor at load.
        let impostor = stored.map(StoredImpostor::decode).transpose()?;
        (impostor, rest)
    } else {
        (None, rest)
    };
    let (line_calibration, rest) = if version >= 9 {
        let (stored, rest) = postcard::take_from_bytes::<Option<StoredLineCalibration>>(rest).map_err(malformed)?;
        // Wood scales 1 until format 11's are read below.
        let calibration = stored.map(|c| LineCalibration {
            first_pixel: c.first_pixel,
            last_pixel: c.last_pixel,
            scales: c.scales,
            wood_scales: [[1.0; WOOD_OPACITY_NODES]; CALIBRATION_STEPS],
        });
        (calibration, rest)
    } else {
        (None, rest)
    };
    // Format 10: the impostor's wood visibility, which older impostors
    // lack: they are dropped (the plugin bakes the impostor at load).
    let (impostor, rest) = if version >= 10 {
        impostor_table(impostor, rest, "wood visibility", |impostor, bytes| {
            WoodVisibility::from_bytes(bytes).map(|table| impostor.wood_visibility = table)
        })?
    } else {
        (None, rest)
    };
    // Format 11: the wood lines' scales, with the line calibration.
    let (line_calibration, rest) = if version >= 11 {
        let (stored, rest) = postcard::take_from_bytes::<Option<[[f32; WOOD_OPACITY_NODES]; CALIBRATION_STEPS]>>(rest)
            .map_err(malformed)?;
        let calibration = both_or_neither(
            line_calibration,
            stored,
            "line calibration: wood scales without the table",
        )?
        .map(|(calibration, wood_scales)| LineCalibration {
            wood_scales,
            ..calibration
        });
        (calibration, rest)
    } else {
        (line_calibration, rest)
    };
    // Format 13: the impostor's crown density; an older impostor's
    // needles are even through its crown.
    let (impostor, rest) = if version >= 13 {
        impostor_table(impostor, rest, "crown density", |impostor, bytes| {
            CrownDensity::from_bytes(bytes).map(|table| impostor.crown_density = table)
        })?
    } else {
        (impostor, rest)
    };
    // Format 14: the mix of needles the impostor's views see, which
    // colours the far crown; an older impostor's crown takes its needles'
    // area mean.
    let (impostor, rest) = if version >= 14 {
        let (stored, rest) =
            postcard::take_from_bytes::<Option<[f32; 2 * NEEDLE_AGE_CLASSES]>>(rest).map_err(malformed)?;
        let impostor = match (impostor, stored) {
            (impostor, None) => impostor,
            (None, Some(_)) => return Err(RecordError::Malformed("seen needles without an impostor".into())),
            (Some(mut impostor), Some(values)) => {
                let mix = NeedleMix::from_array(values).ok_or_else(|| {
                    RecordError::Malformed("seen needles: a share out of [0, 1] or not summing to 1".into())
                })?;
                impostor.seen_needles = Some(mix);
                Some(impostor)
            }
        };
        (impostor, rest)
    } else {
        (impostor, rest)
    };
    // Format 15: how the impostor's direct light is scaled to light its
    // texels as the needles its views show; an older impostor's is lit as
    // its shares say.
    let (impostor, rest) = if version >= 15 {
        let (stored, rest) = postcard::take_from_bytes::<Option<Vec<f32>>>(rest).map_err(malformed)?;
        let impostor = match (impostor, stored) {
            (impostor, None) => impostor,
            (None, Some(_)) => return Err(RecordError::Malformed("view light scale without an impostor".into())),
            (Some(mut impostor), Some(values)) => {
                let scale = ViewLightScale::from_slice(&values).ok_or_else(|| {
                    RecordError::Malformed(format!(
                        "view light scale: {} values (not {}) or one out of {:?}",
                        values.len(),
                        ViewLightScale::LEN,
                        VIEW_LIGHT_SCALE_RANGE
                    ))
                })?;
                impostor.view_light_scale = Some(scale);
                Some(impostor)
            }
        };
        (impostor, rest)
    } else {
        (impostor, rest)
    };
    if line_calibration.is_some_and(|c| !c.is_valid()) {
        return Err(RecordError::Malformed(
            "line calibration: pixel sizes not increasing or a scale out of range".into(),
        ));
    }
    if !rest.is_empty() {
        return Err(RecordError::Malformed(format!(
            "{} bytes after the payload of a format {version} record",
            rest.len()
        )));
    }
    let decoded = p.convert(
        QuantizedPrototypes::decode,
        |entry| entry.decode(),
        QuantizedMesh::decode,
    )?;
    Ok((
        decoded,
        AfterPayload {
            appearance,
            impostor,
            line_calibration,
        },
    ))
}

/// Reads one of the impostor's tables (`what`), stored as bytes after
/// `impostor` (`rest` starts with it) and present exactly when the
/// impostor is, into it with `set` (`None`: bytes of another length);
/// returns the impostor and the bytes after the table.
fn impostor_table<'a>(
    impostor: Option<CrownImpostor>,
    rest: &'a [u8],
    what: &str,
    set: impl FnOnce(&mut CrownImpostor, &[u8]) -> Option<()>,
) -> Result<(Option<CrownImpostor>, &'a [u8]), RecordError> {
    let (stored, rest) =
        postcard::take_from_bytes::<Option<Vec<u8>>>(rest).map_err(|e| RecordError::Malformed(e.to_string()))?;
    let impostor = both_or_neither(impostor, stored, &format!("impostor: a {what} without its impostor"))?
        .map(|(mut impostor, bytes)| {
            set(&mut impostor, &bytes)
                .ok_or_else(|| RecordError::Malformed(format!("impostor: a {what} of another size")))?;
            Ok::<_, RecordError>(impostor)
        })
        .transpose()?;
    Ok((impostor, rest))
}

/// `part` and `extra`, which a record stores together: both, neither, or
/// malformed (`what` says which is missing).
fn both_or_neither<A, B>(part: Option<A>, extra: Option<B>, what: &str) -> Result<Option<(A, B)>, RecordError> {
    match (part, extra) {
        (Some(a), Some(b)) => Ok(Some((a, b))),
        (None, None) => Ok(None),
        _ => Err(RecordError::Malformed(format!("{what}, or the other way"))),
    }
}

/// Placements on codes came with format 6: an older file holding one is
/// malformed.
fn check_placement_codes(version: u32, placements: &[StoredPlacement]) -> Result<(), RecordError> {
    if version < 6 && placements.iter().any(|s| matches!(s, StoredPlacement::Quantized(_))) {
        return Err(RecordError::Malformed(format!(
            "a placement on codes in a format {version} record (codes came with format 6)"
        )));
    }
    Ok(())
}

impl QuantizedPrototypes {
    /// The needles on their prototypes' grids, the errors from their codes.
    fn decode(self) -> Result<DecodedPrototypes, RecordError> {
        let q = &self.needles;
        let n = q.bases.len();
        if q.tips.len() != n || q.radii.len() != n || q.normals.len() != n {
            return Err(RecordError::Malformed("needle arrays differ in length".into()));
        }
        if self.grids.len() != self.needle_counts.len() {
            return Err(RecordError::Malformed("one grid per prototype expected".into()));
        }
        let needle_total: u64 = self.needle_counts.iter().map(|&c| c as u64).sum();
        if needle_total != n as u64 {
            return Err(RecordError::Malformed(
                "prototype needle counts do not add up to the needles stored".into(),
            ));
        }
        let mut needles = Vec::with_capacity(n);
        for (&count, &(origin, exponent)) in self.needle_counts.iter().zip(&self.grids) {
            let Some(grid) = PositionGrid::from_codes(origin, exponent) else {
                return Err(RecordError::Malformed(format!(
                    "grid step 2^{exponent} m is out of range"
                )));
            };
            for i in needles.len()..needles.len() + count as usize {
                needles.push(Needle {
                    base: grid.decode(grid_codes(q.bases[i])),
                    tip: grid.decode(grid_codes(q.tips[i])),
                    radius: log_decode(u16::from_le_bytes(q.radii[i])),
                    normal: decode_normal(q.normals[i]),
                    group: 0,
                });
            }
        }
        Ok(DecodedPrototypes {
            needles,
            merged: self.merged.iter().map(QuantizedMergedEntry::decode).collect(),
            needle_counts: self.needle_counts,
        })
    }
}

fn payload_to_prototype_record(
    p: DecodedPayload,
    appearance: Option<StoredAppearance>,
) -> Result<PrototypeRecord, RecordError> {
    let stored = &p.prototypes;
    let all_needles = &stored.needles;
    let needle_total: u64 = stored.needle_counts.iter().map(|&c| c as u64).sum();
    let merged_total = needle_total.saturating_sub(stored.needle_counts.len() as u64);
    if needle_total != all_needles.len() as u64
        || stored.needle_counts.contains(&0)
        || merged_total != stored.merged.len() as u64
    {
        return Err(RecordError::Malformed(
            "prototype needle counts do not add up to the needles and merged lines stored".into(),
        ));
    }
    let mut prototypes = Vec::with_capacity(stored.needle_counts.len());
    let (mut first_needle, mut first_merged) = (0usize, 0usize);
    for (k, &count) in stored.needle_counts.iter().enumerate() {
        let n = count as usize;
        let needles = all_needles[first_needle..first_needle + n].to_vec();
        let entries = &stored.merged[first_merged..first_merged + n - 1];
        let merged =
            decode_merged(entries, n as u64, |c, earlier| node_ends(n, earlier, c)).map_err(
                |problem| match problem {
                    RecordError::Invalid(problem) => RecordError::Invalid(RecordInvalid::Prototype {
                        prototype: k,
                        problem: Box::new(problem),
                    }),
                    other => other,
                },
            )?;
        prototypes.push(Prototype { needles, merged });
        first_needle += n;
        first_merged += n - 1;
    }
    // Where each placement's needles start, checked before any id is used.
    let mut previous = None;
    let mut placements: Vec<Placement> = p
        .placements
        .iter()
        .map(|stored| {
            let placement = stored.decode(previous);
            previous = Some(placement.prototype);
            placement
        })
        .collect();
    let mut material = FoliageMaterial::from(p.material);
    if let Some(appearance) = appearance {
        appearance.apply(&mut material, &mut placements)?;
    }
    let mut first_end = Vec::with_capacity(placements.len());
    let mut needles = 0u64;
    for (index, placement) in placements.iter().enumerate() {
        let Some(prototype) = prototypes.get(placement.prototype as usize) else {
            return Err(RecordInvalid::BadPlacement(index).into());
        };
        first_end.push(2 * needles as u32);
        needles += prototype.needles.len() as u64;
        if needles > MAX_PLACED_NEEDLES {
            return Err(RecordInvalid::TooManyNeedles(needles).into());
        }
    }
    let p_count = placements.len() as u32;
    let tree_merged = decode_merged(&p.tree_merged, p_count as u64, |c, earlier| {
        if c < p_count {
            let prototype = &prototypes[placements[c as usize].prototype as usize];
            Some(prototype.node_ends(prototype.root()).map(|e| first_end[c as usize] + e))
        } else {
            earlier.get((c - p_count) as usize).map(|m| m.ends)
        }
    })?;
    let bake = decode_bake_info(p.weights, p.bake_seconds, p.source)?;
    Ok(PrototypeRecord::from_parts(
        p.name,
        prototypes,
        placements,
        tree_merged,
        decode_wood(&p.wood),
        p.wood_mesh,
        material,
        p.max_sides,
        bake,
    )?)
}

/// Decodes a format 2 payload (one flat tree).
fn decode_v2(body: &[u8]) -> Result<LodRecord, RecordError> {
    let p: PayloadV2 = postcard::from_bytes(body).map_err(|e| RecordError::Malformed(e.to_string()))?;
    let n = p.needles.bases.len();
    let group_total: u64 = p.group_sizes.iter().map(|&s| s as u64).sum();
    if group_total != n as u64 || p.group_sizes.contains(&0) {
        return Err(RecordError::Malformed(
            "group sizes do not add up to the needle count".into(),
        ));
    }
    let group_of: Vec<u32> = p
        .group_sizes
        .iter()
        .enumerate()
        .flat_map(|(g, &s)| std::iter::repeat_n(g as u32, s as usize))
        .collect();
    let needles = p.needles.decode(|i| group_of[i])?;
    let merged = decode_merged(&p.merged, n as u64, |c, earlier| node_ends(n, earlier, c))?;
    let bake = decode_bake_info(p.weights, p.bake_seconds, p.source)?;
    Ok(LodRecord::from_parts(
        p.name,
        needles,
        merged,
        decode_wood(&p.wood),
        p.wood_mesh.decode()?,
        p.material.into(),
        p.max_sides,
        bake,
    )?)
}

/// Writes `record` to `path` atomically: the bytes go to a temporary file
/// beside it, which is renamed over `path` only once complete, so a failure
/// never leaves a half-written record (nor damages one already there).
pub fn write_record(record: &LodRecord, path: &Path) -> Result<u64, RecordError> {
    let bytes = encode_record(record)?;
    write_atomically(path, &bytes)?;
    Ok(bytes.len() as u64)
}

/// Writes `bytes` to a temporary file beside `path` and renames it over
/// `path` once complete and synced; on failure the temporary file is
/// removed and `path` is untouched.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let file_name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "output path has no file name"))?;
    let tmp = dir.join(format!(".{}.tmp-{}", file_name.to_string_lossy(), std::process::id()));
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Writes a tree of prototypes to `path` atomically (see [`write_record`]).
pub fn write_prototype_record(record: &PrototypeRecord, path: &Path) -> Result<u64, RecordError> {
    let bytes = encode_prototype_record(record)?;
    write_atomically(path, &bytes)?;
    Ok(bytes.len() as u64)
}

/// Reads and checks a record file as a flat record.
pub fn read_record(path: &Path) -> Result<LodRecord, RecordError> {
    decode_record(&std::fs::read(path)?)
}

/// Reads and checks a record file as a tree of prototypes.
pub fn read_prototype_record(path: &Path) -> Result<PrototypeRecord, RecordError> {
    decode_prototype_record(&std::fs::read(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A payload of one three-needle prototype placed `placements` times.
    fn payload(placements: Vec<StoredPlacement>) -> PayloadV3 {
        let needle = |k: f32| Needle {
            base: Vec3::ZERO,
            tip: Vec3::new(k * 0.01, 0.05, 0.0),
            radius: 0.001,
            normal: Vec3::Z,
            group: 0,
        };
        let prototype = Prototype {
            needles: vec![needle(0.0), needle(1.0), needle(2.0)],
            merged: Vec::new(),
        };
        let entry = |back: [u32; 2]| MergedEntry {
            back,
            ends: 0b0100,
            error: 0.05,
        };
        PayloadV3 {
            name: "hostile".into(),
            source: String::new(),
            bake_seconds: None,
            weights: [0.25, 0.25, 0.5],
            max_sides: 8,
            material: StoredMaterial::from(&FoliageMaterial::default()),
            prototypes: StoredPrototypes {
                needle_counts: vec![3],
                needles: StoredNeedles::encode(&prototype.needles),
                merged: vec![entry([3, 2]), entry([2, 1])],
            },
            placements,
            tree_merged: Vec::new(),
            wood: Vec::new(),
            wood_mesh: StoredMesh::default(),
        }
    }

    /// `body` in a well-formed file of format `version`.
    fn file_of_version(version: u32, body: &[u8]) -> Vec<u8> {
        let mut file = MAGIC.to_vec();
        file.extend_from_slice(&version.to_le_bytes());
        file.extend_from_slice(&(body.len() as u64).to_le_bytes());
        file.extend_from_slice(&crc32fast::hash(body).to_le_bytes());
        file.extend_from_slice(body);
        file
    }

    /// A well-formed format 3 header around `body` (formats 3 to 5 decode
    /// placements, references and counts alike).
    fn file(body: &[u8]) -> Vec<u8> {
        file_of_version(3, body)
    }

    fn decode(payload: &PayloadV3) -> Result<PrototypeRecord, RecordError> {
        decode_prototype_record(&file(&postcard::to_allocvec(payload).unwrap()))
    }

    /// A baked tree of three one-needle groups: its format 4 payload (the
    /// format 5 payload without its appearance), edited by `edit`, in a
    /// well-formed format 4 file.
    fn edited_v4(edit: impl FnOnce(&mut Payload)) -> Result<PrototypeRecord, RecordError> {
        let bytes = encode_record(&three_groups()).unwrap();
        let mut payload: Payload = postcard::from_bytes(&bytes[HEADER_BYTES..]).unwrap();
        edit(&mut payload);
        decode_prototype_record(&file_of_version(4, &postcard::to_allocvec(&payload).unwrap()))
    }

    /// The bytes a format 14 record file ends with: its impostor's seen
    /// needles.
    fn stored_seen_needles(record: &PrototypeRecord) -> Vec<u8> {
        let seen = record.impostor.as_deref().and_then(|i| i.seen_needles);
        postcard::to_allocvec(&seen.map(|m| m.to_array())).unwrap()
    }

    /// The bytes a record file ends with (format 15): its impostor's view
    /// light scale.
    fn stored_view_light_scale(record: &PrototypeRecord) -> Vec<u8> {
        let scale = record.impostor.as_deref().and_then(|i| i.view_light_scale);
        postcard::to_allocvec(&scale.map(|s| s.to_vec())).unwrap()
    }

    /// A baked flat tree of three one-needle groups.
    fn three_groups() -> LodRecord {
        let needle = |k: f32| Needle {
            base: Vec3::new(k * 0.1, 0.0, 0.0),
            tip: Vec3::new(k * 0.1 + 0.01, 0.05, 0.0),
            radius: 0.001,
            normal: Vec3::Z,
            group: k as u32,
        };
        let input = super::super::needle::TreeInput {
            name: "three".into(),
            needles: vec![needle(0.0), needle(1.0), needle(2.0)],
            ..Default::default()
        };
        super::super::bake(&input, &Default::default(), &()).unwrap()
    }

    #[test]
    fn needle_ages_and_colours_round_trip_and_format_4_reads_as_one_colour() {
        let mut record = PrototypeRecord::from_flat(&three_groups()).unwrap();
        for (k, placement) in record.placements.iter_mut().enumerate() {
            placement.needle_age = [0, 1, 7][k];
        }
        record.material.young_needle_color = [0.2, 0.3, 0.05, 1.0];
        record.material.needle_underside_color = [0.3, 0.35, 0.3, 1.0];
        record.material.upper_wood_color = [0.5, 0.2, 0.05, 1.0];
        record.material.upper_wood_heights = [4.0, 9.5];
        let bytes = encode_prototype_record(&record).unwrap();
        let read = decode_prototype_record(&bytes).unwrap();
        assert_eq!(read.material, record.material);
        let ages: Vec<u8> = read.placements.iter().map(|p| p.needle_age).collect();
        assert_eq!(ages, [0, 1, 7]);

        // The same payload without what format 5 adds, as format 4: one
        // colour per tree, every needle mature.
        let body = &bytes[HEADER_BYTES..];
        let (_, rest): (Payload, &[u8]) = postcard::take_from_bytes(body).unwrap();
        let old = decode_prototype_record(&file_of_version(4, &body[..body.len() - rest.len()])).unwrap();
        let uniform = FoliageMaterial::uniform(
            record.material.needle_color,
            record.material.wood_color,
            record.material.roughness,
            record.material.reflectance,
        );
        assert_eq!(old.material, uniform);
        assert!(
            old.placements
                .iter()
                .all(|p| p.needle_age == crate::model::color::MATURE_NEEDLE_AGE)
        );

        // Format 5 without its appearance, or with an age too few, is
        // malformed.
        let error = decode_prototype_record(&file_of_version(5, &body[..body.len() - rest.len()])).unwrap_err();
        assert!(matches!(error, RecordError::Malformed(_)), "{error}");
        let mut short = StoredAppearance::encode(&record);
        short.age_runs.pop();
        let mut body_short = body[..body.len() - rest.len()].to_vec();
        body_short.extend(postcard::to_allocvec(&short).unwrap());
        let error = decode_prototype_record(&file_of_version(5, &body_short)).unwrap_err();
        assert!(error.to_string().contains("2 needle ages for 3 placements"), "{error}");
    }

    #[test]
    fn the_line_calibration_round_trips_and_older_files_have_less() {
        let mut record = PrototypeRecord::from_flat(&three_groups()).unwrap();
        let calibration = LineCalibration {
            first_pixel: 0.01,
            last_pixel: 0.2,
            scales: [1.0, 0.98, 0.95, 0.9, 0.86, 0.8, 0.78, 0.75],
            wood_scales: [0.9, 0.85, 0.8, 0.7, 0.6, 0.6, 0.65, 0.7].map(|s| [s, s + 0.1, s + 0.2, 1.0]),
        };
        record.line_calibration = Some(calibration);
        let bytes = encode_prototype_record(&record).unwrap();
        assert_eq!(
            decode_prototype_record(&bytes).unwrap().line_calibration,
            Some(calibration)
        );
        assert_eq!(decode_record(&bytes).unwrap().line_calibration, Some(calibration));
        // Format 15 ends with the impostor's view light scale: format 14
        // stops before it, its impostor lit as its shares say.
        let body = &bytes[HEADER_BYTES..];
        let v14 = &body[..body.len() - stored_view_light_scale(&record).len()];
        let mut unscaled = decode_prototype_record(&bytes).unwrap();
        Arc::make_mut(unscaled.impostor.as_mut().expect("an impostor")).view_light_scale = None;
        assert_eq!(decode_prototype_record(&file_of_version(14, v14)).unwrap(), unscaled);
        // Format 14 ends with the needles the impostor sees: format 13
        // stops before them, its far crown the needles' area mean.
        let seen = stored_seen_needles(&record);
        let v13 = &v14[..v14.len() - seen.len()];
        let mut unseen = unscaled.clone();
        Arc::make_mut(unseen.impostor.as_mut().expect("an impostor")).seen_needles = None;
        assert_eq!(decode_prototype_record(&file_of_version(13, v13)).unwrap(), unseen);
        // Format 13 ends with the impostor's crown density: format 12
        // stops before it, its impostor's needles even through the crown.
        let density = postcard::to_allocvec(&record.impostor.as_deref().map(|i| i.crown_density.to_bytes())).unwrap();
        let v12 = &v13[..v13.len() - density.len()];
        let mut even = unseen.clone();
        Arc::make_mut(even.impostor.as_mut().expect("an impostor")).crown_density = CrownDensity::default();
        assert_eq!(decode_prototype_record(&file_of_version(12, v12)).unwrap(), even);
        // Format 12 is 11's layout (measured against capped silhouettes):
        // an 11 file reads as it is.
        assert_eq!(decode_prototype_record(&file_of_version(11, v12)).unwrap(), even);
        // Format 11 ends with the wood scales: format 10 stops before
        // them, read with every wood scale 1.
        let wood_scales = postcard::to_allocvec(&Some(calibration.wood_scales)).unwrap();
        let v10 = &v12[..v12.len() - wood_scales.len()];
        let read = decode_prototype_record(&file_of_version(10, v10)).unwrap();
        assert_eq!(
            read.line_calibration,
            Some(LineCalibration {
                wood_scales: [[1.0; WOOD_OPACITY_NODES]; CALIBRATION_STEPS],
                ..calibration
            })
        );
        assert!(read.impostor.is_some());
        // Format 8 stops after the impostor: read without a calibration
        // (and without the impostor, which lacks its wood visibility).
        let stored = postcard::to_allocvec(&Some(StoredLineCalibration::from(&calibration))).unwrap();
        let visibility =
            postcard::to_allocvec(&record.impostor.as_deref().map(|i| i.wood_visibility.to_bytes())).unwrap();
        let v8 = &v10[..v10.len() - stored.len() - visibility.len()];
        let old = decode_prototype_record(&file_of_version(8, v8)).unwrap();
        assert!(old.line_calibration.is_none());
        assert!(old.impostor.is_none());
        assert_eq!(old.placements, record.placements);
        // A scale out of range (the needles' or the wood's), sizes not
        // increasing, a NaN, a cut-off calibration, or wood scales without
        // the table: malformed, never a panic.
        let with_calibration = |c: &LineCalibration, wood: Option<[[f32; WOOD_OPACITY_NODES]; CALIBRATION_STEPS]>| {
            let mut body = v8.to_vec();
            body.extend(postcard::to_allocvec(&Some(StoredLineCalibration::from(c))).unwrap());
            body.extend_from_slice(&visibility);
            body.extend(postcard::to_allocvec(&wood).unwrap());
            body
        };
        let mut truncated = v8.to_vec();
        truncated.extend_from_slice(&stored[..stored.len() - 3]);
        let bad = [
            LineCalibration {
                scales: [3.0; 8],
                ..calibration
            },
            LineCalibration {
                last_pixel: 0.001,
                ..calibration
            },
            LineCalibration {
                first_pixel: f32::NAN,
                ..calibration
            },
            LineCalibration {
                wood_scales: [[0.1; WOOD_OPACITY_NODES]; CALIBRATION_STEPS],
                ..calibration
            },
        ];
        let mut bodies: Vec<Vec<u8>> = bad.iter().map(|c| with_calibration(c, Some(c.wood_scales))).collect();
        let mut without_table = v8.to_vec();
        without_table.extend(postcard::to_allocvec(&None::<StoredLineCalibration>).unwrap());
        without_table.extend_from_slice(&visibility);
        without_table.extend(postcard::to_allocvec(&Some(calibration.wood_scales)).unwrap());
        bodies.push(without_table);
        bodies.push(with_calibration(&calibration, None));
        for body in bodies {
            let error = decode_prototype_record(&file_of_version(11, &body)).unwrap_err();
            assert!(matches!(error, RecordError::Malformed(_)), "{error}");
        }
        let error = decode_prototype_record(&file_of_version(9, &truncated)).unwrap_err();
        assert!(matches!(error, RecordError::Malformed(_)), "{error}");
    }

    #[test]
    fn the_impostor_round_trips_and_format_6_and_7_files_have_none() {
        let record = PrototypeRecord::from_flat(&three_groups()).unwrap();
        let impostor = record.impostor.clone().expect("the default bake holds an impostor");
        let bytes = encode_prototype_record(&record).unwrap();
        let read = decode_prototype_record(&bytes).unwrap();
        assert_eq!(read.impostor.as_deref(), Some(&*impostor));
        assert_eq!(decode_record(&bytes).unwrap().impostor.as_deref(), Some(&*impostor));
        // Format 6 stops after the appearance: no impostor.
        let body = &bytes[HEADER_BYTES..];
        let (_, after) = postcard::take_from_bytes::<Payload>(body).unwrap();
        let (_, stored) = postcard::take_from_bytes::<StoredAppearance>(after).unwrap();
        let v6 = &body[..body.len() - stored.len()];
        let old = decode_prototype_record(&file_of_version(6, v6)).unwrap();
        assert!(old.impostor.is_none());
        assert_eq!(old.placements, record.placements);
        // Without one (and without a line calibration), format 15 stores a
        // single byte for each, for the wood visibility, for the wood
        // scales, for the crown density, for the seen needles and for the
        // view light scale.
        let mut bare = record.clone();
        bare.impostor = None;
        bare.line_calibration = None;
        assert_eq!(
            encode_prototype_record(&bare).unwrap().len(),
            HEADER_BYTES + v6.len() + 7
        );
        // A stored impostor that breaks its frame is malformed, never a
        // panic or an allocation past its frame.
        let seen = impostor.seen_needles.map(|mix| mix.to_array());
        assert!(seen.is_some(), "the bake measures the needles it sees");
        let scale = impostor.view_light_scale.map(|scale| scale.to_vec());
        assert!(scale.is_some(), "the bake measures the view light scale");
        let file = |version: u32,
                    edit: &dyn Fn(&mut StoredImpostor),
                    visibility: Option<Vec<u8>>,
                    density: Option<Vec<u8>>| {
            let mut s = StoredImpostor::encode(&impostor).unwrap();
            edit(&mut s);
            let mut body = v6.to_vec();
            body.extend(postcard::to_allocvec(&Some(s)).unwrap());
            if version >= 9 {
                body.extend(postcard::to_allocvec(&None::<StoredLineCalibration>).unwrap());
            }
            if version >= 10 {
                body.extend(postcard::to_allocvec(&visibility).unwrap());
            }
            if version >= 11 {
                body.extend(postcard::to_allocvec(&None::<[[f32; WOOD_OPACITY_NODES]; CALIBRATION_STEPS]>).unwrap());
            }
            if version >= 13 {
                body.extend(postcard::to_allocvec(&density).unwrap());
            }
            if version >= 14 {
                body.extend(postcard::to_allocvec(&seen).unwrap());
            }
            if version >= 15 {
                body.extend(postcard::to_allocvec(&scale).unwrap());
            }
            decode_prototype_record(&file_of_version(version, &body))
        };
        let density = Some(impostor.crown_density.to_bytes());
        let file_with_density = |version: u32, edit: &dyn Fn(&mut StoredImpostor), density: Option<Vec<u8>>| {
            file(version, edit, Some(impostor.wood_visibility.to_bytes()), density)
        };
        let with = |edit: &dyn Fn(&mut StoredImpostor)| file_with_density(15, edit, density.clone());
        assert_eq!(with(&|_| {}).unwrap().impostor.as_deref(), Some(&*impostor));
        // Format 13 stored no seen needles: its crown takes the area mean.
        let unseen = file_with_density(13, &|_| {}, density.clone())
            .unwrap()
            .impostor
            .expect("a format 13 impostor");
        assert_eq!(unseen.seen_needles, None);
        assert_eq!(unseen.texels, impostor.texels);
        // Format 13's crown density comes with the impostor, at its size;
        // format 10 to 12 files read with the needles even through the
        // crown.
        for density in [None, Some(vec![255; 10])] {
            let error = file_with_density(13, &|_| {}, density).unwrap_err();
            assert!(
                matches!(&error, RecordError::Malformed(m) if m.starts_with("impostor")),
                "{error}"
            );
        }
        let even = file_with_density(10, &|_| {}, None)
            .unwrap()
            .impostor
            .expect("a format 10 impostor");
        assert_eq!(even.crown_density, CrownDensity::default());
        assert_eq!(even.texels, impostor.texels);
        // Formats 8 and 9 stored no wood visibility: read without the
        // impostor (the plugin bakes it at load).
        for version in [8, 9] {
            let old = file(version, &|_| {}, None, None).unwrap();
            assert!(old.impostor.is_none());
            assert_eq!(old.placements, record.placements);
        }
        // Format 10's wood visibility comes with the impostor, at its size.
        for visibility in [None, Some(vec![255; 10])] {
            let error = file(10, &|_| {}, visibility, None).unwrap_err();
            assert!(
                matches!(&error, RecordError::Malformed(m) if m.starts_with("impostor")),
                "{error}"
            );
        }
        // Format 7 stored mean axes in the last two planes: read without it.
        let mut v7 = v6.to_vec();
        v7.extend(postcard::to_allocvec(&Some(StoredImpostor::encode(&impostor).unwrap())).unwrap());
        let old = decode_prototype_record(&file_of_version(7, &v7)).unwrap();
        assert!(old.impostor.is_none());
        assert_eq!(old.placements, record.placements);
        type Edit<'a> = (&'a str, &'a dyn Fn(&mut StoredImpostor));
        let edits: [Edit; 6] = [
            ("no views", &|s| s.views = 0),
            ("a texel more", &|s| s.columns += 1),
            ("a huge frame", &|s| (s.rows, s.columns) = (u32::MAX, u32::MAX)),
            ("a NaN texel", &|s| s.texel = f32::NAN),
            ("truncated texels", &|s| s.planes.truncate(s.planes.len() / 2)),
            ("not deflate", &|s| s.planes = vec![0xff; 64]),
        ];
        for (what, edit) in edits {
            let error = with(edit).unwrap_err();
            assert!(
                matches!(&error, RecordError::Malformed(m) if m.starts_with("impostor")),
                "{what}: {error}"
            );
        }
    }

    #[test]
    fn seen_needles_come_with_the_impostor_and_add_up() {
        let record = PrototypeRecord::from_flat(&three_groups()).unwrap();
        let bytes = encode_prototype_record(&record).unwrap();
        // A format 14 file ends with the seen needles: `Some` and six f32s.
        let body = &bytes[HEADER_BYTES..bytes.len() - stored_view_light_scale(&record).len()];
        let stored = stored_seen_needles(&record);
        assert_eq!(stored.len(), 1 + 24);
        assert!(body.ends_with(&stored));
        let before = &body[..body.len() - stored.len()];
        let with = |seen: Option<[f32; 6]>| {
            let mut body = before.to_vec();
            body.extend(postcard::to_allocvec(&seen).unwrap());
            decode_prototype_record(&file_of_version(14, &body))
        };
        let mix = [0.25, 0.1, 0.25, 0.0, 0.5, 0.2];
        assert_eq!(
            with(Some(mix)).unwrap().impostor.and_then(|i| i.seen_needles),
            NeedleMix::from_array(mix)
        );
        assert_eq!(with(None).unwrap().impostor.and_then(|i| i.seen_needles), None);
        for bad in [
            [0.5, 0.1, 0.25, 0.0, 0.5, 0.2],
            [f32::NAN, 0.0, 1.0, 0.0, 0.0, 0.0],
            [1.0, 2.0, 0.0, 0.0, 0.0, 0.0],
        ] {
            let error = with(Some(bad)).unwrap_err();
            assert!(
                matches!(&error, RecordError::Malformed(m) if m.starts_with("seen needles")),
                "{error}"
            );
        }
        // Seen needles without an impostor are malformed.
        let mut bare = record.clone();
        bare.impostor = None;
        let bare_bytes = encode_prototype_record(&bare).unwrap();
        let mut body = bare_bytes[HEADER_BYTES..bare_bytes.len() - 2].to_vec();
        body.extend(postcard::to_allocvec(&Some(mix)).unwrap());
        let error = decode_prototype_record(&file_of_version(14, &body)).unwrap_err();
        assert!(
            matches!(&error, RecordError::Malformed(m) if m.starts_with("seen needles")),
            "{error}"
        );
    }

    #[test]
    fn the_view_light_scale_comes_with_the_impostor_in_range() {
        let record = PrototypeRecord::from_flat(&three_groups()).unwrap();
        let bytes = encode_prototype_record(&record).unwrap();
        let body = &bytes[HEADER_BYTES..];
        // The last bytes are the scale: `Some`, its length and 91 f32s.
        let stored = stored_view_light_scale(&record);
        assert_eq!(stored.len(), 2 + 4 * ViewLightScale::LEN);
        assert!(body.ends_with(&stored));
        let before = &body[..body.len() - stored.len()];
        let with = |scale: Option<Vec<f32>>| {
            let mut body = before.to_vec();
            body.extend(postcard::to_allocvec(&scale).unwrap());
            decode_prototype_record(&file_of_version(15, &body))
        };
        let values: Vec<f32> = (0..ViewLightScale::LEN).map(|k| 0.6 + 0.01 * k as f32).collect();
        let read = with(Some(values.clone()))
            .unwrap()
            .impostor
            .and_then(|i| i.view_light_scale);
        assert_eq!(read.map(|s| s.to_vec()), Some(values.clone()));
        assert_eq!(
            read.unwrap().scales[1][0],
            values[crate::model::impostor::VIEW_LIGHT_ROLLS]
        );
        assert_eq!(with(None).unwrap().impostor.and_then(|i| i.view_light_scale), None);
        let mut bad = Vec::new();
        for (k, value) in [(0, f32::NAN), (7, 0.4), (90, 2.5)] {
            let mut v = values.clone();
            v[k] = value;
            bad.push(v);
        }
        bad.push(values[..90].to_vec());
        bad.push(vec![1.0; 92]);
        for bad in bad {
            let error = with(Some(bad)).unwrap_err();
            assert!(
                matches!(&error, RecordError::Malformed(m) if m.starts_with("view light scale")),
                "{error}"
            );
        }
        // A scale without an impostor is malformed.
        let mut bare = record.clone();
        bare.impostor = None;
        let bare_bytes = encode_prototype_record(&bare).unwrap();
        let mut body = bare_bytes[HEADER_BYTES..bare_bytes.len() - 1].to_vec();
        body.extend(postcard::to_allocvec(&Some(values)).unwrap());
        let error = decode_prototype_record(&file_of_version(15, &body)).unwrap_err();
        assert!(
            matches!(&error, RecordError::Malformed(m) if m.starts_with("view light scale")),
            "{error}"
        );
    }

    #[test]
    fn corrupted_codes_are_typed_errors() {
        assert!(edited_v4(|_| {}).is_ok());
        // A radius of code 0 is a zero radius: a degenerate needle.
        let error = edited_v4(|p| p.prototypes.needles.radii[1] = [0, 0]).unwrap_err();
        assert!(error.to_string().contains("degenerate"), "{error}");
        // Both ends on the same code: a zero-length needle.
        let error = edited_v4(|p| p.prototypes.needles.tips[0] = p.prototypes.needles.bases[0]).unwrap_err();
        assert!(error.to_string().contains("degenerate"), "{error}");
        // A merged error below its children's.
        let error = edited_v4(|p| p.tree_merged.last_mut().unwrap().error = 1u16.to_le_bytes()).unwrap_err();
        assert!(
            matches!(error, RecordError::Invalid(RecordInvalid::ErrorNotMonotone(_))),
            "{error}"
        );
        // A grid step of 2^100 m, or a grid missing.
        let error = edited_v4(|p| p.prototypes.grids[0].1 = 100).unwrap_err();
        assert!(matches!(error, RecordError::Malformed(_)), "{error}");
        let error = edited_v4(|p| p.prototypes.grids.clear()).unwrap_err();
        assert!(matches!(error, RecordError::Malformed(_)), "{error}");
        // Needle arrays of different lengths.
        let error = edited_v4(|p| {
            p.prototypes.needles.radii.pop();
        })
        .unwrap_err();
        assert!(matches!(error, RecordError::Malformed(_)), "{error}");
        // A wood mesh grid out of range.
        let error = edited_v4(|p| p.wood_mesh.grid.1 = -100).unwrap_err();
        assert!(
            matches!(error, RecordError::Invalid(RecordInvalid::BadWoodMesh)),
            "{error}"
        );
    }

    /// A baked prototype of two needles placed three times, rotated,
    /// scaled and moved; the third placement 100 m away, beyond the grid of
    /// translations.
    fn rotated_placements() -> PrototypeRecord {
        let needle = |k: f32| Needle {
            base: Vec3::new(0.0, k * 0.01, 0.0),
            tip: Vec3::new(0.02, k * 0.01 + 0.05, 0.0),
            radius: 0.001,
            normal: Vec3::Z,
            group: 0,
        };
        let input = super::super::PrototypeInput {
            name: "rotated".into(),
            prototypes: vec![vec![needle(0.0), needle(1.0)]],
            placements: (0..3)
                .map(|i| Placement {
                    rotation: glam::Quat::from_rotation_y(i as f32 * 0.7 + 0.1),
                    translation: Vec3::new(i as f32 * 0.3, 1.0, if i == 2 { 100.0 } else { 0.0 }),
                    scale: 1.0 + 0.1 * i as f32,
                    ..Placement::identity(0)
                })
                .collect(),
            ..Default::default()
        };
        super::super::bake_prototypes(&input, &Default::default(), &()).unwrap()
    }

    #[test]
    fn placements_on_codes_round_trip_in_23_bytes_and_far_ones_as_floats() {
        let record = rotated_placements();
        let bytes = encode_prototype_record(&record).unwrap();
        assert_eq!(decode_prototype_record(&bytes).unwrap(), record);
        let (payload, _): (Payload, &[u8]) = postcard::take_from_bytes(&bytes[HEADER_BYTES..]).unwrap();
        assert!(matches!(
            payload.placements[..],
            [
                StoredPlacement::Quantized(_),
                StoredPlacement::Quantized(_),
                StoredPlacement::Similarity(_)
            ]
        ));
        assert_eq!(postcard::to_allocvec(&payload.placements[0]).unwrap().len(), 23);
    }

    #[test]
    fn format_5_placements_read_as_floats_and_codes_need_format_6() {
        let record = rotated_placements();
        let bytes = encode_prototype_record(&record).unwrap();
        let body = &bytes[HEADER_BYTES..];
        let (mut payload, after): (Payload, &[u8]) = postcard::take_from_bytes(body).unwrap();
        // What formats 5 and 6 store after the payload: the appearance,
        // not format 7's impostor.
        let (_, impostor) = postcard::take_from_bytes::<StoredAppearance>(after).unwrap();
        let appearance = &after[..after.len() - impostor.len()];
        let edited = |payload: &Payload| {
            let mut body = postcard::to_allocvec(payload).unwrap();
            body.extend_from_slice(appearance);
            body
        };
        // Format 5 with its codes: malformed.
        let error = decode_prototype_record(&file_of_version(5, &edited(&payload))).unwrap_err();
        assert!(error.to_string().contains("format 6"), "{error}");
        // Format 5 as it was written: f32 placements, read as they are
        // (not snapped to codes).
        let rotation = glam::Quat::from_rotation_y(0.123_456_7);
        payload.placements[0] = StoredPlacement::Similarity(StoredSimilarity {
            prototype: 0,
            rotation: rotation.to_array(),
            translation: [0.123_456_7, 1.0, 0.0],
            scale: 1.0,
        });
        payload.placements[1] = StoredPlacement::Similarity(StoredSimilarity {
            prototype: 0,
            rotation: record.placements[1].rotation.to_array(),
            translation: record.placements[1].translation.to_array(),
            scale: record.placements[1].scale,
        });
        let read = decode_prototype_record(&file_of_version(5, &edited(&payload))).unwrap();
        assert_eq!(read.placements[0].rotation, rotation);
        assert_eq!(read.placements[0].translation.x, 0.123_456_7);
        assert_eq!(read.placements[1..], record.placements[1..]);
        // A rotation code beyond unit length is a bad placement.
        payload.placements[0] = StoredPlacement::Quantized(StoredSimilarity {
            prototype: 0,
            rotation: (u64::MAX >> 2).to_le_bytes(),
            translation: [0; 9],
            scale: 1.0,
        });
        let error = decode_prototype_record(&file_of_version(6, &edited(&payload))).unwrap_err();
        assert!(
            matches!(error, RecordError::Invalid(RecordInvalid::BadPlacement(0))),
            "{error}"
        );
    }

    #[test]
    fn a_well_formed_payload_decodes() {
        let record = decode(&payload(vec![StoredPlacement::NextIdentity])).unwrap();
        assert_eq!((record.prototypes.len(), record.needle_count()), (1, 3));
    }

    #[test]
    fn unknown_prototype_ids_are_bad_placements() {
        for placements in [
            vec![StoredPlacement::NextIdentity, StoredPlacement::NextIdentity],
            vec![StoredPlacement::Identity(0), StoredPlacement::Identity(u32::MAX)],
            vec![
                StoredPlacement::NextIdentity,
                StoredPlacement::Similarity(StoredSimilarity {
                    prototype: 7,
                    rotation: [0.0, 0.0, 0.0, 1.0],
                    translation: [0.0; 3],
                    scale: 1.0,
                }),
            ],
        ] {
            assert!(matches!(
                decode(&payload(placements)),
                Err(RecordError::Invalid(RecordInvalid::BadPlacement(1)))
            ));
        }
    }

    #[test]
    fn non_finite_or_degenerate_transforms_are_bad_placements() {
        for (rotation, scale) in [
            ([f32::NAN, 0.0, 0.0, 1.0], 1.0),
            ([0.0, 0.0, 0.0, 0.0], 1.0),
            ([0.0, 0.0, 0.0, 1.0], 0.0),
            ([0.0, 0.0, 0.0, 1.0], f32::INFINITY),
        ] {
            let placement = StoredPlacement::Similarity(StoredSimilarity {
                prototype: 0,
                rotation,
                translation: [0.0; 3],
                scale,
            });
            assert!(matches!(
                decode(&payload(vec![placement])),
                Err(RecordError::Invalid(RecordInvalid::BadPlacement(0)))
            ));
        }
    }

    #[test]
    fn placements_past_the_needle_limit_are_refused_before_expanding() {
        // 3 needles placed 2^24 / 3 + 1 times: just over the limit, in a
        // payload of a few megabytes.
        let count = (MAX_PLACED_NEEDLES / 3 + 1) as usize;
        let placements = (0..count).map(|_| StoredPlacement::Identity(0)).collect();
        assert!(matches!(
            decode(&payload(placements)),
            Err(RecordError::Invalid(RecordInvalid::TooManyNeedles(n))) if n > MAX_PLACED_NEEDLES
        ));
    }

    #[test]
    fn counts_that_do_not_add_up_are_malformed() {
        let mut bad = payload(vec![StoredPlacement::NextIdentity]);
        bad.prototypes.needle_counts = vec![2];
        assert!(matches!(decode(&bad), Err(RecordError::Malformed(_))));
        let mut bad = payload(vec![StoredPlacement::NextIdentity]);
        bad.prototypes.merged.pop();
        assert!(matches!(decode(&bad), Err(RecordError::Malformed(_))));
        let mut bad = payload(vec![StoredPlacement::NextIdentity]);
        bad.prototypes.needle_counts = vec![3, 0];
        assert!(matches!(decode(&bad), Err(RecordError::Malformed(_))));
        // A merged line whose child is its own id: the prototype's error.
        let mut bad = payload(vec![StoredPlacement::NextIdentity]);
        bad.prototypes.merged[1].back = [0, 1];
        assert!(matches!(
            decode(&bad),
            Err(RecordError::Invalid(RecordInvalid::Prototype { prototype: 0, .. }))
        ));
    }

    #[test]
    fn a_two_billion_element_header_is_an_error_not_an_allocation() {
        // Everything before the prototypes, then a needle count list that
        // claims 2^31 entries and ends at once.
        let prefix = (
            "hostile",
            "",
            None::<f64>,
            [0.25f32, 0.25, 0.5],
            8u8,
            FoliageMaterial::default(),
        );
        let mut body = postcard::to_allocvec(&prefix).unwrap();
        body.extend_from_slice(&[0x80, 0x80, 0x80, 0x80, 0x08, 1, 2, 3]);
        assert!(matches!(
            decode_prototype_record(&file(&body)),
            Err(RecordError::Malformed(_))
        ));
        assert!(matches!(decode_record(&file(&body)), Err(RecordError::Malformed(_))));
    }

    #[test]
    fn normal_codes_round_trip_exactly() {
        let mut state = 0x2545F4914F6CDD1Du64;
        for _ in 0..200_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let code = (state as u32).to_le_bytes();
            let n = decode_normal(code);
            assert!((n.length() - 1.0).abs() < 1e-5);
            let again = decode_normal(encode_normal(n));
            assert_eq!(again, n, "code {code:?}");
        }
    }

    #[test]
    fn snapped_normals_are_close() {
        for n in [
            Vec3::X,
            -Vec3::Y,
            Vec3::new(0.3, -0.4, -0.866).normalize(),
            Vec3::new(-1.0, 2.0, 3.0).normalize(),
        ] {
            assert!(snap_normal(n).angle_between(n) < 1e-3);
        }
        assert!(snap_normal(Vec3::ZERO).angle_between(Vec3::Z) < 1e-4);
    }
}
