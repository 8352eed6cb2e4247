//! The record file: round trip, size, and every malformed-file case gives a
//! typed error, never a panic, and never damages a file already written.

use bevy_conifer_lod::model::file::{FORMAT_VERSION, HEADER_BYTES, MAGIC};
use bevy_conifer_lod::model::{
    BakeOptions, LodRecord, Needle, RecordError, TreeInput, WoodSegment, bake, decode_record, encode_record,
    read_record, write_record,
};
use glam::Vec3;

/// A small deterministic tree: 40 fascicles of 3 needles on a helix.
fn small_record() -> LodRecord {
    let mut needles = Vec::new();
    for g in 0..40u32 {
        let t = g as f32 * 0.37;
        let base = Vec3::new(t.cos() * 0.3, g as f32 * 0.02, t.sin() * 0.3);
        for k in 0..3 {
            let direction = Vec3::new(t.cos(), 0.4 + 0.1 * k as f32, t.sin() + 0.2 * k as f32).normalize();
            needles.push(Needle {
                base,
                tip: base + direction * 0.05,
                radius: 0.000_777 + 0.000_01 * k as f32,
                normal: direction.any_orthonormal_vector(),
                group: g,
            });
        }
    }
    let wood = vec![WoodSegment {
        start: Vec3::ZERO,
        end: Vec3::Y,
        start_radius: 0.03,
        end_radius: 0.01,
    }];
    let input = TreeInput {
        name: "helix".into(),
        needles,
        wood,
        ..Default::default()
    };
    bake(&input, &BakeOptions::default(), &()).unwrap()
}

