//! Any bytes given to the record decoder: an error or a record whose cuts
//! cover every needle once, never a panic.
//!
//! An odd first byte makes the rest the payload of a well-formed header
//! (magic, version, length and checksum filled in), so the fuzzer reaches
//! the payload decoder and the record's invariant checks instead of
//! stopping at the checksum. Both views are decoded: the tree of prototypes
//! (its direct cut must equal its flattened record's cut) and the flat
//! record; each must encode (format 4) and decode again to itself quantized,
//! unless it holds what format 4 cannot (a format 3 record with a needle
//! beyond 65 km or an error above 100 km: a typed error). The tree of
//! prototypes' compact GPU layout (`CompactSpecies::build_placed`: placed
//! prototypes, or flat) is built too: an error or a layout whose draws
//! stand for every needle once at every probe error.
#![no_main]

use bevy_conifer_lod::model::file::{FORMAT_VERSION, MAGIC};
use bevy_conifer_lod::model::file::RecordError;
use bevy_conifer_lod::model::compact::{CompactSpecies, threshold_code};
use bevy_conifer_lod::model::{
    PrototypeRecord, decode_prototype_record, decode_record, encode_prototype_record, encode_record,
};
use libfuzzer_sys::fuzz_target;

const PROBES: [f32; 6] = [0.0, 1e-4, 1e-2, 1.0, 1e3, f32::INFINITY];

fuzz_target!(|data: &[u8]| {
    let bytes = match data.split_first() {
        Some((first, payload)) if first & 1 == 1 => {
            let mut bytes = MAGIC.to_vec();
            bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
            bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
            bytes.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
            bytes.extend_from_slice(payload);
            bytes
        }
        _ => data.to_vec(),
    };
    if let Ok(prototypes) = decode_prototype_record(&bytes) {
        let flat = prototypes.flatten().expect("a decoded tree of prototypes flattens");
        for e in PROBES {
            let cut = prototypes.cut(e).sorted();
            assert_eq!(cut, flat.cut(e).sorted());
            assert!(flat.coverage(&cut).iter().all(|&c| c == 1));
        }
        if let Ok(compact) = CompactSpecies::build_placed(&prototypes) {
            if !compact.placements.is_empty() {
                for e in PROBES {
                    let (drawn, _) = compact.placed_drawn(&prototypes, threshold_code(e), e, threshold_code);
                    assert!(flat.coverage(&drawn).iter().all(|&c| c == 1), "placed draws at e = {e}");
                }
            }
        }
        match encode_prototype_record(&prototypes) {
            Ok(again) => assert_eq!(
                decode_prototype_record(&again).expect("and decodes again"),
                prototypes.quantized().expect("it quantized when encoded")
            ),
            Err(RecordError::Invalid(_)) => {}
            Err(other) => panic!("a decoded record fails to encode: {other}"),
        }
    }
    if let Ok(record) = decode_record(&bytes) {
        for e in PROBES {
            let cut = record.cut(e);
            assert!(record.coverage(&cut).iter().all(|&c| c == 1));
        }
        match encode_record(&record) {
            Ok(again) => {
                let quantized = PrototypeRecord::from_flat(&record)
                    .and_then(|p| p.quantized())
                    .and_then(|p| p.flatten())
                    .expect("it quantized when encoded");
                assert_eq!(decode_record(&again).expect("and decodes again"), quantized);
            }
            Err(RecordError::Invalid(_)) => {}
            Err(other) => panic!("a decoded record fails to encode: {other}"),
        }
    }
});
