//! Small file helpers shared by everything that writes results.

use std::io::{Read as _, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Reads a whole input file, refusing it when it holds more than `cap`
/// bytes: a regular file by its size before anything is read, anything
/// else (a pipe, `/dev/fd/N` from a shell's process substitution, a
/// device such as `/dev/zero`) by reading at most `cap + 1` bytes, so an
/// endless stream is an error rather than memory growing until the
/// process is killed. `what` names the input in the error ("pose file").
pub fn read_capped(path: &Path, cap: u64, what: &str) -> Result<Vec<u8>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::InvalidInput(format!("{}: is a folder, expected a {what}", path.display())));
    }
    if meta.is_file() && meta.len() > cap {
        return Err(Error::InvalidInput(format!("{}: a {what} of {} bytes, more than the {} MiB read", path.display(), meta.len(), cap >> 20)));
    }
    let mut bytes = Vec::with_capacity(if meta.is_file() { meta.len() as usize } else { 0 });
    std::fs::File::open(path).and_then(|f| f.take(cap + 1).read_to_end(&mut bytes)).map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > cap {
        return Err(Error::InvalidInput(format!("{}: not a regular file, and more than the {} MiB a {what} may hold (an endless stream?)", path.display(), cap >> 20)));
    }
    Ok(bytes)
}

/// [`read_capped`] for a text (JSON) input: UTF-8, with a leading byte
/// order mark dropped (editors on Windows write one; JSON parsers refuse
/// it as "expected value at line 1 column 1").
pub fn read_to_string_capped(path: &Path, cap: u64, what: &str) -> Result<String> {
    text_of(path, read_capped(path, cap, what)?)
}

/// The bytes read from `path` as UTF-8 text, a leading byte order mark
/// dropped (see [`read_to_string_capped`]).
pub fn text_of(path: &Path, bytes: Vec<u8>) -> Result<String> {
    let mut text = String::from_utf8(bytes).map_err(|e| Error::io(path, std::io::Error::new(std::io::ErrorKind::InvalidData, e.utf8_error())))?;
    if text.starts_with('\u{feff}') {
        text.drain(..'\u{feff}'.len_utf8());
    }
    Ok(text)
}

/// The file a path names once symbolic links are followed (the link's
/// target, made if it does not exist yet): renaming a new file over the
/// path itself would replace the link and leave its target unchanged.
pub fn link_target(path: &Path) -> PathBuf {
    // A device, pipe or folder is used as it is: /dev/stdout on a pipe
    // links to "pipe:[N]", which names no file.
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        return path.to_path_buf();
    }
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        let Ok(target) = std::fs::read_link(&p) else { break };
        p = match p.parent() {
            Some(d) if target.is_relative() => d.join(target),
            _ => target,
        };
    }
    p
}

/// Writes `path` through a temporary file beside it, renamed into place
/// only when everything was written: a full disk or a kill leaves the old
/// file (or none), never half a new one.
///
/// A path that exists and is not a regular file (`/dev/stdout`, a FIFO,
/// `/dev/full`) is written in place: renaming over it would replace the
/// device.
pub fn write_atomically(path: &Path, body: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>) -> Result<()> {
    let path = &link_target(path);
    if path.exists() && !path.is_file() && !path.is_dir() {
        let result = (|| {
            let file = std::fs::OpenOptions::new().write(true).open(path)?;
            let mut w = std::io::BufWriter::new(file);
            body(&mut w)?;
            w.flush()
        })();
        return result.map_err(|e| Error::write(path, e));
    }
    let tmp = temp_beside(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        body(&mut w)?;
        w.flush()?;
        w.get_ref().sync_all()?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::write(path, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::write(path, e)
    })
}

/// Saves an image as PNG through [`write_atomically`]: a full disk or a
/// kill leaves no truncated picture.
pub fn save_png<P, C>(path: &Path, img: &image::ImageBuffer<P, C>) -> Result<()>
where
    P: image::Pixel + image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    write_atomically(path, |w| img.write_to(w, image::ImageFormat::Png).map_err(std::io::Error::other))
}

fn temp_beside(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Checks before long work that `path` can be written: its folder exists
/// and a file can be created there. Through a symbolic link, the folder of
/// the file it names, where [`write_atomically`] writes.
pub fn check_writable(path: &Path) -> Result<()> {
    let path = &link_target(path);
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(Error::InvalidInput(format!("{}: the folder {} does not exist", path.display(), dir.display())));
    }
    if path.is_dir() {
        return Err(Error::InvalidInput(format!("{}: is a folder, expected a file name", path.display())));
    }
    #[cfg(unix)]
    if std::fs::metadata(path).is_ok_and(|m| std::os::unix::fs::FileTypeExt::is_fifo(&m.file_type())) {
        // A FIFO is not opened: opening and closing it for writing hands
        // its reader an end of file, and the real write later blocks for
        // ever with no reader left. Whether this user may write it is
        // asked instead (access(2), which knows owner, group and root).
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(path.as_os_str().as_bytes()).map_err(|e| Error::write(path, std::io::Error::new(std::io::ErrorKind::InvalidInput, e)))?;
        // SAFETY: `c` is a NUL-terminated path that outlives the call.
        if unsafe { libc::access(c.as_ptr(), libc::W_OK) } != 0 {
            return Err(Error::write(path, std::io::Error::last_os_error()));
        }
        return Ok(());
    }
    if path.exists() && !path.is_file() {
        // A device (/dev/null, /dev/full): it must open for writing.
        std::fs::OpenOptions::new().write(true).open(path).map_err(|e| Error::write(path, e))?;
        return Ok(());
    }
    let probe = temp_beside(path);
    std::fs::File::create(&probe).map_err(|e| Error::write(path, e))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}
