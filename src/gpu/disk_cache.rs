//! Compiled pipelines kept on disk between runs (issue 40), so that a small run does not pay the
//! driver's compile again: a `wgpu::PipelineCache` (Vulkan's `VkPipelineCache`) per problem,
//! loaded before the pipelines are built and written back after.
//!
//! - **Where**: `$CBFREACH_CACHE_DIR` (set but empty: no cache), else `$XDG_CACHE_HOME/cbfreach`,
//!   else `$HOME/.cache/cbfreach`, else none; files `pipelines/<key>.bin` under it.
//! - **Key**: a hash of the adapter (vendor, device, name, driver and its version), this
//!   crate's version and every WGSL source compiled with it (the shaders and the generated
//!   problem), so a new driver or shader finds no stale file. A collision is harmless: the
//!   driver keys its entries by shader itself and reads a foreign cache as a miss.
//! - **Never breaks a run**: a file that is truncated, corrupt (its checksum) or from another
//!   driver (wgpu's header, then the driver's own) is dropped and the pipelines are compiled;
//!   a cache that cannot be written is skipped. The outcome is reported ([`Loaded`], [`Saved`]),
//!   never raised.
//! - **Atomic**: written to a file of its own (process id and a counter) and renamed over the
//!   old one, so parallel runs read a whole file or none.
//!
//! How much it saves depends on the driver: NVIDIA's and AMD's keep their own cache too;
//! lavapipe (Mesa 22.3) keeps nothing in a `VkPipelineCache`, and Mesa's shader disk cache
//! (`MESA_SHADER_CACHE_DIR`) already holds its compiled code (docs/design.md §4).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::GpuContext;

/// The variable naming the cache directory (empty: no cache on disk).
pub const CACHE_DIR_ENV: &str = "CBFREACH_CACHE_DIR";

/// Files the directory keeps; the oldest beyond this are removed after a write (each problem,
/// precision and setting of the bound kernels has its own).
const MAX_FILES: usize = 64;

/// The file's own header: magic, payload length, payload checksum.
const MAGIC: &[u8; 8] = b"cbfpipe1";
const HEADER: usize = 24;

/// The cache directory: `$CBFREACH_CACHE_DIR` (empty: none), else the platform's cache
/// directory (`$XDG_CACHE_HOME`, else `$HOME/.cache`) with `cbfreach` under it.
pub fn cache_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name);
    if let Some(dir) = var(CACHE_DIR_ENV) {
        return (!dir.is_empty()).then(|| PathBuf::from(dir));
    }
    let base = var("XDG_CACHE_HOME")
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            var("HOME")
                .filter(|d| !d.is_empty())
                .map(|h| PathBuf::from(h).join(".cache"))
        })?;
    Some(base.join("cbfreach"))
}

/// What was found on disk when the cache was opened.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Loaded {
    /// No directory (or the device has no pipeline caches): compiled, nothing kept.
    Off,
    /// No file for this key yet.
    Missing,
    /// The file's data was handed to the device (bytes); wgpu and the driver may still drop
    /// data they do not recognise as theirs, and compile.
    Read(usize),
    /// The file was unusable and the pipelines were compiled; why.
    Rejected(String),
}

/// What [`DiskCache::save`] did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Saved {
    /// Nothing to write (no cache, or the driver gave no data).
    Off,
    /// The driver's data equals what was read: the file stays.
    Unchanged,
    /// Written (bytes).
    Written(usize),
    /// Could not be written; why (the run goes on).
    Failed(String),
}

/// A pipeline cache for one set of shaders on one device, backed by a file.
pub struct DiskCache {
    path: Option<PathBuf>,
    cache: Option<wgpu::PipelineCache>,
    read: Option<Vec<u8>>,
    loaded: Loaded,
}

impl std::fmt::Debug for DiskCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DiskCache")
            .field("path", &self.path)
            .field("loaded", &self.loaded)
            .finish()
    }
}

