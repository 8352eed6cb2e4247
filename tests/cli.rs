//! The `conifer` command line, run as a user runs it: outputs, JSON keys,
//! and clear errors (non-zero exit, file named, no panic) on bad input.

use bevy_conifer_lod::model::file::FORMAT_VERSION;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn conifer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_conifer"))
        .args(args)
        .output()
        .expect("conifer runs")
}

fn json(output: &Output) -> Value {
    assert!(
        output.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("one JSON object on stdout")
}

/// Asserts a clean failure: non-zero exit, a message naming `needle`, no panic.
fn assert_fails_naming(output: &Output, needle: &str) -> String {
    let stderr = String::from_utf8_lossy(&output.stderr).to_string();
    assert!(!output.status.success(), "expected failure, stderr: {stderr}");
    assert!(stderr.contains(needle), "stderr does not name {needle:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    stderr
}

/// A young preset baked (the figures below were calibrated on them).
fn baked(dir: &Path, preset: &str, needles: &str) -> PathBuf {
    let out = dir.join(format!("{preset}.conifer"));
    let output = conifer(&[
        "bake",
        "--preset",
        preset,
        "--age",
        "young",
        "--seed",
        "3",
        "--needles",
        needles,
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    out
}

#[test]
fn bake_inspect_and_cut_a_preset() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "norway-spruce", "6000");
    let path = file.to_str().unwrap();

    let inspect = json(&conifer(&["inspect", path, "--json"]));
    let needles = inspect["needles"].as_u64().unwrap();
    assert!((4000..=8000).contains(&needles), "{needles}");
    assert_eq!(inspect["lines_original"].as_u64(), Some(needles));
    assert_eq!(inspect["lines_merged"].as_u64(), Some(needles - 1));
    assert_eq!(inspect["roots"].as_u64(), Some(1));
    assert!(inspect["groups"].as_u64().unwrap() > 10);
    for part in ["cylinders", "original_lines", "merged_lines"] {
        let range = inspect["error_ranges"][part].as_array().unwrap();
        assert!(range[0].as_f64().unwrap() <= range[1].as_f64().unwrap());
    }
    let bytes = inspect["bytes"].as_u64().unwrap();
    assert_eq!(bytes, std::fs::metadata(&file).unwrap().len());
    assert!((inspect["bytes_per_needle"].as_f64().unwrap() - bytes as f64 / needles as f64).abs() < 1e-9);
    assert!(inspect["bake_seconds"].as_f64().unwrap() > 0.0);

    let mut previous_primitives = u64::MAX;
    for distance in ["0.5", "2", "10", "40", "160", "1000"] {
        let cut = json(&conifer(&["cut", path, "--distance", distance, "--json"]));
        assert_eq!(cut["needles_covered"].as_u64(), Some(needles), "at {distance} m");
        let triangles = cut["triangles"].as_u64().unwrap();
        let segments = cut["line_segments"].as_u64().unwrap();
        assert_eq!(
            segments,
            cut["lines_original"].as_u64().unwrap() + cut["lines_merged"].as_u64().unwrap()
        );
        let prism_total: u64 = cut["prism_sides"]
            .as_object()
            .unwrap()
            .values()
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(prism_total, cut["prisms"].as_u64().unwrap());
        // The placed layout the plugin loads walks at least what it draws
        // (a prism or a line a primitive).
        let drawn = cut["prisms"].as_u64().unwrap() + segments;
        let processed = cut["gpu_placed_primitives_processed"].as_u64().unwrap();
        assert!(
            drawn <= processed,
            "at {distance} m: {processed} processed, {drawn} drawn"
        );
        assert!(triangles + segments <= previous_primitives, "cost grew at {distance} m");
        previous_primitives = triangles + segments;
    }
    let close = json(&conifer(&["cut", path, "--distance", "0.5", "--json"]));
    assert_eq!(
        close["prisms"].as_u64(),
        Some(needles),
        "every needle is a prism at 0.5 m"
    );
    let far = json(&conifer(&["cut", path, "--distance", "1000", "--json"]));
    assert_eq!(far["prisms"].as_u64(), Some(0));
    assert!(far["line_segments"].as_u64().unwrap() < needles / 10);
}

#[test]
fn preview_writes_a_picture() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "scots-pine", "5000");
    let png = dir.path().join("pine.png");
    let report = json(&conifer(&[
        "preview",
        file.to_str().unwrap(),
        "--distance",
        "12",
        "--size",
        "128x160",
        "-o",
        png.to_str().unwrap(),
    ]));
    assert!(report["render_ms"].as_f64().unwrap() >= 0.0);
    let image = image::open(&png).unwrap().to_rgba8();
    assert_eq!(image.dimensions(), (128, 160));
    let background = *image.get_pixel(0, 0);
    let drawn = image.pixels().filter(|p| **p != background).count();
    assert!(drawn > 500, "only {drawn} pixels differ from the background");
}

