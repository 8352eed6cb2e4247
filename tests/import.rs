//! The glTF importer and exporter: the Weber–Penn fixture, round trips
//! through our own GLB writer, the group rule on trees with known groups,
//! the glTF features modelling tools write, and bad input.

use bevy_conifer_lod::export::{TreeGlbOptions, encode_cut_glb, encode_tree_glb};
use bevy_conifer_lod::generate::{GenerateOptions, Species, generate};
use bevy_conifer_lod::import::{
    GroupSource, ImportError, ImportOptions, group_agreement, import_gltf, import_gltf_bytes,
};
use bevy_conifer_lod::model::{BakeOptions, bake, decode_record, encode_record};
use glam::Vec3;
use std::path::Path;

const FIXTURE: &str = "../shared/fixtures/small_pine_s0.glb";

fn preset(species: Species, needles: usize) -> bevy_conifer_lod::model::TreeInput {
    generate(
        species,
        &GenerateOptions {
            seed: 2,
            target_needles: Some(needles),
            age: bevy_conifer_lod::generate::Age::Young,
        },
    )
}

#[test]
fn fixture_needles_radii_and_groups() {
    let (tree, report) = import_gltf(Path::new(FIXTURE), &ImportOptions::default()).unwrap();
    // Every needle quad of the `leaves` mesh is found; nothing is skipped.
    assert_eq!(report.needles, 48_607);
    assert_eq!(tree.needles.len(), 48_607);
    assert_eq!(report.skipped.total(), 0);
    assert_eq!(report.needle_primitives.len(), 1);
    // The trunk and branches are kept whole.
    assert_eq!(report.wood_triangles, 60_224);
    assert_eq!(tree.wood_mesh.triangle_count(), 60_224);
    // Radius = half the quad width (3.4 mm quads: 2.7–4.4 mm wide).
    assert!((report.radius.median - 0.001_724).abs() < 2e-5, "{:?}", report.radius);
    assert!(
        report.radius.min > 0.0013 && report.radius.max < 0.0023,
        "{:?}",
        report.radius
    );
    assert!((report.length.median - 0.1724).abs() < 1e-3, "{:?}", report.length);
    // A ~5 m tree.
    let (lo, hi) = tree.needle_bounds().unwrap();
    assert!((4.4..5.0).contains(&(hi.y - lo.y)), "{lo} {hi}");
    // Groups: inferred shoot segments, none above the cap.
    let GroupSource::Inferred(info) = &report.group_source else {
        panic!("{:?}", report.group_source)
    };
    assert!(info.base_spacing > 0.002 && info.base_spacing < 0.003, "{info:?}");
    assert!((300..1500).contains(&report.groups), "{}", report.groups);
    assert!(
        report.group_size.max <= 128.0 && report.group_size.median >= 40.0,
        "{:?}",
        report.group_size
    );
    // The file writes each quad's base edge first: the importer agrees
    // (from geometry alone) for almost every needle.
    let bytes = std::fs::read(FIXTURE).unwrap();
    let first_corner = fixture_first_corners(&bytes);
    let agree = tree
        .needles
        .iter()
        .zip(&first_corner)
        .filter(|(n, c)| n.base.distance(**c) < n.tip.distance(**c))
        .count();
    assert!(agree as f64 > 0.99 * 48_607.0, "base/tip agree for {agree}");
}

/// The first vertex of each quad of the fixture's `leaves` mesh (accessor 0,
/// four vertices a quad), read straight from the GLB.
fn fixture_first_corners(bytes: &[u8]) -> Vec<Vec3> {
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    let bin = &bytes[20 + json_len + 8..];
    let view = &json["bufferViews"][json["accessors"][0]["bufferView"].as_u64().unwrap() as usize];
    let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize;
    let count = json["accessors"][0]["count"].as_u64().unwrap() as usize;
    (0..count / 4)
        .map(|q| {
            let at = offset + q * 4 * 12;
            let f = |k: usize| f32::from_le_bytes(bin[at + 4 * k..at + 4 * k + 4].try_into().unwrap());
            Vec3::new(f(0), f(1), f(2))
        })
        .collect()
}

