//! Small file helpers shared by everything that writes results.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Writes `path` through a temporary file beside it, renamed into place
/// only when everything was written: a full disk or a kill leaves the old
/// file (or none), never half a new one.
///
/// A path that exists and is not a regular file (`/dev/stdout`, a FIFO,
/// `/dev/full`) is written in place: renaming over it would replace the
/// device.
pub fn write_atomically(path: &Path, body: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>) -> Result<()> {
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

fn temp_beside(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Checks before long work that `path` can be written: its folder exists
/// and a file can be created there.
pub fn check_writable(path: &Path) -> Result<()> {
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
    if path.exists() && !path.is_file() {
        // A device or FIFO: it must open for writing.
        std::fs::OpenOptions::new().write(true).open(path).map_err(|e| Error::write(path, e))?;
        return Ok(());
    }
    let probe = temp_beside(path);
    std::fs::File::create(&probe).map_err(|e| Error::write(path, e))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}