#[test]
fn bake_the_fixture_inspect_and_export() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("pine.conifer");
    let output = conifer(&[
        "bake",
        "../shared/fixtures/small_pine_s0.glb",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]);
    let report = json(&output);
    assert_eq!(report["needles"].as_u64(), Some(48_607));
    assert_eq!(report["import"]["needles"].as_u64(), Some(48_607));
    assert_eq!(report["import"]["wood_triangles"].as_u64(), Some(60_224));
    let inspect = json(&conifer(&["inspect", out.to_str().unwrap(), "--json"]));
    assert_eq!(inspect["needles"].as_u64(), Some(48_607));
    assert_eq!(inspect["wood_triangles"].as_u64(), Some(60_224));
    let radius = inspect["radius"]["median"].as_f64().unwrap();
    assert!((radius - 0.001_724).abs() < 2e-5, "{radius}");
    for key in ["radius", "length", "group_size"] {
        let v = &inspect[key];
        assert!(v["min"].as_f64().unwrap() <= v["median"].as_f64().unwrap(), "{key}");
        assert!(v["median"].as_f64().unwrap() <= v["max"].as_f64().unwrap(), "{key}");
    }
    assert!(inspect["group_size"]["max"].as_f64().unwrap() <= 128.0);

    let glb = dir.path().join("cut.glb");
    let export = json(&conifer(&[
        "export",
        out.to_str().unwrap(),
        "--error",
        "0.03",
        "-o",
        glb.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(export["wood_triangles"].as_u64(), Some(60_224));
    let bytes = std::fs::read(&glb).unwrap();
    assert_eq!(export["bytes"].as_u64(), Some(bytes.len() as u64));
    let gltf = gltf::Gltf::from_slice(&bytes).expect("a valid glTF");
    assert!(gltf.meshes().any(|m| m.name() == Some("lines")));
    // The same cut as `conifer cut` at that error.
    let cut = json(&conifer(&["cut", out.to_str().unwrap(), "--distance", "1", "--json"]));
    assert!(cut["needles_covered"].as_u64() == Some(48_607));
}

#[test]
fn needles_names_and_scale_options() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.conifer");
    // Naming the wrong geometry: no needles, a clear error.
    let output = conifer(&[
        "bake",
        "../shared/fixtures/small_pine_s0.glb",
        "--needles",
        "bark*",
        "-o",
        out.to_str().unwrap(),
    ]);
    let stderr = assert_fails_naming(&output, "small_pine_s0.glb");
    assert!(
        stderr.contains("no needle geometry") && stderr.contains("bark*"),
        "{stderr}"
    );
    assert!(!out.exists());
    // Naming the right one, in centimetres.
    let report = json(&conifer(&[
        "bake",
        "../shared/fixtures/small_pine_s0.glb",
        "--needles",
        "LEAVES",
        "--needles",
        "unused",
        "--scale",
        "0.01",
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]));
    let radius = report["import"]["radius"]["median"].as_f64().unwrap();
    assert!((radius - 0.000_017_24).abs() < 2e-7, "{radius}");
    // --needles with a preset is a count.
    let output = conifer(&[
        "bake",
        "--preset",
        "scots-pine",
        "--needles",
        "leaves",
        "-o",
        "/tmp/never.conifer",
    ]);
    assert_fails_naming(&output, "needle count");
}

#[test]
fn bad_gltf_files_are_named_errors_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let fixture = std::fs::read("../shared/fixtures/small_pine_s0.glb").unwrap();
    let quad = |count: u64, mode: u32, buffer: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"nodes":[{{"mesh":0,"name":"leaves"}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"mode":{mode}}}]}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                         {{"bufferView":1,"componentType":5125,"count":{count},"type":"SCALAR"}}],
            "bufferViews":[{{"buffer":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
            "buffers":[{{"byteLength":72,"uri":"{buffer}"}}]}}"#
        )
    };
    let mut bin: Vec<u8> = [
        [0.0f32, 0.0, 0.0],
        [0.0, 0.1, 0.0],
        [0.002, 0.1, 0.0],
        [0.002, 0.0, 0.0],
    ]
    .iter()
    .flatten()
    .flat_map(|x| x.to_le_bytes())
    .collect();
    bin.extend([0u32, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    std::fs::write(dir.path().join("quad.bin"), &bin).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("notes.glb", b"these are my notes".to_vec(), "not a glTF file"),
        ("cut.glb", fixture[..fixture.len() / 2].to_vec(), "truncated"),
        (
            "trunk.gltf",
            quad(6, 4, "quad.bin").replace("leaves", "trunk").into_bytes(),
            "no needle geometry",
        ),
        ("nobuffer.gltf", quad(6, 4, "gone.bin").into_bytes(), "gone.bin"),
        (
            "huge.gltf",
            quad(2_000_000_000, 4, "quad.bin").into_bytes(),
            "2000000000 elements",
        ),
        ("lines.gltf", quad(6, 1, "quad.bin").into_bytes(), "LINES"),
    ];
    for (name, bytes, cause) in cases {
        let input = dir.path().join(name);
        std::fs::write(&input, &bytes).unwrap();
        let out = dir.path().join(format!("{name}.conifer"));
        let stderr = assert_fails_naming(
            &conifer(&["bake", input.to_str().unwrap(), "-o", out.to_str().unwrap()]),
            name,
        );
        assert!(stderr.contains(cause), "{name}: {stderr}");
        assert!(!out.exists(), "{name}: nothing written");
    }
    // A good one, for contrast, from the same buffer file.
    let input = dir.path().join("good.gltf");
    std::fs::write(&input, quad(6, 4, "quad.bin")).unwrap();
    let out = dir.path().join("good.conifer");
    let report = json(&conifer(&[
        "bake",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(report["needles"].as_u64(), Some(1));
    // A failed import leaves an existing record alone, and no temporary files.
    let before = std::fs::read(&out).unwrap();
    let notes = dir.path().join("notes.glb");
    assert_fails_naming(
        &conifer(&["bake", notes.to_str().unwrap(), "-o", out.to_str().unwrap()]),
        "notes.glb",
    );
    assert_eq!(std::fs::read(&out).unwrap(), before);
    assert!(
        std::fs::read_dir(dir.path())
            .unwrap()
            .all(|e| !e.unwrap().file_name().to_string_lossy().contains(".tmp"))
    );
}

#[test]
fn export_refuses_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "lawson-cypress", "5000");
    let out = dir.path().join("x.glb");
    for bad in [["--error", "-1"], ["--error", "NaN"]] {
        let output = conifer(&[
            "export",
            file.to_str().unwrap(),
            bad[0],
            bad[1],
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_fails_naming(&output, "--error");
    }
    let output = conifer(&[
        "export",
        "/nonexistent/x.conifer",
        "--error",
        "0.1",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_fails_naming(&output, "x.conifer");
    assert!(!out.exists());
}

#[test]
fn unknown_merge_errors_are_named() {
    let output = conifer(&[
        "bake",
        "--preset",
        "scots-pine",
        "--merge-error",
        "tightest",
        "-o",
        "/tmp/never.conifer",
    ]);
    let stderr = assert_fails_naming(&output, "tightest");
    assert!(stderr.contains("needles") && stderr.contains("nested"), "{stderr}");
    assert!(!std::path::Path::new("/tmp/never.conifer").exists());
}

#[test]
fn unknown_preset_lists_the_valid_ones() {
    let output = conifer(&["bake", "--preset", "oak", "-o", "/tmp/never.conifer"]);
    let stderr = assert_fails_naming(&output, "oak");
    for name in ["scots-pine", "norway-spruce", "eastern-white-pine", "lawson-cypress"] {
        assert!(stderr.contains(name), "{stderr}");
    }
}

#[test]
fn bad_records_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = baked(dir.path(), "lawson-cypress", "5000");
    let bytes = std::fs::read(&good).unwrap();

    let missing = dir.path().join("missing.conifer");
    assert_fails_naming(&conifer(&["inspect", missing.to_str().unwrap()]), "missing.conifer");

    let truncated = dir.path().join("truncated.conifer");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let stderr = assert_fails_naming(&conifer(&["inspect", truncated.to_str().unwrap()]), "truncated.conifer");
    assert!(stderr.contains("truncated"), "{stderr}");

    let corrupted = dir.path().join("corrupted.conifer");
    let mut flipped = bytes.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0x10;
    std::fs::write(&corrupted, &flipped).unwrap();
    let stderr = assert_fails_naming(
        &conifer(&["cut", corrupted.to_str().unwrap(), "--distance", "10"]),
        "corrupted.conifer",
    );
    assert!(stderr.contains("checksum"), "{stderr}");

    let text = dir.path().join("notes.conifer");
    std::fs::write(&text, "hello").unwrap();
    let stderr = assert_fails_naming(
        &conifer(&["inspect", text.to_str().unwrap(), "--json"]),
        "notes.conifer",
    );
    assert!(stderr.contains("not a conifer LOD record"), "{stderr}");
}

#[test]
fn bad_views_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "lawson-cypress", "5000");
    let path = file.to_str().unwrap();
    assert_fails_naming(&conifer(&["cut", path, "--distance=-1"]), "--distance");
    assert_fails_naming(&conifer(&["cut", path, "--distance", "NaN"]), "--distance");
    assert_fails_naming(
        &conifer(&["cut", path, "--distance", "5", "--height-px", "0"]),
        "--height-px",
    );
    assert_fails_naming(
        &conifer(&["cut", path, "--distance", "5", "--transition", "1.5"]),
        "--transition",
    );
    assert_fails_naming(
        &conifer(&["preview", path, "--distance", "5", "--size", "0x0", "-o", "/tmp/x.png"]),
        "--size",
    );
}

/// `--impostor-steep START,END`: a band that is not two degrees from 0 to
/// 90 in order is refused by `conifer eval` before any record is read,
/// naming the option and the form it expects.
#[cfg(feature = "eval")]
#[test]
fn bad_impostor_steep_bands_are_refused() {
    for bad in ["30,15", "20,20", "15", "-5,30", "15,91", "NaN,30", "a,b"] {
        let stderr = assert_fails_naming(
            &conifer(&["eval", "no-such.conifer", &format!("--impostor-steep={bad}")]),
            "--impostor-steep",
        );
        assert!(stderr.contains("START,END"), "{bad}: {stderr}");
        assert!(
            !stderr.contains("no-such.conifer"),
            "{bad}: read the record first: {stderr}"
        );
    }
}

#[test]
fn a_failed_bake_keeps_the_previous_record() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "lawson-cypress", "5000");
    let before = std::fs::read(&file).unwrap();
    // Invalid options fail before anything is written.
    let output = conifer(&[
        "bake",
        "--preset",
        "lawson-cypress",
        "--max-sides",
        "2",
        "-o",
        file.to_str().unwrap(),
    ]);
    assert_fails_naming(&output, "max sides");
    assert_eq!(std::fs::read(&file).unwrap(), before);
    let entries = std::fs::read_dir(dir.path()).unwrap().count();
    assert_eq!(entries, 1, "no temporary file left behind");
}

