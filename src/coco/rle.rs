//! COCO run-length encoded masks, as pycocotools stores them: runs of
//! alternating background and object pixels (background first) down the
//! columns, left to right (column-major), either as a list of counts or as
//! COCO's compressed string (6-bit characters from `'0'`, 5 bits of value
//! each, counts after the third as differences from the one two before).
//!
//! Written from the format's definition (pycocotools' `maskApi.c` is the
//! reference for the byte layout and for IoU); no crate reads it.

/// A mask of `h × w` pixels as column-major runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rle {
    pub h: u32,
    pub w: u32,
    /// Run lengths, background first; they sum to `h × w`.
    pub counts: Vec<u32>,
}

impl Rle {
    /// Encodes a row-major mask of `w × h` pixels.
    pub fn from_mask(mask: &[bool], w: u32, h: u32) -> Rle {
        debug_assert_eq!(mask.len(), w as usize * h as usize);
        let (w_, h_) = (w as usize, h as usize);
        let mut counts = Vec::new();
        let (mut current, mut run) = (false, 0u32);
        for x in 0..w_ {
            for y in 0..h_ {
                let v = mask[y * w_ + x];
                if v != current {
                    counts.push(run);
                    current = v;
                    run = 0;
                }
                run += 1;
            }
        }
        counts.push(run);
        Rle { h, w, counts }
    }

    /// Takes uncompressed counts (COCO's `{"counts": [...], "size": [h, w]}`),
    /// checking that they cover the image exactly: pycocotools does not,
    /// and counts that fall short or run over give areas and overlaps of
    /// pixels that are not in the image.
    pub fn from_counts(counts: Vec<u32>, h: u32, w: u32) -> Result<Rle, String> {
        let sum: u64 = counts.iter().map(|&c| c as u64).sum();
        let n = h as u64 * w as u64;
        if sum != n {
            return Err(format!("the run lengths sum to {sum}, not to the mask's {h} x {w} = {n} pixels"));
        }
        Ok(Rle { h, w, counts })
    }

    /// Decodes COCO's compressed string (pycocotools' `rleFrString`).
    pub fn from_compressed(s: &str, h: u32, w: u32) -> Result<Rle, String> {
        let bytes = s.as_bytes();
        let mut counts: Vec<u32> = Vec::with_capacity(bytes.len() / 2 + 1);
        let mut p = 0;
        while p < bytes.len() {
            let (mut x, mut k) = (0i64, 0u32);
            loop {
                let Some(&b) = bytes.get(p) else {
                    return Err(format!("the string ends inside a count (at character {p})"));
                };
                if !(48..48 + 64).contains(&b) {
                    let c = s[p..].chars().next().unwrap_or('?');
                    return Err(format!("{c:?} at byte {p} is not of COCO's RLE alphabet ('0' to 'o')"));
                }
                if k >= 7 {
                    return Err(format!("a count at character {p} has more than 7 characters (over 2^35)"));
                }
                let c = (b - 48) as i64;
                x |= (c & 0x1f) << (5 * k);
                p += 1;
                k += 1;
                if c & 0x20 == 0 {
                    if c & 0x10 != 0 {
                        x |= -1i64 << (5 * k);
                    }
                    break;
                }
            }
            if counts.len() > 2 {
                x += counts[counts.len() - 2] as i64;
            }
            let c = u32::try_from(x).map_err(|_| format!("count {} decodes to {x}, outside 0..2^32", counts.len()))?;
            counts.push(c);
        }
        Rle::from_counts(counts, h, w)
    }

    /// COCO's compressed string of these counts (pycocotools' `rleToString`).
    pub fn to_compressed(&self) -> String {
        let mut s = Vec::new();
        for (i, &c) in self.counts.iter().enumerate() {
            let mut x = c as i64;
            if i > 2 {
                x -= self.counts[i - 2] as i64;
            }
            loop {
                let mut ch = x & 0x1f;
                x >>= 5;
                let more = if ch & 0x10 != 0 { x != -1 } else { x != 0 };
                if more {
                    ch |= 0x20;
                }
                s.push((ch + 48) as u8);
                if !more {
                    break;
                }
            }
        }
        String::from_utf8(s).expect("ASCII")
    }

    /// Object pixels: the sum of the odd runs.
    pub fn area(&self) -> u64 {
        self.counts.iter().skip(1).step_by(2).map(|&c| c as u64).sum()
    }

    /// Object pixels in both masks (same size), by walking both run lists
    /// at once.
    pub fn intersection(&self, other: &Rle) -> u64 {
        let (a, b) = (&self.counts, &other.counts);
        let (mut i, mut j) = (0, 0);
        let (mut ra, mut rb) = (a.first().copied().unwrap_or(0) as u64, b.first().copied().unwrap_or(0) as u64);
        let mut n = 0u64;
        while i < a.len() && j < b.len() {
            let step = ra.min(rb);
            if i % 2 == 1 && j % 2 == 1 {
                n += step;
            }
            ra -= step;
            rb -= step;
            while ra == 0 && i < a.len() {
                i += 1;
                ra = a.get(i).copied().unwrap_or(0) as u64;
            }
            while rb == 0 && j < b.len() {
                j += 1;
                rb = b.get(j).copied().unwrap_or(0) as u64;
            }
        }
        n
    }
}