#[test]
fn fixture_bakes_and_its_wood_survives_the_record_file() {
    let (tree, _) = import_gltf(Path::new(FIXTURE), &ImportOptions::default()).unwrap();
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    assert_eq!(record.needle_count(), 48_607);
    let bytes = encode_record(&record).unwrap();
    let back = decode_record(&bytes).unwrap();
    assert_eq!(back, record);
    assert_eq!(back.wood_mesh.triangle_count(), 60_224);
    // Every cut covers every needle once.
    for e in [0.0005, 0.005, 0.05, 0.5] {
        assert!(back.coverage(&back.cut(e)).iter().all(|&c| c == 1));
    }
}

/// Needles as unordered centerlines, for comparing trees.
fn same_needles(a: &[bevy_conifer_lod::model::Needle], b: &[bevy_conifer_lod::model::Needle]) -> usize {
    a.iter()
        .zip(b)
        .filter(|(x, y)| {
            let ends = x.base.distance(y.base).max(x.tip.distance(y.tip));
            let swapped = x.base.distance(y.tip).max(x.tip.distance(y.base));
            // f32 corners a metre from the origin: widths good to ~0.3 µm.
            ends.min(swapped) < 1e-5 && (x.radius - y.radius).abs() <= 1e-6
        })
        .count()
}

#[test]
fn presets_round_trip_through_glb() {
    for species in Species::ALL {
        let tree = preset(species, 4000);
        for groups in [false, true] {
            let glb = encode_tree_glb(&tree, &TreeGlbOptions { groups });
            let (back, report) = import_gltf_bytes(&glb, None, "rt", &ImportOptions::default()).unwrap();
            assert_eq!(back.needles.len(), tree.needles.len(), "{species} needle count");
            assert_eq!(report.skipped.total(), 0, "{species}");
            assert_eq!(
                same_needles(&tree.needles, &back.needles),
                tree.needles.len(),
                "{species}"
            );
            if groups {
                assert!(matches!(report.group_source, GroupSource::Attribute(_)));
                let truth: Vec<u32> = tree.needles.iter().map(|n| n.group).collect();
                let got: Vec<u32> = back.needles.iter().map(|n| n.group).collect();
                assert_eq!(group_agreement(&truth, &got).adjusted_rand_index, 1.0, "{species}");
            }
            // The normals are the needles' (up to sign: a quad has two sides).
            for (a, b) in tree.needles.iter().zip(&back.needles) {
                assert!(
                    a.normal.dot(b.normal).abs() > 0.999,
                    "{species}: {} vs {}",
                    a.normal,
                    b.normal
                );
            }
            assert!(back.wood_mesh.triangle_count() > 0);
        }
    }
}

#[test]
fn group_rule_on_trees_with_known_groups() {
    // Written without groups, imported back; needles keep the file's order.
    let score = |species: Species| {
        let tree = preset(species, 20_000);
        let glb = encode_tree_glb(&tree, &TreeGlbOptions::default());
        let (back, report) = import_gltf_bytes(&glb, None, "g", &ImportOptions::default()).unwrap();
        assert!(matches!(report.group_source, GroupSource::Inferred(_)));
        let truth: Vec<u32> = tree.needles.iter().map(|n| n.group).collect();
        let got: Vec<u32> = back.needles.iter().map(|n| n.group).collect();
        group_agreement(&truth, &got)
    };
    // Pine fascicles (needles sharing a base point) are found.
    let white_pine = score(Species::EasternWhitePine);
    assert!(white_pine.adjusted_rand_index > 0.99, "{white_pine:?}");
    let scots = score(Species::ScotsPine);
    assert!(scots.purity > 0.99 && scots.adjusted_rand_index > 0.95, "{scots:?}");
    // Spruce shoots interleave (neighbouring shoots' bases are as close as
    // a shoot's own): a base-distance rule mixes neighbouring shoots, and
    // cuts at 128 where the preset cuts at 60. Measured, not hidden.
    let spruce = score(Species::NorwaySpruce);
    assert!(spruce.purity > 0.25 && spruce.completeness > 0.8, "{spruce:?}");
}

// ---- hand-made GLBs: the features modelling tools write ----

/// A GLB from a JSON document and a binary chunk.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

