//! Depth images in TIFF, read as the BOP toolkit reads them
//! (`imageio.imread(path).astype(np.float32)`): ITODD's 16-bit grey TIFFs,
//! and float TIFFs (32- or 64-bit) or 8/32-bit integer ones, whatever the
//! sensor wrote. The `image` crate decodes no float grey image, so the
//! `tiff` crate (which `image` itself uses) reads them here.

use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::ColorType;

use crate::error::{Error, Result};
use crate::observation::{png_size, MAX_IMAGE_SIDE};

/// Whether `path` names a TIFF (by extension, as BOP's file layout does).
pub fn is_tiff(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
}

/// Opens a TIFF's decoder on a regular file (a FIFO without a writer would
/// block the open for ever) and checks its size.
fn open(path: &Path) -> Result<(Decoder<BufReader<std::fs::File>>, u32, u32)> {
    let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(bad("not a regular file (an image is read from a file, not a pipe or device)".into()));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut dec = Decoder::new(BufReader::new(file)).map_err(|e| bad(e.to_string()))?;
    let (w, h) = dec.dimensions().map_err(|e| bad(e.to_string()))?;
    if w == 0 || h == 0 || w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(bad(format!("image is {w}x{h}; 1 to {MAX_IMAGE_SIDE} pixels a side are read")));
    }
    Ok((dec, w, h))
}

/// The size of a depth image from its header: TIFF or PNG.
pub fn depth_size(path: &Path) -> Result<(u32, u32)> {
    if is_tiff(path) {
        open(path).map(|(_, w, h)| (w, h))
    } else {
        png_size(path)
    }
}

/// A single-channel TIFF's values as f32 (rounded to nearest, as numpy's
/// `astype(np.float32)`), with its size. NaN and negative values, which the
/// toolkit's depth tests (`> 0`) treat as no measurement, become 0; an
/// infinite depth is an error.
pub fn read_tiff_depth(path: &Path) -> Result<(u32, u32, Vec<f32>)> {
    let bad = |reason: String| Error::BadImage { path: path.to_path_buf(), reason };
    let (mut dec, w, h) = open(path)?;
    match dec.colortype().map_err(|e| bad(e.to_string()))? {
        ColorType::Gray(_) => {}
        other => return Err(bad(format!("depth must be a single-channel image, this TIFF is {other:?}"))),
    }
    let values: Vec<f32> = match dec.read_image().map_err(|e| bad(e.to_string()))? {
        DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::I8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::F32(v) => v,
        DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        _ => return Err(bad("depth samples of 16-bit floats or 64-bit integers are not read (8, 16 or 32-bit integers, 32 or 64-bit floats are)".into())),
    };
    if values.len() != w as usize * h as usize {
        return Err(bad(format!("{} samples for a {w}x{h} image", values.len())));
    }
    if let Some(n) = Some(values.iter().filter(|v| v.is_infinite() && **v > 0.0).count()).filter(|&n| n > 0) {
        return Err(bad(format!("{n} pixels hold an infinite depth (0, NaN or a negative value marks a pixel without measurement)")));
    }
    Ok((w, h, values.into_iter().map(|v| if v > 0.0 { v } else { 0.0 }).collect()))
}
