//! Atomic file writes: a reader (or a resumed job) never sees a half-written file.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::SensorError;

/// Writes `bytes` to a temporary file beside `path`, syncs it, then renames it over `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SensorError> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// Like [`write_atomic`] without the sync: a killed process still leaves the old file or the
/// whole new one, but after a power cut the new file may be empty or short. For files a reader
/// checks (see [`png_is_complete`]) and many of them, where a sync each costs more than the
/// encoding.
pub fn write_atomic_unsynced(path: &Path, bytes: &[u8]) -> Result<(), SensorError> {
    write_file(path, false, |f| f.write_all(bytes))
}

/// Encodes an RGB image as PNG, with fast compression: camera frames are noisy and barely
/// compress, and a generator or a frame loop writes many.
pub fn encode_png_rgb(img: &image::RgbImage) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(img.len() / 2);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Up)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .expect("in-memory PNG encode");
    out
}

/// Whether a PNG file ends with its `IEND` chunk: a cheap check that it was written whole.
pub fn png_is_complete(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    const IEND: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xae, 0x42, 0x60, 0x82];
    let tail = (|| {
        let mut f = std::fs::File::open(path)?;
        if f.metadata()?.len() < 8 + 25 + 12 {
            return Ok::<_, std::io::Error>(None);
        }
        f.seek(SeekFrom::End(-12))?;
        let mut tail = [0u8; 12];
        f.read_exact(&mut tail)?;
        Ok(Some(tail))
    })();
    matches!(tail, Ok(Some(t)) if t == IEND)
}

/// Like [`write_atomic`], with the content produced by `fill`.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> Result<(), SensorError> {
    write_file(path, true, fill)
}

fn write_file(
    path: &Path,
    sync: bool,
    fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>,
) -> Result<(), SensorError> {
    let tmp = temp_path(path);
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        fill(&mut file)?;
        if sync {
            file.sync_all()?;
        }
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(SensorError::io(path, e));
    }
    Ok(())
}

/// The temporary name used while `path` is written: same folder (so rename is atomic),
/// unique per process, ending in `.tmp` so that cleanup can recognise leftovers.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
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
        let bytes = crate::DepthMap::zeros(8).to_png_um();
        write_atomic_unsynced(&path, &bytes).unwrap();
        assert!(png_is_complete(&path));
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        assert!(!png_is_complete(&path));
        std::fs::write(&path, b"").unwrap();
        assert!(!png_is_complete(&path));
        assert!(!png_is_complete(&dir.path().join("missing.png")));
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
}