/// `count` needle quads (10 cm × 2 mm, 1 cm apart along x) as positions.
/// Two triangles per quad of [`quad_positions`], as u8 indices.
fn quad_indices_u8(count: u8) -> Vec<u8> {
    (0..count)
        .flat_map(|q| [4 * q, 4 * q + 1, 4 * q + 2, 4 * q, 4 * q + 2, 4 * q + 3])
        .collect()
}

fn quad_positions(count: usize) -> Vec<[f32; 3]> {
    (0..count)
        .flat_map(|k| {
            let x = k as f32 * 0.01;
            [
                [x - 0.001, 0.0, 0.0],
                [x - 0.001, 0.1, 0.0],
                [x + 0.001, 0.1, 0.0],
                [x + 0.001, 0.0, 0.0],
            ]
        })
        .collect()
}

fn f32_bytes(values: impl IntoIterator<Item = f32>) -> Vec<u8> {
    values.into_iter().flat_map(f32::to_le_bytes).collect()
}

fn import(
    bytes: &[u8],
) -> Result<
    (
        bevy_conifer_lod::model::TreeInput,
        bevy_conifer_lod::import::ImportReport,
    ),
    ImportError,
> {
    import_gltf_bytes(bytes, None, "t", &ImportOptions::default())
}

#[test]
fn interleaved_strided_u8_indices_trs_and_instancing() {
    // 3 quads; POSITION and NORMAL interleaved (stride 24); u8 indices;
    // the mesh placed by two nodes: one scaled ×2 and moved, one under a
    // parent with a matrix (translation 5 m in z) and mirrored in x.
    let positions = quad_positions(3);
    let mut bin: Vec<u8> = positions
        .iter()
        .flat_map(|p| f32_bytes([p[0], p[1], p[2], 0.0, 0.0, 1.0]))
        .collect();
    let index_offset = bin.len();
    let indices = quad_indices_u8(3);
    bin.extend_from_slice(&indices);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1]}}],
        "nodes":[{{"name":"Needles.001","mesh":0,"scale":[2,2,2],"translation":[1,0,0]}},
                 {{"children":[2],"matrix":[-1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,5,1]}},
                 {{"name":"needle copy","mesh":0}}],
        "meshes":[{{"name":"shoot","primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},"indices":2}}]}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":12,"type":"VEC3","min":[-1,0,0],"max":[1,1,0]}},
          {{"bufferView":0,"byteOffset":12,"componentType":5126,"count":12,"type":"VEC3"}},
          {{"bufferView":1,"componentType":5121,"count":18,"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":{index_offset},"byteStride":24}},
                       {{"buffer":0,"byteOffset":{index_offset},"byteLength":18}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        bin.len()
    );
    let (tree, report) = import(&glb(&json, &bin)).unwrap();
    assert_eq!(report.needles, 6, "{report:?}");
    assert_eq!(report.needle_primitives.len(), 2);
    // Two placed primitives of 3 needles: one group each.
    assert_eq!(report.group_source, GroupSource::Primitives);
    assert_eq!(report.groups, 2);
    let mut radii: Vec<f32> = tree.needles.iter().map(|n| n.radius).collect();
    radii.sort_by(f32::total_cmp);
    assert!(
        (radii[0] - 0.001).abs() < 1e-6 && (radii[5] - 0.002).abs() < 1e-6,
        "{radii:?}"
    );
    let moved = tree.needles.iter().filter(|n| (n.length() - 0.2).abs() < 1e-5).count();
    assert_eq!(moved, 3);
    assert!(
        tree.needles
            .iter()
            .any(|n| (n.base.z - 5.0).abs() < 1e-5 && n.base.x < 0.0)
    );
}

