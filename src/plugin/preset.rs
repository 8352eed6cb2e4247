//! Species from the procedural presets, with no asset files: baked on a
//! background task at load and cached on disk, so the next start reads the
//! record back in milliseconds.

use super::asset::{ConiferLoadError, ConiferSpecies};
use crate::generate::{Preset, PresetParseError};
use crate::model::file::{decode_prototype_record, write_prototype_record};
use crate::model::{BakeError, PrototypeRecord};
use bevy::ecs::system::SystemParam;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::tasks::AsyncComputeTaskPool;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Where baked presets are kept between runs.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum PresetCache {
    /// The platform's user cache directory, under `bevy_conifer_lod/presets`:
    /// `$XDG_CACHE_HOME` or `~/.cache` on Linux, `~/Library/Caches` on
    /// macOS, `%LOCALAPPDATA%` on Windows; no cache where none is known
    /// (e.g. the web).
    #[default]
    Platform,
    /// This directory (created when first written).
    Directory(PathBuf),
    /// Bake every preset at every start.
    Off,
}

impl PresetCache {
    /// The directory baked presets are read from and written to, if any.
    pub fn directory(&self) -> Option<PathBuf> {
        match self {
            PresetCache::Platform => platform_cache_dir().map(|dir| dir.join("bevy_conifer_lod").join("presets")),
            PresetCache::Directory(dir) => Some(dir.clone()),
            PresetCache::Off => None,
        }
    }
}

fn platform_cache_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    if cfg!(target_os = "windows") {
        var("LOCALAPPDATA")
    } else if cfg!(target_os = "macos") {
        var("HOME").map(|home| home.join("Library").join("Caches"))
    } else if cfg!(target_family = "unix") {
        var("XDG_CACHE_HOME").or_else(|| var("HOME").map(|home| home.join(".cache")))
    } else {
        None
    }
}

/// Why a preset species did not load. Bevy logs it once (naming the
/// preset) and trees of its handle are simply not drawn.
#[derive(Debug, thiserror::Error)]
pub enum PresetLoadError {
    /// The text does not name a preset.
    #[error("conifer preset `{text}`: {source}")]
    Parse {
        /// The text given to [`ConiferPresets::load_named`].
        text: String,
        /// What is wrong with it.
        source: PresetParseError,
    },
    /// The bake failed (e.g. a needle count of 0).
    #[error("conifer preset `{preset}` did not bake: {source}")]
    Bake {
        /// The preset.
        preset: Preset,
        /// Why.
        source: BakeError,
    },
    /// The baked record does not make a species (it does not fit the GPU
    /// layout: far too many needles).
    #[error("conifer preset `{preset}`: {source}; ask for fewer needles")]
    Species {
        /// The preset.
        preset: Preset,
        /// Why.
        source: ConiferLoadError,
    },
}

/// The presets asked for so far and where their bakes are cached.
#[derive(Resource, Debug)]
pub(crate) struct PresetStore {
    cache: Option<PathBuf>,
    handles: HashMap<Preset, Handle<ConiferSpecies>>,
}

impl PresetStore {
    pub(crate) fn new(cache: &PresetCache) -> Self {
        Self {
            cache: cache.directory(),
            handles: HashMap::default(),
        }
    }
}

/// Loads species from the procedural presets, with no asset files:
///
/// ```no_run
/// use bevy::prelude::*;
/// use bevy_conifer_lod::generate::{Preset, Species};
/// use bevy_conifer_lod::prelude::*;
///
/// fn setup(mut commands: Commands, mut presets: ConiferPresets) {
///     let spruce = presets.load(Preset::new(Species::NorwaySpruce).with_seed(3));
///     let pine = presets.load_named("scots-pine?seed=1");
///     commands.spawn((ConiferFoliage(spruce), Transform::from_xyz(0.0, 0.0, -20.0)));
///     commands.spawn((ConiferFoliage(pine), Transform::from_xyz(6.0, 0.0, -24.0)));
/// }
/// ```
///
/// The handle is returned at once; the tree is grown and baked on a
/// background task (Bevy's async compute pool, the bake's merges on a
/// rayon pool one thread smaller than the machine, so frames keep a core)
/// and drawn from the frame its species arrives. The bake is written to
/// the [`PresetCache`] (atomically: a crash leaves no half file) and read
/// back on the next start; a cached file that no longer decodes is baked
/// again. The same preset asked for twice gives the same handle. Its load
/// state is Bevy's ([`AssetServer::load_state`]); a failure is logged once
/// by Bevy as a [`PresetLoadError`].
#[derive(SystemParam)]
pub struct ConiferPresets<'w> {
    server: Res<'w, AssetServer>,
    store: ResMut<'w, PresetStore>,
}

