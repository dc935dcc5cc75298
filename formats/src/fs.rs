//! Atomic file and folder writes: a reader (or a resumed job) never sees a half-written file or
//! half a folder.

use std::io::Write;
use std::path::{Path, PathBuf};

/// An I/O failure with the path it happened on.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {source}")]
pub struct FsError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

impl FsError {
    pub fn new(path: &Path, source: std::io::Error) -> Self {
        FsError { path: path.to_path_buf(), source }
    }
}

/// SHA-256 of `bytes` as lowercase hex (what `sha256sum` prints): a bundle's files and a
/// labelled row's inputs are recorded by it.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// Writes `bytes` to a temporary file beside `path`, syncs it, then renames it over `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FsError> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// Like [`write_atomic`] without the sync: a killed process still leaves the old file or the
/// whole new one, but after a power cut the new file may be empty or short. For files a reader
/// checks (see [`png_is_complete`]) and many of them, where a sync each costs more than the
/// encoding.
pub fn write_atomic_unsynced(path: &Path, bytes: &[u8]) -> Result<(), FsError> {
    write_file(path, false, |f| f.write_all(bytes))
}

/// Like [`write_atomic`], with the content produced by `fill`.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> Result<(), FsError> {
    write_file(path, true, fill)
}

fn write_file(
    path: &Path,
    sync: bool,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> Result<(), FsError> {
    let tmp = temp_path(path);
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        injected_failure(path)?;
        fill(&mut file)?;
        if sync {
            file.sync_all()?;
        }
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(FsError::new(path, e));
    }
    Ok(())
}

/// Test hook standing in for a full disk: with `DENSETACT_FAIL_WRITES` set to a piece of a path,
/// every atomic write to a path containing it fails as a full disk does (ENOSPC). Tests of the
/// commands use it to check that a failing write stops them as an I/O error.
pub const FAIL_WRITES_ENV: &str = "DENSETACT_FAIL_WRITES";

fn injected_failure(path: &Path) -> std::io::Result<()> {
    static PATTERN: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    let pattern = PATTERN.get_or_init(|| std::env::var(FAIL_WRITES_ENV).ok().filter(|p| !p.is_empty()));
    match pattern {
        Some(p) if path.to_string_lossy().contains(p.as_str()) => {
            Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "No space left on device (injected)"))
        }
        _ => Ok(()),
    }
}

/// The temporary name used while `path` is written: same folder (so rename is atomic),
/// unique per process, ending in `.tmp` so that cleanup can recognise leftovers.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Whether a file name is one [`temp_path`] makes (`.NAME.PID.tmp`): what a write killed before
/// its rename leaves behind.
pub fn is_temporary(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".tmp")
}

/// Removes the temporary files a killed run left in `dir` ([`is_temporary`]).
pub fn remove_temporaries(dir: &Path) -> Result<(), FsError> {
    for entry in std::fs::read_dir(dir).map_err(|e| FsError::new(dir, e))? {
        let path = entry.map_err(|e| FsError::new(dir, e))?.path();
        if path.file_name().is_some_and(|n| is_temporary(&n.to_string_lossy())) {
            std::fs::remove_file(&path).map_err(|e| FsError::new(&path, e))?;
        }
    }
    Ok(())
}

/// A PNG's last chunk, `IEND` (empty, with its CRC).
const PNG_IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xae, 0x42, 0x60, 0x82];
/// A JPEG's end-of-image marker.
const JPEG_EOI: [u8; 2] = [0xff, 0xd9];
/// The smallest PNG: signature, `IHDR`, `IEND`.
const PNG_MIN_LEN: u64 = 8 + 25 + 12;

/// The last `N` bytes of the file at `path` if it has at least `min_len` bytes.
fn file_tail<const N: usize>(path: &Path, min_len: u64) -> Option<[u8; N]> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path).ok()?;
    if f.metadata().ok()?.len() < min_len.max(N as u64) {
        return None;
    }
    f.seek(SeekFrom::End(-(N as i64))).ok()?;
    let mut tail = [0u8; N];
    f.read_exact(&mut tail).ok()?;
    Some(tail)
}

/// Whether a PNG file ends with its `IEND` chunk: a cheap check that it was written whole.
pub fn png_is_complete(path: &Path) -> bool {
    file_tail::<12>(path, PNG_MIN_LEN) == Some(PNG_IEND)
}

/// Whether a JPEG file ends with its end-of-image marker: a cheap check that it was written whole.
pub fn jpeg_is_complete(path: &Path) -> bool {
    file_tail::<2>(path, 4) == Some(JPEG_EOI)
}

