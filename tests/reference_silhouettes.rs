//! What `conifer eval`'s reference draws, checked on the CPU: every needle
//! a capped cylinder and every wood segment a cone, in the eval camera's
//! perspective. The reference's covered pixels (its mean coverage over the
//! tree's box, in the JSON a run of `conifer eval` wrote) equal those of
//! the pieces' perspective silhouettes sampled on the CPU
//! (`look::SampleBits`, needles with their end caps at their slant,
//! `PieceEnds::Capped`).
//!
//! The same silhouettes seen orthographically, as the line calibration and
//! the impostor bake see them, cover less at 12 m wherever the crown's
//! front hides its back: perspective magnifies the front (the young Norway
//! spruce and eastern white pine, about 5 %), which an orthographic
//! measure cannot see. Without their caps (as strips) the needles cover
//! less still; the crown impostor's texels hold the capped orthographic
//! silhouettes' coverage.

use bevy_conifer_lod::model::file::decode_record;
use bevy_conifer_lod::model::look::{PieceEnds, SampleBits};
use bevy_conifer_lod::model::record::LodRecord;
use glam::{Vec2, Vec3};

/// Samples per pixel along each axis.
const SAMPLES: f32 = 32.0;

/// Pixels `record`'s silhouettes cover in a `size`-pixel square picture
/// with a vertical field of view of `fov_degrees`, the camera `distance`
/// metres from the crown's centre on `+z` looking at it (as `conifer eval`
/// places it), in perspective or orthographic at that distance's scale;
/// needles with their caps or, `flat`, as strips.
fn covered_pixels(
    record: &LodRecord,
    size: u32,
    fov_degrees: f32,
    distance: f32,
    perspective: bool,
    flat: bool,
) -> f64 {
    let eye = record.crown_center() + Vec3::Z * distance;
    let focal = 0.5 * size as f32 / (0.5 * fov_degrees.to_radians()).tan();
    let half = 0.5 * size as f32;
    // Sample units and the metres-to-samples scale at `p`'s depth.
    let project = |p: Vec3| {
        let q = p - eye;
        let depth = if perspective { -q.z } else { distance };
        let scale = focal / depth * SAMPLES;
        (
            Vec2::new(half * SAMPLES + q.x * scale, half * SAMPLES - q.y * scale),
            scale,
        )
    };
    let side = size * SAMPLES as u32;
    let mut bits = SampleBits::new(side, side);
    for n in &record.needles {
        let ((a, scale_a), (b, scale_b)) = (project(n.base), project(n.tip));
        let view = if perspective {
            0.5 * (n.base + n.tip) - eye
        } else {
            Vec3::Z
        };
        let ends = if flat {
            PieceEnds::Flat
        } else {
            PieceEnds::of_cylinder(n.tip - n.base, view)
        };
        bits.stamp(a, b, n.radius * scale_a, n.radius * scale_b, ends);
    }
    for w in &record.wood {
        let ((a, scale_a), (b, scale_b)) = (project(w.start), project(w.end));
        bits.stamp(a, b, w.start_radius * scale_a, w.end_radius * scale_b, PieceEnds::Round);
    }
    bits.count_set() as f64 / f64::from(SAMPLES * SAMPLES)
}

#[test]
fn the_references_pixels_are_its_capped_cylinders_in_perspective() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    for tree in ["norway-spruce", "scots-pine", "eastern-white-pine", "lawson-cypress"] {
        let record = decode_record(&std::fs::read(root.join(format!("assets/trees/{tree}.conifer"))).unwrap()).unwrap();
        let json: serde_json::Value = serde_json::from_slice(
            &std::fs::read(root.join(format!("docs/eval/capped-silhouettes/{tree}-front.json"))).unwrap(),
        )
        .unwrap();
        let size = json["height"].as_u64().unwrap() as u32;
        assert_eq!(json["width"].as_u64(), Some(u64::from(size)));
        let fov = json["fov_deg"].as_f64().unwrap() as f32;
        for distance in json["reference"]["distances"].as_array().unwrap() {
            let at = distance["distance"].as_f64().unwrap() as f32;
            let area = |b: &serde_json::Value| {
                let side = |k: &str| b[k].as_i64().unwrap();
                ((side("x1") - side("x0")) * (side("y1") - side("y0"))) as f64
            };
            let reference = distance["mean_coverage"].as_f64().unwrap() * area(&distance["screen_box"]);
            let perspective = covered_pixels(&record, size, fov, at, true, false);
            let orthographic = covered_pixels(&record, size, fov, at, false, false);
            let strips = covered_pixels(&record, size, fov, at, false, true);
            // The impostor's texels of the view from the front, summed.
            let impostor = record.impostor.as_ref().unwrap();
            let pixel = 2.0 * at * (0.5 * fov.to_radians()).tan() / size as f32;
            let texels: f32 = impostor.coverage_grid(0).coverage.iter().sum();
            let texels = f64::from(texels * (impostor.texel / pixel).powi(2));
            println!(
                "{tree} at {at} m: reference {reference:.1} px; silhouettes {perspective:.1} in perspective, \
                 {orthographic:.1} orthographic ({strips:.1} without the caps); impostor's texels {texels:.2}"
            );
            // The impostor holds the orthographic silhouettes' coverage.
            assert!((texels / orthographic - 1.0).abs() < 0.02, "{tree} at {at} m");
            // Within 1 % and a quarter pixel (the reference's alpha is 8-bit).
            assert!(
                (perspective - reference).abs() < 0.01 * reference + 0.25,
                "{tree} at {at} m"
            );
            if at < 20.0 && (tree == "norway-spruce" || tree == "eastern-white-pine") {
                assert!(perspective > 1.03 * orthographic, "{tree} at {at} m");
            }
            // The caps add to every tree, most to the cypress's short leaves.
            assert!(orthographic > strips, "{tree} at {at} m");
            if tree == "lawson-cypress" {
                assert!(orthographic > 1.05 * strips, "{tree} at {at} m");
            }
        }
    }
}