impl ConiferPresets<'_> {
    /// The species of `preset`, baked (or read from the cache) in the
    /// background.
    pub fn load(&mut self, preset: impl Into<Preset>) -> Handle<ConiferSpecies> {
        let preset = preset.into();
        if let Some(handle) = self.store.handles.get(&preset) {
            return handle.clone();
        }
        let cache = self.store.cache.clone();
        let task = AsyncComputeTaskPool::get().spawn(async move { load_preset(preset, cache.as_deref()) });
        let handle = self.server.add_async(task);
        self.store.handles.insert(preset, handle.clone());
        handle
    }

    /// The species of a preset given as text (`norway-spruce?seed=3`, see
    /// [`Preset`]), e.g. from a level file. Text that names no preset gives
    /// a handle whose load fails with [`PresetLoadError::Parse`], which
    /// lists the presets.
    pub fn load_named(&mut self, text: &str) -> Handle<ConiferSpecies> {
        match text.parse::<Preset>() {
            Ok(preset) => self.load(preset),
            Err(source) => {
                let text = text.to_owned();
                self.server
                    .add_async(async move { Err::<ConiferSpecies, _>(PresetLoadError::Parse { text, source }) })
            }
        }
    }
}

/// The species of `preset`: from `cache` if a valid bake is there, else
/// baked (and written there). Blocks; runs on a background task.
pub fn load_preset(preset: Preset, cache: Option<&Path>) -> Result<ConiferSpecies, PresetLoadError> {
    let species = |record: &PrototypeRecord| {
        ConiferSpecies::from_prototype_record(record).map_err(|source| PresetLoadError::Species { preset, source })
    };
    let path = cache.map(|dir| dir.join(cache_file_name(&preset)));
    if let Some(path) = &path {
        match std::fs::read(path) {
            Ok(bytes) => match decode_prototype_record(&bytes) {
                Ok(record) => return species(&record),
                Err(error) => warn!(
                    "re-baking conifer preset `{preset}`: its cache {} is unreadable ({error})",
                    path.display()
                ),
            },
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => {}
            Err(error) => warn!(
                "re-baking conifer preset `{preset}`: cannot read {} ({error})",
                path.display()
            ),
        }
    }
    let record = match bake_pool() {
        Some(pool) => pool.install(|| preset.bake()),
        None => preset.bake(),
    }
    .map_err(|source| PresetLoadError::Bake { preset, source })?;
    if let Some(path) = &path {
        let written = std::fs::create_dir_all(path.parent().unwrap_or(Path::new(".")))
            .map_err(crate::model::RecordError::from)
            .and_then(|()| write_prototype_record(&record, path));
        if let Err(error) = written {
            warn!(
                "conifer preset `{preset}` is not cached: cannot write {} ({error})",
                path.display()
            );
        }
    }
    species(&record)
}

/// The cache file of `preset`: its file stem with the generator's
/// fingerprint, so a changed generator or format bakes anew.
pub fn cache_file_name(preset: &Preset) -> String {
    format!("{}-{:016x}.conifer", preset.file_stem(), preset.fingerprint())
}

/// The rayon pool preset bakes run on: one thread fewer than the machine
/// has (at least one), at the lowest scheduling priority where the OS
/// sets it per thread (Linux), so a bake never takes a core from the
/// frame's threads;
/// `None` where no thread could be started (the bake then runs on the
/// calling task).
fn bake_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get().saturating_sub(1).max(1));
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("conifer-bake-{i}"))
            .start_handler(|_| lower_this_thread_priority())
            .build()
            .ok()
    })
    .as_ref()
}

/// Gives the calling thread the lowest scheduling priority (nice 19): it
/// then runs on what the frame's threads leave.
#[cfg(any(target_os = "linux", target_os = "android"))]
fn lower_this_thread_priority() {
    // SAFETY: `setpriority` takes no pointers; on Linux `PRIO_PROCESS`
    // with `who = 0` changes the calling thread only (threads are tasks).
    // A failure leaves the priority as it was, which is harmless.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, 19);
    }
}

/// Elsewhere the priority is per process, and lowering it would slow the
/// game: the bake pool's size alone leaves the frame a core.
#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn lower_this_thread_priority() {}