#[test]
fn presets_bake_as_shared_shoots_and_upgrade_rewrites_old_records() {
    let dir = tempfile::tempdir().unwrap();
    let shoots = baked(dir.path(), "eastern-white-pine", "20000");
    let inspect = json(&conifer(&["inspect", shoots.to_str().unwrap(), "--json"]));
    let needles = inspect["needles"].as_u64().unwrap();
    assert!((19_000..=21_000).contains(&needles), "{needles}");
    assert_eq!(inspect["format_version"].as_u64(), Some(u64::from(FORMAT_VERSION)));
    let prototypes = inspect["prototypes"].as_u64().unwrap();
    assert!((10..=120).contains(&prototypes), "{prototypes} prototypes");
    assert!(inspect["prototype_needles"].as_u64().unwrap() * 5 < needles);
    assert!(inspect["groups"].as_u64().unwrap() > prototypes);
    // The bake calibrated its lines: eight scales, none above 1.05 (a
    // crown's lines over-cover, never under-cover, by much).
    let scales = inspect["line_calibration"]["scales"]
        .as_array()
        .expect("a line calibration");
    assert_eq!(scales.len(), 8);
    assert!(
        scales.iter().all(|s| (0.25..=1.05).contains(&s.as_f64().unwrap())),
        "{scales:?}"
    );

    // The bake measured the needles its impostor sees: six shares, the
    // ages' summing to 1, and the far colour their mix.
    let seen = inspect["impostor"]["seen_needles"].clone();
    let shares: Vec<[f64; 2]> = serde_json::from_value(seen.clone()).expect("seen needles");
    assert_eq!(shares.len(), 3);
    assert!(
        (shares.iter().map(|s| s[0]).sum::<f64>() - 1.0).abs() < 1e-3,
        "{shares:?}"
    );
    assert!(shares.iter().all(|s| (0.0..=s[0]).contains(&s[1])), "{shares:?}");
    // The bake measured its impostor's view light scale.
    let scale = inspect["impostor"]["view_light_scale"].clone();
    assert!(scale.is_array(), "the bake measures the view light scale: {scale}");
    // Format 14 and 13 copies (the last bytes cut: the scale, `Some`, its
    // length and 91 f32s, then the mix's 25; the header rewritten) read
    // without them and upgrade to the bake's.
    let scale_bytes = 2 + 4 * bevy_conifer_lod::model::impostor::ViewLightScale::LEN;
    let bytes = std::fs::read(&shoots).unwrap();
    let copy = |version: u32, cut: usize| {
        let old = dir.path().join(format!("format{version}.conifer"));
        let body = &bytes[bevy_conifer_lod::model::file::HEADER_BYTES..bytes.len() - cut];
        let mut file = bytes[..8].to_vec();
        file.extend_from_slice(&version.to_le_bytes());
        file.extend_from_slice(&(body.len() as u64).to_le_bytes());
        file.extend_from_slice(&crc32fast::hash(body).to_le_bytes());
        file.extend_from_slice(body);
        std::fs::write(&old, &file).unwrap();
        old
    };
    for (version, cut) in [(14, scale_bytes), (13, scale_bytes + 25)] {
        let old = copy(version, cut);
        let read = json(&conifer(&["inspect", old.to_str().unwrap(), "--json"]));
        assert!(read["impostor"]["view_light_scale"].is_null(), "format {version}");
        assert_eq!(read["impostor"]["seen_needles"].is_null(), version < 14);
        let output = conifer(&["upgrade", old.to_str().unwrap()]);
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        let upgraded = json(&conifer(&["inspect", old.to_str().unwrap(), "--json"]));
        assert_eq!(upgraded["impostor"]["seen_needles"], seen, "format {version}");
        assert_eq!(upgraded["impostor"]["view_light_scale"], scale, "format {version}");
        assert_eq!(upgraded["far_needle_color"], inspect["far_needle_color"]);
    }

    // The flat generator: every group its own prototype.
    let flat = dir.path().join("flat.conifer");
    let output = conifer(&[
        "bake",
        "--preset",
        "eastern-white-pine",
        "--age",
        "young",
        "--needles",
        "20000",
        "--flat",
        "--no-line-calibration",
        "-o",
        flat.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let flat_inspect = json(&conifer(&["inspect", flat.to_str().unwrap(), "--json"]));
    assert!(flat_inspect["line_calibration"].is_null());
    assert_eq!(flat_inspect["prototypes"], flat_inspect["groups"]);
    assert_eq!(flat_inspect["prototype_needles"], flat_inspect["needles"]);
    assert!(flat_inspect["bytes"].as_u64().unwrap() > 4 * inspect["bytes"].as_u64().unwrap());

    // A format 2 record: read as it is, rewritten in format 6 with the same cuts.
    let old = dir.path().join("old.conifer");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/format2-scots-pine.conifer"),
        &old,
    )
    .unwrap();
    let path = old.to_str().unwrap();
    assert_eq!(
        json(&conifer(&["inspect", path, "--json"]))["format_version"].as_u64(),
        Some(2)
    );
    let cuts = |path: &str| -> Vec<serde_json::Value> {
        ["0.3", "3", "30", "300"]
            .iter()
            .map(|d| json(&conifer(&["cut", path, "--distance", d, "--json"])))
            .collect()
    };
    let before = cuts(path);
    assert!(json(&conifer(&["inspect", path, "--json"]))["line_calibration"].is_null());
    let output = conifer(&["upgrade", path]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stderr).contains(&format!("format 2 → {FORMAT_VERSION}")));
    let upgraded = json(&conifer(&["inspect", path, "--json"]));
    assert_eq!(upgraded["format_version"].as_u64(), Some(u64::from(FORMAT_VERSION)));
    assert!(
        upgraded["line_calibration"]["scales"].is_array(),
        "upgrade calibrates the lines"
    );
    // The same cuts; only the opacity moves with the radii's quantization,
    // and the lines the GPU processes with the band limits (which follow
    // the rounded-up errors).
    let opacity = |cut: &mut serde_json::Value| cut.as_object_mut().unwrap().remove("mean_original_line_opacity");
    for (mut after, mut then) in cuts(path).into_iter().zip(before) {
        for cut in [&mut after, &mut then] {
            let processed = cut.as_object_mut().unwrap().remove("gpu_lines_processed").unwrap();
            assert!(processed.as_u64() >= cut["line_segments"].as_u64());
        }
        match (
            opacity(&mut after).and_then(|o| o.as_f64()),
            opacity(&mut then).and_then(|o| o.as_f64()),
        ) {
            (Some(a), Some(b)) => assert!((a / b - 1.0).abs() < 5e-4, "opacity {a} vs {b}"),
            (a, b) => assert_eq!(a, b),
        }
        assert_eq!(after, then);
    }
    let output = conifer(&["upgrade", path]);
    assert!(String::from_utf8_lossy(&output.stderr).contains(&format!("already format {FORMAT_VERSION}")));

    // Not a record: an error naming the file, and the file is untouched.
    let junk = dir.path().join("junk.conifer");
    std::fs::write(&junk, b"not a record at all").unwrap();
    assert_fails_naming(&conifer(&["upgrade", junk.to_str().unwrap()]), "junk.conifer");
    assert_eq!(std::fs::read(&junk).unwrap(), b"not a record at all");
}