/// Whether `bytes` are a whole PNG or JPEG (by signature, then end marker): a file another
/// program is still writing is not.
pub fn image_bytes_complete(bytes: &[u8]) -> bool {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        return bytes.len() as u64 >= PNG_MIN_LEN && bytes.ends_with(&PNG_IEND);
    }
    bytes.starts_with(&[0xff, 0xd8]) && bytes.len() >= 4 && bytes.ends_with(&JPEG_EOI)
}

/// Writes several files so that either all of them are replaced or none: each is written to a
/// temporary file first, and only when every one is written are they renamed into place.
pub fn write_files_atomic(files: &[(&Path, &[u8])]) -> Result<(), FsError> {
    let mut written: Vec<(PathBuf, &Path)> = Vec::new();
    for (path, bytes) in files {
        let tmp = temp_path(path);
        let result = (|| {
            let mut f = std::fs::File::create(&tmp)?;
            f.write_all(bytes)?;
            f.sync_all()
        })();
        if let Err(e) = result {
            let _ = std::fs::remove_file(&tmp);
            for (t, _) in &written {
                let _ = std::fs::remove_file(t);
            }
            return Err(FsError::new(path, e));
        }
        written.push((tmp, path));
    }
    for (tmp, path) in &written {
        std::fs::rename(tmp, path).map_err(|e| FsError::new(path, e))?;
    }
    Ok(())
}

/// Writes a whole folder atomically: `fill` writes into a temporary folder beside `dir`, which
/// then replaces `dir` (the old one is renamed away first and removed last). A failed `fill`
/// leaves `dir` as it was and removes the temporary folder.
pub fn write_dir_atomic<E: From<FsError>>(dir: &Path, fill: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), E> {
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let tmp = dir.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| FsError::new(&tmp, e))?;
    let result = fill(&tmp).and_then(|()| {
        let old = dir.with_file_name(format!(".{name}.{}.old", std::process::id()));
        if dir.exists() {
            std::fs::rename(dir, &old).map_err(|e| FsError::new(dir, e))?;
        }
        std::fs::rename(&tmp, dir).map_err(|e| FsError::new(dir, e))?;
        let _ = std::fs::remove_dir_all(&old);
        Ok(())
    });
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replaces_whole_file_and_leaves_no_temp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"first version, longer").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn complete_pngs_are_told_from_cut_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        let bytes = sensor::DepthMap::zeros(8).to_png_um();
        write_atomic_unsynced(&path, &bytes).unwrap();
        assert!(png_is_complete(&path));
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        assert!(!png_is_complete(&path));
        std::fs::write(&path, b"").unwrap();
        assert!(!png_is_complete(&path));
        assert!(!png_is_complete(&dir.path().join("missing.png")));

        // The same in memory, and for JPEG; a cut JPEG or one file's bytes under another's
        // signature is not whole.
        assert!(image_bytes_complete(&bytes));
        assert!(!image_bytes_complete(&bytes[..bytes.len() - 1]));
        let jpeg = sensor::frame::encode_jpeg_rgb(&image::RgbImage::new(16, 16), 90);
        assert!(image_bytes_complete(&jpeg));
        assert!(!image_bytes_complete(&jpeg[..jpeg.len() - 1]));
        assert!(!image_bytes_complete(&jpeg[2..]));
        std::fs::write(&path, &jpeg).unwrap();
        assert!(jpeg_is_complete(&path) && !png_is_complete(&path));
    }

    #[test]
    fn failed_fill_keeps_old_content() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"kept").unwrap();
        let err = write_atomic_with(&path, |_| Err(std::io::Error::other("disk full"))).unwrap_err();
        assert!(err.to_string().contains("a.txt"));
        assert_eq!(std::fs::read(&path).unwrap(), b"kept");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn several_files_are_written_all_or_none() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        write_files_atomic(&[(&a, b"1"), (&b, b"2")]).unwrap();
        assert_eq!((std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap()), (b"1".to_vec(), b"2".to_vec()));
        // The second cannot be written (its folder is missing): the first keeps its old content.
        let bad = dir.path().join("missing/c");
        assert!(write_files_atomic(&[(&a, b"new"), (&bad, b"3")]).is_err());
        assert_eq!(std::fs::read(&a).unwrap(), b"1");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, "no temporary file is left");
    }

    #[test]
    fn folders_are_replaced_whole_or_not_at_all() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        let write = |text: &'static str| write_dir_atomic(&dir, |tmp| write_atomic(&tmp.join("f"), text.as_bytes()));
        write("one").unwrap();
        write("two").unwrap();
        assert_eq!(std::fs::read(dir.join("f")).unwrap(), b"two");
        let failed: Result<(), FsError> = write_dir_atomic(&dir, |tmp| {
            write_atomic(&tmp.join("f"), b"three")?;
            Err(FsError::new(tmp, std::io::Error::other("no space")))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(dir.join("f")).unwrap(), b"two");
        // Nothing but the folder itself is left beside it.
        assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 1);
    }
}
