//! BOP'24 6D detection scoring (`eval_bop24_pose.py`,
//! `score.calc_pose_detection_scores`, `score.calc_ap`): average precision
//! per object over MSSD and MSPD thresholds.
//!
//! Unlike BOP'19 localization, every estimate of an object in an image is
//! kept (up to a cap per image), every annotated instance can be matched,
//! and instances visible less than [`VISIB_GT_MIN`] neither count nor
//! punish: an estimate matched to one is left out. Per object and
//! threshold the kept estimates, in falling score order, are true
//! positives (matched to a counted instance) or false positives, and AP is
//! the COCO-style mean of the interpolated precision at 101 recall levels.
//! Estimates of objects not annotated in their image are never looked at,
//! as in the toolkit (which computes errors only for the image's objects).

use std::collections::BTreeMap;

use super::pose_error::np_mean;
use super::recall::{match_estimates, TargetErrors};

/// Instances visible less than this fraction are ignored (the toolkit's
/// `visib_gt_min` for detection).
pub const VISIB_GT_MIN: f64 = 0.1;

/// Estimates kept per image (the highest-scored; the toolkit's
/// `max_num_estimates_per_image`, 200 for XYZ-IBD).
pub const MAX_ESTIMATES_PER_IMAGE: usize = 100;

/// The toolkit's cap per image for dataset `name`.
pub fn max_estimates_per_image(name: Option<&str>) -> usize {
    if name == Some("xyzibd") { 200 } else { MAX_ESTIMATES_PER_IMAGE }
}

/// The MSSD thresholds in millimetres of BOP'25's `mssd_mm` score: 2, 4, …, 20.
pub fn bop25_mssd_mm() -> Vec<f64> {
    (1..=10).map(|i| 2.0 * i as f64).collect()
}

/// One (image, object) of a detection evaluation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DetectionTarget {
    /// The object's kept estimates in the image, in falling score order
    /// (ties in file order), with `valid` = every instance of the object.
    pub errors: TargetErrors,
    /// The instances that count: visible at least [`VISIB_GT_MIN`].
    pub counted: Vec<usize>,
    /// Position of the (image, object) in the toolkit's order of
    /// estimates, which breaks ties in score between images.
    pub rank: usize,
}