/// Recomputes the header checksum after the payload was edited, so the
/// decoder's own checks (not the checksum) must catch the problem.
fn fix_checksum(bytes: &mut [u8]) {
    let crc = crc32fast::hash(&bytes[HEADER_BYTES..]);
    bytes[20..24].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn round_trip_through_a_file() {
    let record = small_record();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("helix.conifer");
    let bytes = write_record(&record, &path).unwrap();
    assert_eq!(bytes, std::fs::metadata(&path).unwrap().len());
    assert_eq!(read_record(&path).unwrap(), record);
    // Compact: far below the paper's prism sequences (≥ 66 vertices a needle).
    let per_needle = bytes as f64 / record.needle_count() as f64;
    assert!(per_needle < 60.0, "{per_needle} bytes per needle");
}

#[test]
fn every_truncation_is_reported_as_truncated() {
    let bytes = encode_record(&small_record()).unwrap();
    for len in 0..bytes.len() {
        match decode_record(&bytes[..len]) {
            Err(RecordError::Truncated { found, .. }) => assert_eq!(found, len as u64),
            other => panic!("length {len}: expected Truncated, got {other:?}"),
        }
    }
}

#[test]
fn every_flipped_byte_is_an_error_not_a_panic() {
    let bytes = encode_record(&small_record()).unwrap();
    for at in 0..bytes.len() {
        for flip in [0x01u8, 0x80] {
            let mut bad = bytes.clone();
            bad[at] ^= flip;
            let result = decode_record(&bad);
            assert!(result.is_err(), "flipping byte {at} went unnoticed");
            if at >= HEADER_BYTES {
                assert!(
                    matches!(result, Err(RecordError::ChecksumMismatch { .. })),
                    "byte {at}: {result:?}"
                );
            }
        }
    }
}

#[test]
fn edited_payloads_with_valid_checksums_are_rejected() {
    let bytes = encode_record(&small_record()).unwrap();
    // Any single-byte edit of the payload, checksum recomputed: either a
    // typed error or a record that passes every invariant, never a panic.
    for at in HEADER_BYTES..bytes.len() {
        for value in [0x00u8, 0xFF, 0x7F] {
            let mut edited = bytes.clone();
            edited[at] = value;
            fix_checksum(&mut edited);
            if let Ok(record) = decode_record(&edited) {
                for e in [0.0, 0.001, 0.01, 0.1, 10.0] {
                    let cut = record.cut(e);
                    assert!(record.coverage(&cut).iter().all(|&c| c == 1));
                }
            }
        }
    }
}

#[test]
fn wrong_magic_and_version() {
    let bytes = encode_record(&small_record()).unwrap();
    let mut bad = bytes.clone();
    bad[0] = b'X';
    assert!(matches!(decode_record(&bad), Err(RecordError::NotARecord)));
    assert!(matches!(
        decode_record(b"glTF\x02\0\0\0 not a record at all"),
        Err(RecordError::NotARecord)
    ));
    let mut future = bytes.clone();
    future[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    match decode_record(&future) {
        Err(RecordError::UnsupportedVersion { found, supported }) => {
            assert_eq!((found, supported), (FORMAT_VERSION + 1, FORMAT_VERSION));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(&bytes[..8], &MAGIC);
}

#[test]
fn trailing_bytes_and_huge_lengths() {
    let bytes = encode_record(&small_record()).unwrap();
    let mut longer = bytes.clone();
    longer.extend_from_slice(b"junk");
    assert!(matches!(decode_record(&longer), Err(RecordError::TrailingBytes(4))));
    let mut huge = bytes.clone();
    huge[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(matches!(decode_record(&huge), Err(RecordError::Truncated { .. })));
}

#[test]
fn nan_carrying_records_are_rejected() {
    // Format 4 stores needles and errors as codes (no NaN to write; the
    // unit tests of `model::file` corrupt the codes); wood segments,
    // placements and the material stay f32. The trunk's start radius:
    let record = small_record();
    let bytes = encode_record(&record).unwrap();
    let radius = record.wood[0].start_radius.to_le_bytes();
    let at = bytes
        .windows(4)
        .position(|w| w == radius)
        .expect("wood radius stored verbatim");
    let mut bad = bytes.clone();
    bad[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    fix_checksum(&mut bad);
    match decode_record(&bad) {
        Err(RecordError::Invalid(reason)) => assert!(reason.to_string().contains("non-finite"), "{reason}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_failed_write_leaves_the_existing_file_intact() {
    let record = small_record();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tree.conifer");
    write_record(&record, &path).unwrap();
    let before = std::fs::read(&path).unwrap();
    // Writing into a directory that does not exist fails cleanly.
    let missing = dir.path().join("no/such/dir/tree.conifer");
    assert!(matches!(write_record(&record, &missing), Err(RecordError::Io(_))));
    // A path that is a directory cannot be replaced: the error leaves no temp file.
    assert!(write_record(&record, dir.path()).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before);
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "{leftovers:?}");
}

#[test]
fn reading_a_missing_file_is_an_io_error() {
    assert!(matches!(
        read_record(std::path::Path::new("/nonexistent/x.conifer")),
        Err(RecordError::Io(_))
    ));
}

#[test]
fn shipped_tree_records_load_with_the_current_format() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "conifer") {
            let bytes = std::fs::read(&path).unwrap();
            // Header: magic, then the format version (u32, little-endian).
            assert_eq!(bytes[..8], MAGIC, "{}", path.display());
            assert_eq!(
                u32::from_le_bytes(bytes[8..12].try_into().unwrap()),
                FORMAT_VERSION,
                "{}: re-bake the shipped records after a format change",
                path.display()
            );
            let record = read_record(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(record.needle_count() >= 30_000 && !record.wood.is_empty());
            names.push(path.file_stem().unwrap().to_string_lossy().into_owned());
        }
    }
    names.sort();
    assert_eq!(
        names,
        ["eastern-white-pine", "lawson-cypress", "norway-spruce", "scots-pine"]
    );
}

#[test]
fn format_2_files_load_converted() {
    use bevy_conifer_lod::model::{PrototypeRecord, decode_prototype_record, encode_prototype_record};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/format2-scots-pine.conifer");
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 2);
    let flat = decode_record(&bytes).unwrap();
    assert_eq!((flat.needle_count(), flat.group_count()), (60, 30));
    // As prototypes: every group a prototype placed once, flattening back
    // to the very same record.
    let prototypes = decode_prototype_record(&bytes).unwrap();
    assert_eq!(prototypes, PrototypeRecord::from_flat(&flat).unwrap());
    assert_eq!(prototypes.placements.len(), 30);
    assert_eq!(prototypes.flatten().unwrap(), flat);
    // Written again, it is a current-format file holding the same tree, quantized:
    // needle ends within a grid step (micrometres for these fascicles),
    // radii within 0.025 %, merged errors rounded up (0.05 % a level, plus
    // what their children's rounding added), the merge forest unchanged;
    // and quantizing again changes nothing.
    let again = encode_prototype_record(&prototypes).unwrap();
    assert_eq!(u32::from_le_bytes(again[8..12].try_into().unwrap()), FORMAT_VERSION);
    let back = decode_record(&again).unwrap();
    assert_eq!((back.needle_count(), back.group_count()), (60, 30));
    for (a, b) in flat.needles.iter().zip(&back.needles) {
        assert!(
            a.base.distance(b.base) < 1e-5 && a.tip.distance(b.tip) < 1e-5,
            "{a:?} vs {b:?}"
        );
        assert!(
            (b.radius / a.radius - 1.0).abs() < 2.5e-4,
            "{} vs {}",
            a.radius,
            b.radius
        );
        assert_eq!(a.group, b.group);
    }
    assert_eq!(flat.merged.len(), back.merged.len());
    for (a, b) in flat.merged.iter().zip(&back.merged) {
        assert_eq!((a.children, a.ends), (b.children, b.ends));
        assert!(
            b.error >= a.error && b.error <= a.error * 1.002,
            "{} vs {}",
            a.error,
            b.error
        );
    }
    assert_eq!(encode_record(&back).unwrap(), again);
    // Format 1 is refused with an error that says to re-bake.
    let mut old = bytes.clone();
    old[8..12].copy_from_slice(&1u32.to_le_bytes());
    let error = decode_record(&old).unwrap_err();
    assert!(matches!(error, RecordError::UnsupportedVersion { found: 1, .. }));
    assert!(error.to_string().contains("re-bake"), "{error}");
}

#[test]
fn shipped_mature_records_are_the_presets_current_bakes() {
    // `assets/trees/mature/`: the six mature presets (seed 0) as `conifer
    // bake --preset P` writes them; each must be what the generator and
    // the bake make today (re-bake them after changing either).
    use bevy_conifer_lod::generate::{GenerateOptions, Species, generate_prototypes};
    use bevy_conifer_lod::model::{bake_prototypes, read_prototype_record};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/mature");
    let mut total = 0u64;
    for species in Species::ALL {
        let path = dir.join(format!("{}.conifer", species.name()));
        total += std::fs::metadata(&path).unwrap().len();
        let shipped = read_prototype_record(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(
            (1_800_000..=2_000_800).contains(&shipped.needle_count()),
            "{species}: {} needles",
            shipped.needle_count()
        );
        let flat = shipped.flatten().unwrap();
        let (lo, hi) = flat.bounds();
        assert!((15.0..=50.0).contains(&(hi.y - lo.y)), "{species}: {} m", hi.y - lo.y);
        // The shipped impostor is baked with the default options (its
        // texels are the bake's own function of the needles, tested in
        // `model::impostor`; baking six here would take minutes in debug).
        let impostor = shipped.impostor.as_deref().expect("the record holds its impostor");
        assert_eq!(
            impostor.crown_density,
            bevy_conifer_lod::model::impostor::CrownDensity::measure(&flat.needles, impostor),
            "{species}: the impostor's crown density is its needles'"
        );
        assert_eq!(
            impostor.seen_needles,
            bevy_conifer_lod::model::color::NeedleMix::seen(&shipped, &shipped.placed_needles(), impostor),
            "{species}: the impostor's seen needles are what its views see"
        );
        let options = bevy_conifer_lod::model::impostor::ImpostorOptions::default();
        assert_eq!(impostor.views, options.views, "{species}");
        assert!(
            impostor.texel <= options.texel && impostor.texel > 0.98 * options.texel,
            "{species}: texel {}",
            impostor.texel
        );
        let input = generate_prototypes(species, &GenerateOptions::default());
        let without_impostor = BakeOptions {
            impostor: None,
            line_calibration: None,
            ..BakeOptions::default()
        };
        let baked = bake_prototypes(&input, &without_impostor, &()).unwrap();
        assert!(
            baked.prototypes == shipped.prototypes
                && baked.placements == shipped.placements
                && baked.tree_merged == shipped.tree_merged
                && baked.wood == shipped.wood,
            "{species}: the shipped record is not the preset's current bake; re-bake it \
             (conifer bake --preset {} -o {})",
            species.name(),
            path.display()
        );
    }
    assert!(total <= 30 << 20, "{total} bytes shipped");
}

#[test]
fn shipped_impostors_keep_their_coverage_at_every_mip_level() {
    // Each view of every shipped record's crown impostor: the mean
    // coverage of every mip level the plugin uploads is the picture's to
    // within half a step of 255, the levels of odd size too. (Rounding
    // each level from the one below drifted a faint crown's coverage by
    // up to 5 % by its fourth level.)
    use bevy_conifer_lod::model::read_prototype_record;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees");
    let mut paths: Vec<_> = ["", "mature"]
        .iter()
        .flat_map(|sub| std::fs::read_dir(root.join(sub)).unwrap())
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "conifer"))
        .collect();
    paths.sort();
    assert_eq!(paths.len(), 10);
    for path in paths {
        let impostor = match read_record(&path) {
            Ok(record) => record.impostor,
            Err(_) => read_prototype_record(&path).unwrap().impostor,
        }
        .unwrap_or_else(|| panic!("{}: no impostor", path.display()));
        let chain = impostor.mip_chain();
        let mut worst: f64 = 0.0;
        for view in 0..impostor.views as usize {
            let mean = |(w, h, texels): &(u32, u32, Vec<[u8; 4]>)| {
                let n = (*w * *h) as usize;
                texels[view * n..(view + 1) * n]
                    .iter()
                    .map(|t| f64::from(t[0]))
                    .sum::<f64>()
                    / n as f64
            };
            let whole = mean(&chain[0]);
            for level in &chain[1..] {
                let drift = mean(level) - whole;
                assert!(drift.abs() <= 0.5 + 1e-9, "{} view {view}: {drift}", path.display());
                worst = worst.max(drift.abs() / whole);
            }
        }
        println!(
            "{}: {} levels, largest drift {:.2} %",
            path.display(),
            chain.len(),
            100.0 * worst
        );
    }
}

/// The mature Norway spruce's impostor takes its shadows where its
/// needles are seen. A depth buffer of its needles in view 0 (16 × 16
/// samples a texel; a needle's steps of half a sample each hit the sample
/// under them with the share of it they cover, the nearest hit kept)
/// gives each texel's median seen depth; the impostor's middle shadow
/// sample (`shadow_sample_depths`) with the crown's rings sits nearer it
/// than with the needles even along the chord. Measured: even 0.88 m in
/// front of it on average over 11,479 of the crown's texels, the rings
/// 0.40 m.
#[test]
fn the_mature_spruces_impostor_takes_its_shadows_where_its_needles_are_seen() {
    use bevy_conifer_lod::model::impostor::{CROWN_DENSITY_RINGS, CrownImpostor, shadow_sample_depths};
    use bevy_conifer_lod::model::read_prototype_record;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/trees/mature/norway-spruce.conifer");
    let record = read_prototype_record(&path).unwrap();
    let impostor = record.impostor.as_deref().expect("an impostor");
    let needles = record.placed_needles();
    let radii = impostor.crown_radii();
    let n = 16u32;
    let sample = impostor.texel / n as f32;
    let (width, height) = (impostor.columns * n, impostor.rows * n);
    let axis = Vec3::new(impostor.axis.x, 0.0, impostor.axis.y);
    let (right, toward) = (impostor.view_right(0), Vec3::Z);
    let mut nearest = vec![f32::NEG_INFINITY; (width * height) as usize];
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    for needle in &needles {
        let steps = ((needle.length() / (0.5 * sample)).ceil() as u32).max(1);
        let hit = f64::from(2.0 * needle.radius * needle.length() / steps as f32 / (sample * sample));
        for k in 0..steps {
            let p = needle.base.lerp(needle.tip, (k as f32 + 0.5) / steps as f32);
            let x = ((p - axis).dot(right) + impostor.half_width) / sample;
            let y = (impostor.top() - p.y) / sample;
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            if x >= 0.0
                && y >= 0.0
                && x < width as f32
                && y < height as f32
                && ((seed >> 11) as f64) < hit * (1u64 << 53) as f64
            {
                let at = &mut nearest[(y as u32 * width + x as u32) as usize];
                *at = at.max((p - axis).dot(toward));
            }
        }
    }
    let (mut even_off, mut rings_off, mut texels) = (0.0f64, 0.0f64, 0u32);
    for row in 0..impostor.rows {
        let y = impostor.top() - (row as f32 + 0.5) * impostor.texel;
        let radius = CrownImpostor::crown_radius_at(&radii, impostor.bottom, impostor.top(), y);
        let density = impostor.crown_density.row_at(impostor.bottom, impostor.top(), y);
        for column in 0..impostor.columns {
            let texel = impostor.texel_at(0, column, row).unwrap();
            let offset = (column as f32 + 0.5) * impostor.texel - impostor.half_width;
            if texel.coverage < 0.1 || texel.wood > 0.05 || offset.abs() >= radius {
                continue;
            }
            let mut seen: Vec<f32> = (row * n..(row + 1) * n)
                .flat_map(|j| (column * n..(column + 1) * n).map(move |i| (j * width + i) as usize))
                .map(|i| nearest[i])
                .filter(|d| d.is_finite())
                .collect();
            if seen.len() < 12 {
                continue;
            }
            seen.sort_by(f32::total_cmp);
            let median = seen[seen.len() / 2];
            let even = shadow_sample_depths(texel.coverage, offset, radius, &[1.0; CROWN_DENSITY_RINGS])[1];
            let rings = shadow_sample_depths(texel.coverage, offset, radius, &density)[1];
            even_off += f64::from(even - median);
            rings_off += f64::from(rings - median);
            texels += 1;
        }
    }
    let (even_off, rings_off) = (even_off / f64::from(texels), rings_off / f64::from(texels));
    println!(
        "middle shadow sample in front of the median seen needle over {texels} texels: even {even_off:.3} m, rings {rings_off:.3} m"
    );
    assert!(texels > 5_000, "{texels} texels");
    assert!(even_off > 0.5, "the even crown puts the samples in front: {even_off}");
    assert!(
        rings_off.abs() < 0.5 * even_off,
        "the rings: {rings_off}, even: {even_off}"
    );
}