/// pycocotools' mask IoU (`rleIou`) of a detection against a ground-truth
/// mask of the same size: intersection over union, or over the detection's
/// area for a crowd region; 0 when they do not overlap.
pub fn mask_iou(dt: &Rle, gt: &Rle, crowd: bool) -> f64 {
    let i = dt.intersection(gt);
    if i == 0 {
        return 0.0;
    }
    let u = if crowd { dt.area() } else { dt.area() + gt.area() - i };
    i as f64 / u as f64
}

/// pycocotools' box IoU (`bbIou`) of `[x, y, w, h]` boxes, in its order
/// of f64 operations.
pub fn bbox_iou(d: &[f64; 4], g: &[f64; 4], crowd: bool) -> f64 {
    let w = (d[2] + d[0]).min(g[2] + g[0]) - d[0].max(g[0]);
    if w <= 0.0 {
        return 0.0;
    }
    let h = (d[3] + d[1]).min(g[3] + g[1]) - d[1].max(g[1]);
    if h <= 0.0 {
        return 0.0;
    }
    let i = w * h;
    let da = d[2] * d[3];
    let u = if crowd { da } else { da + g[2] * g[3] - i };
    i / u
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(w: u32, h: u32, f: impl Fn(u32, u32) -> bool) -> Vec<bool> {
        (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| f(x, y)).collect()
    }

    #[test]
    fn runs_go_down_the_columns() {
        // 3 x 2, object at (1, 0) and (1, 1) and (2, 1): column-major
        // 0 0 | 1 1 | 0 1 -> runs 2, 2, 1, 1.
        let m = mask(3, 2, |x, y| x == 1 || (x == 2 && y == 1));
        let r = Rle::from_mask(&m, 3, 2);
        assert_eq!(r.counts, vec![2, 2, 1, 1]);
        assert_eq!(r.area(), 3);
        // A mask starting with the object begins with an empty background run.
        assert_eq!(Rle::from_mask(&[true, false], 2, 1).counts, vec![0, 1, 1]);
    }

    #[test]
    fn compressed_strings_round_trip_and_match_pycocotools() {
        // pycocotools.mask.encode of a 4x4 mask with a 2x2 object at
        // rows 1-2, columns 1-2: counts [5, 2, 2, 2, 5] -> b'52203'.
        let m = mask(4, 4, |x, y| (1..3).contains(&x) && (1..3).contains(&y));
        let r = Rle::from_mask(&m, 4, 4);
        assert_eq!(r.counts, vec![5, 2, 2, 2, 5]);
        assert_eq!(r.to_compressed(), "52203");
        assert_eq!(Rle::from_compressed("52203", 4, 4).unwrap(), r);
        // Large counts and negative differences.
        let big = Rle { h: 1000, w: 1000, counts: vec![300_000, 5, 1, 400_000, 299_994] };
        assert_eq!(Rle::from_compressed(&big.to_compressed(), 1000, 1000).unwrap(), big);
    }

    #[test]
    fn bad_strings_and_counts_are_refused() {
        assert!(Rle::from_compressed("52203", 4, 5).unwrap_err().contains("sum"));
        assert!(Rle::from_compressed("5 2", 4, 4).unwrap_err().contains("alphabet"));
        assert!(Rle::from_compressed("o", 4, 4).unwrap_err().contains("ends inside"));
        assert!(Rle::from_compressed("oooooooo0", 4, 4).unwrap_err().contains("7 characters"));
        assert!(Rle::from_counts(vec![3, 4], 2, 2).is_err());
    }

    #[test]
    fn iou_of_masks_and_boxes() {
        let a = Rle::from_mask(&mask(4, 4, |x, _| x < 2), 4, 4);
        let b = Rle::from_mask(&mask(4, 4, |x, _| (1..3).contains(&x)), 4, 4);
        assert_eq!(a.intersection(&b), 4);
        assert_eq!(mask_iou(&a, &b, false), 4.0 / 12.0);
        assert_eq!(mask_iou(&a, &b, true), 4.0 / 8.0);
        let none = Rle::from_mask(&[false; 16], 4, 4);
        assert_eq!(mask_iou(&none, &a, false), 0.0);
        assert_eq!(bbox_iou(&[0.0, 0.0, 2.0, 2.0], &[1.0, 1.0, 2.0, 2.0], false), 1.0 / 7.0);
        assert_eq!(bbox_iou(&[0.0, 0.0, 2.0, 2.0], &[2.0, 0.0, 2.0, 2.0], false), 0.0);
    }
}