/// AP per object at one threshold on error column `column`; objects with no
/// counted instance are left out (the toolkit skips them).
pub fn object_ap(targets: &[DetectionTarget], threshold: f64, column: usize) -> BTreeMap<u32, f64> {
    // Per object: its detections and counted instances.
    let mut per_obj: BTreeMap<u32, (Vec<Detection>, usize)> = BTreeMap::new();
    for t in targets {
        let o = per_obj.entry(t.errors.obj_id).or_default();
        o.1 += t.counted.len();
        for (i, (m, e)) in match_estimates(&t.errors, threshold, column).into_iter().zip(&t.errors.estimates).enumerate() {
            match m {
                Some(g) if !t.counted.contains(&g) => {} // matched to an instance that does not count: ignored
                _ => o.0.push((e.score, t.rank, i, m.is_some())),
            }
        }
    }
    per_obj
        .into_iter()
        .filter(|(_, (_, n))| *n > 0)
        .map(|(obj, (mut ests, n))| {
            // Falling score, ties in the toolkit's order (Python's stable sort).
            ests.sort_by(|a, b| super::falling(a.0, b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
            (obj, average_precision_of(&ests.iter().map(|e| e.3).collect::<Vec<_>>(), n))
        })
        .collect()
}

/// A kept estimate at one threshold: (score, its target's rank, its index
/// in the target, true positive).
type Detection = (f64, usize, usize, bool);

/// AP of detections in falling score order (`true` = true positive)
/// against `n_gt` instances.
pub fn average_precision_of(tp: &[bool], n_gt: usize) -> f64 {
    let (mut recalls, mut precisions) = (Vec::with_capacity(tp.len()), Vec::with_capacity(tp.len()));
    let (mut tps, mut fps) = (0usize, 0usize);
    for &t in tp {
        if t { tps += 1 } else { fps += 1 }
        recalls.push(tps as f64 / n_gt as f64);
        precisions.push(tps as f64 / (tps + fps) as f64);
    }
    average_precision(&recalls, &precisions)
}

/// `score.calc_ap`: the mean over recall levels 0, 0.01, …, 1 of the
/// highest precision reached at that recall or above (0 where none is),
/// the curve closed by (0, 0) and (1, 0).
pub fn average_precision(recalls: &[f64], precisions: &[f64]) -> f64 {
    let levels: Vec<f64> = (0..=100).map(|i| if i == 100 { 1.0 } else { i as f64 * 0.01 }).collect();
    let interpolated: Vec<f64> = levels
        .iter()
        .map(|&rt| {
            let inner = recalls.iter().zip(precisions).filter(|(r, _)| **r >= rt).map(|(_, p)| *p);
            // The closing points: (0, 0) counts at rt = 0, (1, 0) always.
            let ends = [(0.0, 0.0), (1.0, 0.0)].into_iter().filter(|(r, _)| *r >= rt).map(|(_, p)| p);
            inner.chain(ends).fold(f64::NEG_INFINITY, f64::max)
        })
        .collect();
    np_mean(&interpolated)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::recall::EstimateErrors;

    #[test]
    fn ap_is_the_toolkits_on_its_own_example() {
        // score.py's __main__: tp = [F, T, T, F, T, F] against 6 instances.
        let tp = [false, true, true, false, true, false];
        // Recall 1/6, 2/6, 3/6 at precision 1/2, 2/3, 3/5: levels 0-0.33 get
        // 2/3 and 0.34-0.50 get 3/5 (0.5 is exactly 3/6), the rest 0.
        let want = (34.0 * (2.0 / 3.0) + 17.0 * 0.6) / 101.0;
        assert!((average_precision_of(&tp, 6) - want).abs() < 1e-12);
        assert_eq!(average_precision_of(&[true, true], 2), 1.0);
        assert_eq!(average_precision_of(&[], 3), 0.0);
        assert_eq!(average_precision_of(&[false, false], 3), 0.0);
    }

    fn est(score: f64, errors: &[(usize, f64)]) -> EstimateErrors {
        EstimateErrors { score, errors: errors.iter().map(|&(g, e)| (g, vec![e])).collect() }
    }

    #[test]
    fn estimates_matched_to_barely_visible_instances_are_ignored() {
        // Instance 0 counts, instance 1 is hidden; the best estimate matches
        // the hidden one and is left out, the second is a true positive,
        // the third a false positive below it.
        let t = DetectionTarget {
            errors: TargetErrors {
                obj_id: 3,
                valid: vec![0, 1],
                estimates: vec![est(0.9, &[(0, 0.4), (1, 0.01)]), est(0.8, &[(0, 0.05), (1, 0.3)]), est(0.7, &[(0, 0.2), (1, 0.2)])],
            },
            counted: vec![0],
            rank: 0,
        };
        let ap = object_ap(std::slice::from_ref(&t), 0.1, 0);
        assert_eq!(ap[&3], 1.0);
        // An object with no counted instance is left out.
        let hidden = DetectionTarget { counted: vec![], ..t };
        assert!(object_ap(&[hidden], 0.1, 0).is_empty());
    }

    #[test]
    fn ties_in_score_keep_the_toolkits_order_across_images() {
        // Same score in two images, one a false positive and one a true
        // positive of two counted instances: whichever the toolkit's order
        // puts first sets the precision up to recall 1/2 (levels 0-0.50).
        let miss = DetectionTarget { errors: TargetErrors { obj_id: 1, valid: vec![0], estimates: vec![est(0.5, &[(0, 0.9)])] }, counted: vec![0], rank: 0 };
        let hit = DetectionTarget { errors: TargetErrors { obj_id: 1, valid: vec![0], estimates: vec![est(0.5, &[(0, 0.01)])] }, counted: vec![0], rank: 1 };
        assert_eq!(object_ap(&[hit.clone(), miss.clone()], 0.1, 0)[&1], 0.5 * 51.0 / 101.0);
        let later = DetectionTarget { rank: 2, ..miss };
        assert_eq!(object_ap(&[later, hit], 0.1, 0)[&1], 51.0 / 101.0);
    }
}