#[test]
fn u16_and_u32_indices_strips_fans_and_unindexed() {
    let positions = quad_positions(1);
    let pos = f32_bytes(positions.iter().flatten().copied());
    // u16 strip 0,1,3,2 = the quad; u32 fan 0,1,2,3; unindexed: 6 vertices.
    let strip: Vec<u8> = [0u16, 1, 3, 2].iter().flat_map(|i| i.to_le_bytes()).collect();
    let fan: Vec<u8> = [0u32, 1, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect();
    let flat = f32_bytes([0, 1, 2, 0, 2, 3].iter().flat_map(|&i| positions[i]).map(|x| x + 0.5));
    let mut bin = pos.clone();
    let s_at = bin.len();
    bin.extend_from_slice(&strip);
    let f_at = bin.len();
    bin.extend_from_slice(&fan);
    let u_at = bin.len();
    bin.extend_from_slice(&flat);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[0]}},{{"nodes":[1]}}],"scene":1,
        "nodes":[{{"mesh":0}},{{"mesh":0,"name":"leaves"}}],
        "meshes":[{{"primitives":[
            {{"attributes":{{"POSITION":0}},"indices":1,"mode":5}},
            {{"attributes":{{"POSITION":0}},"indices":2,"mode":6}},
            {{"attributes":{{"POSITION":3}}}}]}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-1,0,0],"max":[1,1,0]}},
          {{"bufferView":1,"componentType":5123,"count":4,"type":"SCALAR"}},
          {{"bufferView":2,"componentType":5125,"count":4,"type":"SCALAR"}},
          {{"bufferView":3,"componentType":5126,"count":6,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}}],
        "bufferViews":[{{"buffer":0,"byteLength":48}},{{"buffer":0,"byteOffset":{s_at},"byteLength":8}},
                       {{"buffer":0,"byteOffset":{f_at},"byteLength":16}},{{"buffer":0,"byteOffset":{u_at},"byteLength":72}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        bin.len()
    );
    let (tree, report) = import(&glb(&json, &bin)).unwrap();
    // Scene 1 (the default) places the node named `leaves`: 3 needles.
    assert_eq!(report.needles, 3, "{report:?}");
    for n in &tree.needles {
        assert!(
            (n.radius - 0.001).abs() < 1e-6 && (n.length() - 0.1).abs() < 1e-6,
            "{n:?}"
        );
    }
}

#[test]
fn sparse_accessors_and_group_attributes() {
    // Two quads; a sparse accessor moves the second quad's corners up 1 m;
    // a `_GROUP` float attribute puts them in groups 7 and 9.
    let positions = quad_positions(2);
    let mut bin = f32_bytes(positions.iter().flatten().copied());
    let idx_at = bin.len();
    bin.extend(
        [4u8, 5, 6, 7]
            .iter()
            .flat_map(|&i| [i, 0, 0, 0]) // u32 sparse indices
            .collect::<Vec<u8>>(),
    );
    let val_at = bin.len();
    bin.extend(f32_bytes(positions[4..8].iter().flat_map(|p| [p[0], p[1] + 1.0, p[2]])));
    let grp_at = bin.len();
    bin.extend(f32_bytes([7.0, 7.0, 7.0, 7.0, 9.0, 9.0, 9.0, 9.0]));
    let tri_at = bin.len();
    bin.extend(
        [0u16, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7]
            .iter()
            .flat_map(|i| i.to_le_bytes()),
    );
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"nodes":[{{"mesh":0}}],
        "meshes":[{{"name":"pine needles","primitives":[{{"attributes":{{"POSITION":0,"_GROUP":1}},"indices":2}}]}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":8,"type":"VEC3","min":[-1,0,0],"max":[1,2,0],
            "sparse":{{"count":4,"indices":{{"bufferView":1,"componentType":5125}},"values":{{"bufferView":2}}}}}},
          {{"bufferView":3,"componentType":5126,"count":8,"type":"SCALAR"}},
          {{"bufferView":4,"componentType":5123,"count":12,"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":96}},{{"buffer":0,"byteOffset":{idx_at},"byteLength":16}},
                       {{"buffer":0,"byteOffset":{val_at},"byteLength":48}},{{"buffer":0,"byteOffset":{grp_at},"byteLength":32}},
                       {{"buffer":0,"byteOffset":{tri_at},"byteLength":24}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        bin.len()
    );
    let (tree, report) = import(&glb(&json, &bin)).unwrap();
    assert_eq!(report.needles, 2);
    assert!(matches!(report.group_source, GroupSource::Attribute(_)));
    assert_eq!(report.groups, 2);
    assert!(
        tree.needles.iter().any(|n| n.base.y.min(n.tip.y) > 0.99),
        "sparse values applied"
    );
}

