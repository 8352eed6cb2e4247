//! How the needles a crown shows are lit, against how its impostor lights
//! them: for each record and each of `conifer eval`'s suns, the Lambert
//! factor averaged over every needle by projected area (what the impostor
//! texels' shares are fitted to), over what the views show (each sample lit
//! at the normal of the needle nearest the camera there) and as the
//! impostor's texels light it ([`CrownImpostor::view_lambert`]), averaged
//! over the impostor's views; and the impostor's light times the record's
//! view light scale at that sun ([`CrownImpostor::view_light_scale`]: what
//! the plugin draws) over what the views show. Used in the README's "The far crown lit by
//! the needles it shows".
//!
//! ```text
//! cargo run --release --no-default-features --example visible_light -- RECORD...
//! ```
//!
//! [`CrownImpostor::view_lambert`]: bevy_conifer_lod::model::impostor::CrownImpostor::view_lambert
//! [`CrownImpostor::view_light_scale`]: bevy_conifer_lod::model::impostor::CrownImpostor::view_light_scale

use bevy_conifer_lod::model::read_prototype_record;
use glam::Vec3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        return Err("usage: visible_light RECORD...".into());
    }
    // `conifer eval`'s suns in the view's frame (x right, y up, z toward
    // the camera): `EvalSun::transform`, the camera on +z.
    let low = 15f32.to_radians();
    let suns = [
        ("front", Vec3::new(4.0, 8.0, 6.0).normalize()),
        ("side", Vec3::new(low.cos(), low.sin(), 0.0)),
        ("back", Vec3::new(0.0, low.sin(), -low.cos())),
    ];
    println!(
        "| record | sun | every needle | needles seen | impostor | impostor / seen | shares of the seen | their / seen | scaled impostor / seen |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for path in paths {
        let record = read_prototype_record(std::path::Path::new(&path))?;
        let impostor = record.impostor.as_deref().ok_or("the record has no crown impostor")?;
        let needles = record.placed_needles();
        let scale = impostor.view_light_scale.unwrap_or_default();
        for (name, sun) in suns {
            let (mut sums, mut views) = ([0.0f64; 4], 0u32);
            for view in 0..impostor.views {
                if let Some(lambert) = impostor.view_lambert(view, &record.wood, &needles, sun) {
                    sums[0] += f64::from(lambert.all_needles);
                    sums[1] += f64::from(lambert.seen_needles);
                    sums[2] += f64::from(lambert.impostor);
                    sums[3] += f64::from(lambert.shares_of_seen);
                    views += 1;
                }
            }
            let [all, seen, texels, fitted] = sums.map(|s| s / f64::from(views.max(1)));
            println!(
                "| {} | {name} | {all:.4} | {seen:.4} | {texels:.4} | {:.3} | {fitted:.4} | {:.3} | {:.3} |",
                record.name,
                texels / seen,
                fitted / seen,
                texels * f64::from(scale.at(sun)) / seen
            );
        }
    }
    Ok(())
}
