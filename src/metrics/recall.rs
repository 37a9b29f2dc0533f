//! BOP'19 scoring (`eval_calc_scores.py`, `pose_matching.py`,
//! `score.calc_localization_scores`): which ground-truth instances count,
//! greedy matching, pooled recall and average recall.
//!
//! - Per target (image, object, `inst_count`), the `inst_count` most
//!   visible instances of the object are valid (`visib_gt_min = −1`), ties
//!   in visible fraction keep annotation order;
//! - only the `inst_count` highest-scored estimates were kept (ties keep
//!   file order), before any matching;
//! - in falling score order each estimate takes the valid, unmatched
//!   instance with the lowest error, only if error < threshold (strict);
//! - recall = matched / valid instances, pooled over the dataset; AR of an
//!   error type = mean recall over its thresholds (and τ for VSD).

use std::collections::BTreeMap;

/// One estimate's errors against each instance of its object in the image:
/// `(gt_id, errors)` in annotation order, `errors` holding one value per
/// column (error type, or VSD τ), already normalized as the thresholds are.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EstimateErrors {
    pub score: f64,
    pub errors: Vec<(usize, Vec<f64>)>,
}

/// One evaluation target with its kept estimates (already in falling score
/// order) and the instance ids that are valid.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TargetErrors {
    pub obj_id: u32,
    /// gt ids (indices into the image's annotations) that count.
    pub valid: Vec<usize>,
    pub estimates: Vec<EstimateErrors>,
}

/// The valid instances of a target (`visib_gt_min = −1`): the
/// `inst_count` instances of `obj_id` with the highest visible fraction,
/// ties in annotation order (Python's stable sort, descending).
pub fn valid_instances(obj_ids: &[u32], visib_fract: &[f64], obj_id: u32, inst_count: u32) -> Vec<usize> {
    let mut ids: Vec<usize> = (0..obj_ids.len()).filter(|&i| obj_ids[i] == obj_id).collect();
    // partial_cmp: −0 and 0 tie, as in the toolkit (NaN is refused on reading).
    ids.sort_by(|&a, &b| super::falling(visib_fract[a], visib_fract[b]));
    ids.truncate(inst_count as usize);
    ids.sort_unstable();
    ids
}

/// Greedy matching of one target at one threshold on error column
/// `column`; returns how many valid instances were matched.
pub fn matched(target: &TargetErrors, threshold: f64, column: usize) -> usize {
    match_estimates(target, threshold, column).iter().flatten().count()
}

/// Greedy matching of one target at one threshold on error column
/// `column` (`pose_matching.match_poses`): per estimate, in the target's
/// order, the valid instance it took, if any.
pub fn match_estimates(target: &TargetErrors, threshold: f64, column: usize) -> Vec<Option<usize>> {
    let mut taken: Vec<usize> = Vec::new();
    let mut out = Vec::with_capacity(target.estimates.len());
    for e in &target.estimates {
        let mut best: Option<usize> = None;
        let mut best_err = threshold;
        for (gt_id, errs) in &e.errors {
            let gt_id = *gt_id;
            if !target.valid.contains(&gt_id) || taken.contains(&gt_id) {
                continue;
            }
            let err = errs[column];
            if err < best_err {
                best = Some(gt_id);
                best_err = err;
            }
        }
        if let Some(g) = best {
            taken.push(g);
        }
        out.push(best);
    }
    out
}

/// Pooled and per-object recall at one threshold.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recall {
    pub recall: f64,
    pub tp: usize,
    pub targets: usize,
    pub per_object: BTreeMap<u32, f64>,
}

/// Recall of all targets at one threshold on error column `column`.
pub fn recall(targets: &[TargetErrors], threshold: f64, column: usize) -> Recall {
    let mut tp = 0;
    let mut n = 0;
    let mut obj: BTreeMap<u32, (usize, usize)> = BTreeMap::new();
    for t in targets {
        let m = matched(t, threshold, column);
        tp += m;
        n += t.valid.len();
        let o = obj.entry(t.obj_id).or_default();
        o.0 += m;
        o.1 += t.valid.len();
    }
    let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    Recall { recall: ratio(tp, n), tp, targets: n, per_object: obj.into_iter().map(|(o, (a, b))| (o, ratio(a, b))).collect() }
}

/// Thresholds as `numpy.arange(start, stop, step)` makes them:
/// start + i·step (0.05 + 5·0.05 is 0.3 exactly, 0.05·6 is not).
pub fn arange(start: f64, stop: f64, step: f64) -> Vec<f64> {
    let n = ((stop - start) / step).ceil().max(0.0) as usize;
    (0..n).map(|i| start + i as f64 * step).collect()
}

/// The BOP'19 thresholds and VSD τ: 0.05, 0.10, …, 0.50.
pub fn bop19_fractions() -> Vec<f64> {
    arange(0.05, 0.51, 0.05)
}

/// The BOP'19 MSPD thresholds: 5, 10, …, 50 px.
pub fn bop19_mspd_px() -> Vec<f64> {
    arange(5.0, 51.0, 5.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arange_matches_numpy() {
        let a = bop19_fractions();
        assert_eq!(a.len(), 10);
        assert_eq!(a[2], 0.15000000000000002);
        assert_eq!(a[5], 0.3);
        assert_eq!(a[6], 0.35000000000000003);
        assert_ne!(a[5], 0.05 * 6.0);
        assert_eq!(bop19_mspd_px(), vec![5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0]);
    }

    #[test]
    fn most_visible_instances_are_valid_ties_in_order() {
        let objs = [1, 2, 1, 1];
        let vis = [0.5, 0.9, 0.7, 0.7];
        assert_eq!(valid_instances(&objs, &vis, 1, 1), vec![2]);
        assert_eq!(valid_instances(&objs, &vis, 1, 2), vec![2, 3]);
        assert_eq!(valid_instances(&objs, &vis, 1, 5), vec![0, 2, 3]);
        assert_eq!(valid_instances(&objs, &vis, 3, 1), Vec::<usize>::new());
    }

    fn est(score: f64, errors: &[(usize, f64)]) -> EstimateErrors {
        EstimateErrors { score, errors: errors.iter().map(|&(g, e)| (g, vec![e])).collect() }
    }

    #[test]
    fn greedy_matching_is_strict_and_takes_the_lowest_error() {
        // Two instances; the first estimate is closer to instance 1 and takes
        // it, the second gets instance 0.
        let t = TargetErrors {
            obj_id: 1,
            valid: vec![0, 1],
            estimates: vec![est(0.9, &[(0, 0.2), (1, 0.1)]), est(0.8, &[(0, 0.15), (1, 0.05)])],
        };
        assert_eq!(matched(&t, 0.3, 0), 2);
        // Error equal to the threshold does not match.
        assert_eq!(matched(&t, 0.15, 0), 1);
        // An invalid instance cannot be matched.
        let t2 = TargetErrors { valid: vec![0], ..t.clone() };
        assert_eq!(matched(&t2, 0.3, 0), 1);
        let r = recall(&[t, t2], 0.3, 0);
        assert_eq!((r.tp, r.targets), (3, 3));
        assert_eq!(r.recall, 1.0);
    }
}