// ---- bad input ----

fn quad_glb_json(count: u64, mode: u32, extra: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"nodes":[{{"mesh":0,"name":"leaves"}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"mode":{mode}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[-1,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5125,"count":{count},"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
        "buffers":[{{"byteLength":72{extra}}}]}}"#
    )
}

fn quad_bin() -> Vec<u8> {
    let mut bin = f32_bytes(quad_positions(1).iter().flatten().copied());
    bin.extend([0u32, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    bin
}

#[test]
fn bad_input_is_a_clear_error() {
    let ok = glb(&quad_glb_json(6, 4, ""), &quad_bin());
    assert_eq!(import(&ok).unwrap().1.needles, 1);

    let message = |bytes: &[u8]| import(bytes).unwrap_err().to_string();
    assert!(message(b"hello, world").contains("not a glTF file"));
    assert!(message(b"").contains("not a glTF file"));
    // Truncated anywhere: header, JSON chunk, binary chunk.
    for len in [3, 11, 30, ok.len() - 40, ok.len() - 1] {
        let m = message(&ok[..len]);
        assert!(m.contains("truncated"), "length {len}: {m}");
    }
    // A 2 G index count in a tiny file: refused before any allocation.
    let huge = glb(&quad_glb_json(2_000_000_000, 4, ""), &quad_bin());
    assert!(huge.len() < 1024);
    let m = message(&huge);
    assert!(m.contains("accessor 1") && m.contains("2000000000"), "{m}");
    // Lines where needles should be.
    let m = message(&glb(&quad_glb_json(6, 1, ""), &quad_bin()));
    assert!(m.contains("LINES") && m.contains("not triangles"), "{m}");
    // No needle-like names.
    let trunk = quad_glb_json(6, 4, "").replace("\"leaves\"", "\"trunk\"");
    let m = message(&glb(&trunk, &quad_bin()));
    assert!(m.contains("no needle geometry") && m.contains("--needles"), "{m}");
    // ...unless named on the command line.
    let named = import_gltf_bytes(
        &glb(&trunk, &quad_bin()),
        None,
        "t",
        &ImportOptions {
            needle_names: vec!["TRUNK".into()],
            ..Default::default()
        },
    );
    assert_eq!(named.unwrap().1.needles, 1);
    // External buffer missing.
    let external = quad_glb_json(6, 4, r#","uri":"missing.bin""#);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tree.gltf");
    std::fs::write(&path, &external).unwrap();
    let m = import_gltf(&path, &ImportOptions::default()).unwrap_err().to_string();
    assert!(
        m.contains("missing external buffer") && m.contains("missing.bin"),
        "{m}"
    );
    // ...and present.
    std::fs::write(dir.path().join("missing.bin"), quad_bin()).unwrap();
    assert_eq!(import_gltf(&path, &ImportOptions::default()).unwrap().1.needles, 1);
    // Malformed JSON, out-of-range references, bad indices, cycles.
    assert!(message(&glb("{\"asset\":", &[])).contains("malformed glTF JSON"));
    let m = message(&glb(
        &quad_glb_json(6, 4, "").replace("\"indices\":1", "\"indices\":9"),
        &quad_bin(),
    ));
    assert!(m.contains("accessor 9 does not exist"), "{m}");
    let mut bad_index = quad_bin();
    bad_index[48] = 200;
    assert!(message(&glb(&quad_glb_json(6, 4, ""), &bad_index)).contains("out of range"));
    let cycle = quad_glb_json(6, 4, "").replace(
        "{\"mesh\":0,\"name\":\"leaves\"}",
        "{\"mesh\":0,\"name\":\"leaves\",\"children\":[1]},{\"children\":[0]}",
    );
    assert!(message(&glb(&cycle, &quad_bin())).contains("cycle"));
    let rooted = cycle.replacen('{', r#"{"scene":0,"scenes":[{"nodes":[0]}],"#, 1);
    assert!(message(&glb(&rooted, &quad_bin())).contains("cycle"));
    // Normalized or odd component types where floats are needed.
    let odd = quad_glb_json(6, 4, "").replace("\"componentType\":5125", "\"componentType\":5126");
    assert!(message(&glb(&odd, &quad_bin())).contains("does not read"));
    // Required extensions we cannot read.
    let draco = quad_glb_json(6, 4, "").replacen('{', r#"{"extensionsRequired":["KHR_draco_mesh_compression"],"#, 1);
    assert!(message(&glb(&draco, &quad_bin())).contains("KHR_draco_mesh_compression"));
    // Only degenerate needles.
    let mut flat = quad_bin();
    for k in 0..12 {
        flat[4 * k..4 * k + 4].copy_from_slice(&0.5f32.to_le_bytes());
    }
    assert!(message(&glb(&quad_glb_json(6, 4, ""), &flat)).contains("no needle-shaped pieces"));
    // A bad scale.
    let scaled = import_gltf_bytes(
        &ok,
        None,
        "t",
        &ImportOptions {
            scale: -1.0,
            ..Default::default()
        },
    );
    assert!(matches!(scaled, Err(ImportError::BadScale(_))));
}

#[test]
fn scale_converts_units() {
    let ok = glb(&quad_glb_json(6, 4, ""), &quad_bin());
    let (tree, _) = import_gltf_bytes(
        &ok,
        None,
        "t",
        &ImportOptions {
            scale: 0.01,
            ..Default::default()
        },
    )
    .unwrap();
    assert!((tree.needles[0].radius - 0.00001).abs() < 1e-9);
    assert!((tree.needles[0].length() - 0.001).abs() < 1e-8);
}

// ---- export ----

#[test]
fn exported_cuts_are_valid_gltf() {
    let tree = preset(Species::EasternWhitePine, 3000);
    let record = bake(&tree, &BakeOptions::default(), &()).unwrap();
    for e in [0.0, 0.0002, 0.002, 0.02, 0.2, 2.0] {
        let (bytes, report) = encode_cut_glb(&record, e, 0.8);
        assert_eq!(report.bytes, bytes.len());
        // The gltf crate's own validation accepts the file.
        let gltf = gltf::Gltf::from_slice(&bytes).unwrap_or_else(|err| panic!("e = {e}: {err}"));
        let bin = gltf.blob.as_deref().unwrap();
        let stats = record.cut_stats(&record.cut(e));
        assert_eq!(report.prisms as u64, stats.prisms);
        assert_eq!(report.prism_triangles as u64, stats.triangles);
        assert_eq!(
            (report.lines_original + report.lines_merged) as u64,
            stats.line_segments
        );
        for mesh in gltf.meshes() {
            for primitive in mesh.primitives() {
                let positions = primitive.get(&gltf::Semantic::Positions).unwrap();
                match mesh.name() {
                    Some("lines") => {
                        assert_eq!(primitive.mode(), gltf::mesh::Mode::Lines);
                        assert_eq!(positions.count() as u64, 2 * stats.line_segments);
                        // Alpha of every line vertex within [0, δ].
                        let color = primitive.get(&gltf::Semantic::Colors(0)).unwrap();
                        let view = color.view().unwrap();
                        let start = view.offset() + color.offset();
                        for k in 0..color.count() {
                            let at = start + 16 * k + 12;
                            let alpha = f32::from_le_bytes(bin[at..at + 4].try_into().unwrap());
                            assert!((0.0..=0.8 + 1e-6).contains(&alpha), "alpha {alpha}");
                        }
                    }
                    Some("prisms") => {
                        let indices = primitive.indices().unwrap();
                        assert_eq!(indices.count() as u64, 3 * stats.triangles);
                    }
                    Some("wood") => assert!(positions.count() > 0),
                    other => panic!("unexpected mesh {other:?}"),
                }
            }
        }
    }
}

#[test]
fn exported_trees_are_valid_gltf_and_the_fixture_exports_with_its_wood() {
    let tree = preset(Species::ScotsPine, 2000);
    let bytes = encode_tree_glb(&tree, &TreeGlbOptions { groups: true });
    let gltf = gltf::Gltf::from_slice(&bytes).unwrap();
    let names: Vec<_> = gltf.meshes().map(|m| m.name().unwrap().to_string()).collect();
    assert_eq!(names, ["needles", "wood"]);

    let (fixture, _) = import_gltf(Path::new(FIXTURE), &ImportOptions::default()).unwrap();
    let record = bake(&fixture, &BakeOptions::default(), &()).unwrap();
    let (bytes, report) = encode_cut_glb(&record, 0.05, 1.0);
    assert_eq!(report.wood_triangles, 60_224);
    gltf::Gltf::from_slice(&bytes).unwrap();
}

#[test]
fn instanced_needle_meshes_become_one_prototype() {
    use bevy_conifer_lod::import::import_gltf_bytes_prototypes;
    use bevy_conifer_lod::model::{BakeOptions, bake, bake_prototypes};
    // One mesh of 3 needle quads placed by six nodes: four rotated, moved
    // and uniformly scaled (one prototype), one scaled unevenly and one
    // mirrored (each a prototype of its own, placed as it is).
    let positions = quad_positions(3);
    let mut bin = f32_bytes(positions.iter().flatten().copied());
    let index_offset = bin.len();
    let indices = quad_indices_u8(3);
    bin.extend_from_slice(&indices);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1,2,3,4,5]}}],
        "nodes":[{{"mesh":0}},
                 {{"mesh":0,"translation":[1,2,3],"rotation":[0,0.3826834,0,0.9238795]}},
                 {{"mesh":0,"translation":[-1,0.5,0],"scale":[1.5,1.5,1.5],"rotation":[0.5,0.5,0.5,0.5]}},
                 {{"mesh":0,"matrix":[0,0,-0.8,0, 0,0.8,0,0, 0.8,0,0,0, 0,1,-2,1]}},
                 {{"mesh":0,"scale":[1,3,1],"translation":[2,0,0]}},
                 {{"mesh":0,"scale":[-1,1,1],"translation":[0,0,2]}}],
        "meshes":[{{"name":"needles","primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":12,"type":"VEC3","min":[-1,0,0],"max":[1,1,0]}},
          {{"bufferView":1,"componentType":5121,"count":18,"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":{index_offset}}},
                       {{"buffer":0,"byteOffset":{index_offset},"byteLength":18}}],
        "buffers":[{{"byteLength":{}}}]}}"#,
        bin.len()
    );
    let bytes = glb(&json, &bin);
    let (tree, flat_report) = import(&bytes).unwrap();
    let (input, report) = import_gltf_bytes_prototypes(&bytes, None, "t", &ImportOptions::default()).unwrap();
    assert_eq!(flat_report.prototypes, 6);
    assert_eq!(report.prototypes, 3, "{report:?}");
    assert_eq!(input.prototypes.len(), 3);
    assert_eq!(input.placements.len(), 6);
    let shared = input.placements[0].prototype;
    assert!(input.placements[..4].iter().all(|p| p.prototype == shared));
    assert!((input.placements[2].scale - 1.5).abs() < 1e-5);
    assert!(input.placements[4].is_identity() && input.placements[5].is_identity());
    // Placed again, the prototypes are the imported needles.
    let placed = input.to_tree();
    assert_eq!(placed.needles.len(), tree.needles.len());
    for (a, b) in placed.needles.iter().zip(&tree.needles) {
        let same = (a.base.distance(b.base) < 1e-5 && a.tip.distance(b.tip) < 1e-5)
            || (a.base.distance(b.tip) < 1e-5 && a.tip.distance(b.base) < 1e-5);
        assert!(same && (a.radius - b.radius).abs() < 1e-6, "{a:?} vs {b:?}");
    }
    // Baked, the record stores 9 needles for 18 and cuts exactly.
    let record = bake_prototypes(&input, &BakeOptions::default(), &()).unwrap();
    assert_eq!(record.prototype_needle_count(), 9);
    let flat = bake(&tree, &BakeOptions::default(), &()).unwrap();
    assert_eq!(record.needle_count(), flat.needle_count() as u64);
    let flattened = record.flatten().unwrap();
    for e in [0.0, 1e-3, 3e-3, 0.05, 10.0] {
        let cut = record.cut(e).sorted();
        assert_eq!(cut, flattened.cut(e).sorted(), "e = {e}");
        assert!(flattened.coverage(&cut).iter().all(|&c| c == 1), "e = {e}");
    }
    assert_eq!(record.cut(0.0).prisms.len(), 18);
}
