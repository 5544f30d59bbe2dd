//! Writing result files so that no work is lost: every file is written to a temporary file
//! beside it and renamed over the target ([`write_atomic`]), so a failed write (a full disk, a
//! file-size limit, an interrupt) leaves the old file or none, never a truncated one; and output
//! paths are checked before a long computation ([`check_writable`]). Imports nothing of the
//! crate.

use std::io::Write;
use std::path::{Path, PathBuf};

/// The temporary file beside `path` that [`write_atomic`] writes first. It keeps `path`'s
/// extension last, for writers that choose the format by it (plotters).
fn temporary(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "output".into());
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp{ext}", std::process::id()))
}

/// Runs `write`, which writes a whole file at the path it is given, on a temporary file beside
/// `path`, then renames it over `path`: for writers that take a path, not a stream (plotters'
/// backends). On any error the temporary file is removed and `path` is as it was.
pub fn write_atomic_path<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
    io_err: impl FnOnce(std::io::Error) -> E,
) -> Result<(), E> {
    let tmp = temporary(path);
    let result = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(io_err));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Writes `bytes` to `path` atomically: to a temporary file in the same folder, synced, then
/// renamed over `path`. On any error the temporary file is removed and `path` is as it was.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// [`write_atomic`] with a writer: `fill` writes the contents (buffered).
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let tmp = temporary(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Checks, before any work, that a file can be written at `path`: its folder exists and takes
/// a new file, and `path` is not a folder. Writes and removes a temporary file.
pub fn check_writable(path: &Path) -> std::io::Result<()> {
    if path.is_dir() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "is a folder",
        ));
    }
    let tmp = temporary(path);
    std::fs::File::create(&tmp)?;
    std::fs::remove_file(&tmp)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.json");
        write_atomic(&p, b"good").unwrap();
        let err = write_atomic_with(&p, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(err.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"good");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(check_writable(&p).is_ok());
        assert!(check_writable(dir.path()).is_err());
        assert!(check_writable(&dir.path().join("no/such/folder/x.json")).is_err());
    }

    #[test]
    fn a_failed_path_writer_keeps_the_old_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("map.png");
        std::fs::write(&p, b"old picture").unwrap();
        let failed: Result<(), String> = write_atomic_path(
            &p,
            |tmp| {
                assert_eq!(tmp.extension().unwrap(), "png");
                std::fs::write(tmp, b"half").unwrap();
                Err("drawing failed".into())
            },
            |e| e.to_string(),
        );
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"old picture");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let done: Result<(), String> = write_atomic_path(
            &p,
            |tmp| std::fs::write(tmp, b"new").map_err(|e| e.to_string()),
            |e| e.to_string(),
        );
        assert!(done.is_ok());
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
    }
}