/// FNV-1a, 64 bits: the file's checksum and the key (stable across Rust versions, unlike
/// `DefaultHasher`).
fn fnv(parts: &[&[u8]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for part in parts {
        for &b in part.iter().chain(&[0xff]) {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// The file's payload if its header and checksum hold.
fn decode(bytes: &[u8]) -> Result<&[u8], String> {
    if bytes.len() < HEADER || &bytes[..8] != MAGIC {
        return Err("not a cbfreach pipeline cache".into());
    }
    let word = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().unwrap_or([0; 8]));
    let payload = &bytes[HEADER..];
    if word(8) != payload.len() as u64 {
        return Err(format!("truncated: {} of {} bytes", payload.len(), word(8)));
    }
    if word(16) != fnv(&[payload]) {
        return Err("checksum mismatch".into());
    }
    Ok(payload)
}

/// The file holding `payload` (the driver's data): magic `cbfpipe1`, the payload's length and
/// FNV-1a checksum (u64, little-endian), the payload.
pub fn encode(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv(&[payload]).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// A pipeline cache from `data` (none: empty), or the reason the device refused it.
fn create(ctx: &GpuContext, data: Option<&[u8]>) -> Result<wgpu::PipelineCache, String> {
    let device = &ctx.device;
    let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
    // SAFETY: `data` was returned by `PipelineCache::get_data` on an adapter with the same
    // `pipeline_cache_key` (both are in the file's key), as far as a file can show it: its
    // checksum rules out a torn or damaged write; wgpu checks its own header (adapter, driver
    // validation key) and the driver its `VkPipelineCacheHeaderVersionOne` before using it.
    let cache = unsafe {
        device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
            label: Some("cbfreach pipelines"),
            data,
            fallback: true,
        })
    };
    let errors = [
        pollster::block_on(internal.pop()),
        pollster::block_on(validation.pop()),
    ];
    match errors.into_iter().flatten().next() {
        Some(e) => Err(e.to_string()),
        None => Ok(cache),
    }
}

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl DiskCache {
    /// The cache for pipelines compiled from `sources` on `ctx`'s device, read from
    /// [`cache_dir`].
    pub fn open(ctx: &GpuContext, sources: &[&str]) -> DiskCache {
        DiskCache::open_in(ctx, cache_dir().as_deref(), sources)
    }

    /// As [`DiskCache::open`] with the directory given (`None`: no file).
    pub fn open_in(ctx: &GpuContext, dir: Option<&Path>, sources: &[&str]) -> DiskCache {
        let off = DiskCache {
            path: None,
            cache: None,
            read: None,
            loaded: Loaded::Off,
        };
        let supported = ctx.features.contains(wgpu::Features::PIPELINE_CACHE);
        let (Some(dir), Some(adapter_key), true) =
            (dir, wgpu::util::pipeline_cache_key(&ctx.info), supported)
        else {
            return off;
        };
        let i = &ctx.info;
        let mut parts: Vec<&[u8]> = vec![
            adapter_key.as_bytes(),
            i.name.as_bytes(),
            i.driver.as_bytes(),
            i.driver_info.as_bytes(),
            env!("CARGO_PKG_VERSION").as_bytes(),
        ];
        parts.extend(sources.iter().map(|s| s.as_bytes()));
        let path = dir
            .join("pipelines")
            .join(format!("{:016x}.bin", fnv(&parts)));
        let (read, mut loaded) = match std::fs::read(&path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (None, Loaded::Missing),
            Err(e) => (None, Loaded::Rejected(format!("unreadable: {e}"))),
            Ok(bytes) => match decode(&bytes) {
                Ok(payload) => (Some(payload.to_vec()), Loaded::Read(payload.len())),
                Err(why) => (None, Loaded::Rejected(why)),
            },
        };
        let cache = match create(ctx, read.as_deref()) {
            Ok(c) => Some(c),
            Err(why) => {
                loaded = Loaded::Rejected(format!("the device refused it: {why}"));
                create(ctx, None).ok()
            }
        };
        let Some(cache) = cache else { return off };
        DiskCache {
            path: Some(path),
            cache: Some(cache),
            read: read.filter(|_| matches!(loaded, Loaded::Read(_))),
            loaded,
        }
    }

    /// The cache to name in every pipeline descriptor (`None`: compile without one).
    pub fn pipeline_cache(&self) -> Option<&wgpu::PipelineCache> {
        self.cache.as_ref()
    }

    /// What was found on disk.
    pub fn loaded(&self) -> &Loaded {
        &self.loaded
    }

    /// The file (`None`: no cache on disk).
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// Writes the driver's data back, atomically, where it differs from what was read.
    pub fn save(&self) -> Saved {
        let (Some(path), Some(cache)) = (&self.path, &self.cache) else {
            return Saved::Off;
        };
        let Some(data) = cache.get_data() else {
            return Saved::Off;
        };
        if self.read.as_deref() == Some(&data[..]) {
            return Saved::Unchanged;
        }
        match write_atomic(path, &encode(&data)) {
            Ok(()) => {
                prune(path.parent());
                Saved::Written(data.len())
            }
            Err(e) => Saved::Failed(format!("{}: {e}", path.display())),
        }
    }
}

/// `bytes` to `path` through a temporary file in the same directory and a rename.
fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let n = TEMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let temp = path.with_extension(format!("tmp{}-{n}", std::process::id()));
    let written = std::fs::File::create(&temp).and_then(|mut f| f.write_all(bytes));
    let renamed = written.and_then(|()| std::fs::rename(&temp, path));
    if renamed.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    renamed
}

/// Removes the oldest cache files beyond [`MAX_FILES`] (best effort).
fn prune(dir: Option<&Path>) {
    let Some(Ok(entries)) = dir.map(std::fs::read_dir) else {
        return;
    };
    let mut files: Vec<(std::time::SystemTime, PathBuf)> = entries
        .flatten()
        .filter(|e| e.path().extension().is_some_and(|x| x == "bin"))
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .collect();
    if files.len() > MAX_FILES {
        files.sort();
        for (_, p) in &files[..files.len() - MAX_FILES] {
            let _ = std::fs::remove_file(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_checksum_rejects_damage() {
        let file = encode(b"some driver data");
        assert_eq!(decode(&file), Ok(&b"some driver data"[..]));
        assert!(decode(&file[..file.len() - 1]).is_err());
        assert!(decode(&file[..10]).is_err());
        let mut flipped = file.clone();
        flipped[HEADER + 3] ^= 1;
        assert_eq!(decode(&flipped), Err("checksum mismatch".into()));
        assert!(decode(b"").is_err());
    }

    #[test]
    fn key_parts_are_separated() {
        assert_ne!(fnv(&[b"ab", b"c"]), fnv(&[b"a", b"bc"]));
    }
}
