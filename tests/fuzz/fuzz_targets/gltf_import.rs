//! Any bytes given to the glTF importer: an error or a tree, never a panic,
//! a hang or an allocation out of proportion to the input.
#![no_main]

use bevy_conifer_lod::import::{ImportOptions, import_gltf_bytes};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((tree, _)) = import_gltf_bytes(data, None, "fuzz", &ImportOptions::default()) {
        assert!(!tree.needles.is_empty());
        assert!(tree.needles.iter().all(|n| n.is_valid()));
        assert!(tree.wood_mesh.is_valid());
    }
});
