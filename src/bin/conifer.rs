//! `conifer`: bake, inspect, cut and preview conifer LOD records.
//!
//! ```text
//! conifer bake --preset scots-pine --seed 3 -o pine.conifer
//! conifer inspect pine.conifer --json
//! conifer cut pine.conifer --distance 30 --json
//! conifer preview pine.conifer --distance 30 -o pine.png
//! ```
//!
//! Errors go to stderr with a non-zero exit status and name the file and the
//! problem.

use std::process::ExitCode;

/// Counts the heap, for the memory figures of `conifer bench`.
#[global_allocator]
static HEAP: bevy_conifer_lod::cli::heap::CountingAllocator = bevy_conifer_lod::cli::heap::CountingAllocator;

fn main() -> ExitCode {
    match bevy_conifer_lod::cli::run(std::env::args_os()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