/// `--calibration-elevation`: `upgrade` calibrates a current record's
/// lines again on request (level views give back the bake's table exactly,
/// views from ±11° another), and an elevation outside 0–90° is refused by
/// `bake` and `upgrade` alike with nothing written.
#[test]
fn lines_calibrate_from_above_and_below_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let record = baked(dir.path(), "norway-spruce", "4000");
    let path = record.to_str().unwrap();
    let scales = |path: &str| json(&conifer(&["inspect", path, "--json"]))["line_calibration"]["scales"].clone();
    let level = scales(path);
    assert!(level.is_array());
    let output = conifer(&["upgrade", path, "--calibration-elevation", "0"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(scales(path), level);
    let output = conifer(&["upgrade", path, "--calibration-elevation", "11"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let tilted = scales(path);
    assert!(tilted.is_array() && tilted != level, "{tilted} against {level}");

    let bytes = std::fs::read(&record).unwrap();
    for bad in ["90", "-1", "NaN", "inf"] {
        assert_fails_naming(
            &conifer(&["upgrade", path, &format!("--calibration-elevation={bad}")]),
            "--calibration-elevation",
        );
        let out = dir.path().join("refused.conifer");
        assert_fails_naming(
            &conifer(&[
                "bake",
                "--preset",
                "norway-spruce",
                "--age",
                "young",
                "--needles",
                "1000",
                &format!("--calibration-elevation={bad}"),
                "-o",
                out.to_str().unwrap(),
            ]),
            "--calibration-elevation",
        );
        assert!(!out.exists());
    }
    assert_fails_naming(
        &conifer(&["upgrade", path, "--calibration-elevation", "5", "--no-line-calibration"]),
        "--calibration-elevation",
    );
    assert_eq!(std::fs::read(&record).unwrap(), bytes);
}

#[test]
fn mature_presets_are_the_default_and_bad_ages_and_counts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fir.conifer");
    let path = out.to_str().unwrap();
    let output = conifer(&["bake", "--preset", "silver-fir", "--needles", "60000", "-o", path]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let inspect = json(&conifer(&["inspect", path, "--json"]));
    let needles = inspect["needles"].as_u64().unwrap();
    assert!((57_000..=63_000).contains(&needles), "{needles}");
    // A mature tree's needles are widened to keep its crown: far wider
    // than a young fir's 0.9–1.2 mm.
    let radius = inspect["radius"]["median"].as_f64().unwrap();
    assert!(radius > 0.003, "median radius {radius}");
    let cut = json(&conifer(&["cut", path, "--distance", "0.5", "--json"]));
    assert_eq!(cut["needles_covered"].as_u64(), Some(needles));
    for (args, named) in [
        (vec!["--age", "old"], "old"),
        (vec!["--needles", "0"], "needle count above 0"),
    ] {
        let mut all = vec!["bake", "--preset", "silver-fir", "-o", path];
        all.extend(args);
        assert_fails_naming(&conifer(&all), named);
    }
}

/// `conifer render --wind --frames`: an animated PNG whose frames sway
/// (the wind's clock runs 1/fps a frame), and one still in calm.
#[cfg(feature = "plugin")]
#[test]
fn render_in_wind_writes_an_animated_png() {
    let dir = tempfile::tempdir().unwrap();
    let file = baked(dir.path(), "norway-spruce", "4000");
    let apng = dir.path().join("sway.png");
    let report = json(&conifer(&[
        "render",
        file.to_str().unwrap(),
        "--distance",
        "5",
        "--size",
        "96x96",
        "--wind",
        "4",
        "--frames",
        "3",
        "--fps",
        "2",
        "-o",
        apng.to_str().unwrap(),
    ]));
    assert_eq!(
        (report["frames"].as_u64(), report["wind"].as_f64()),
        (Some(3), Some(4.0))
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&apng).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    assert_eq!(reader.info().animation_control.map(|a| a.num_frames), Some(3));
    let mut frames = Vec::new();
    for _ in 0..3 {
        let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
        reader.next_frame(&mut buffer).unwrap();
        frames.push(buffer);
    }
    // Half a second apart in a strong wind: the tree moved.
    for pair in frames.windows(2) {
        let changed = pair[0].chunks(4).zip(pair[1].chunks(4)).filter(|(a, b)| a != b).count();
        assert!(changed > 20, "{changed} pixels changed");
    }
    // A still: one frame, a plain PNG.
    let still = dir.path().join("still.png");
    json(&conifer(&[
        "render",
        file.to_str().unwrap(),
        "--distance",
        "5",
        "--size",
        "96x96",
        "-o",
        still.to_str().unwrap(),
    ]));
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&still).unwrap()));
    assert!(decoder.read_info().unwrap().info().animation_control.is_none());
}
