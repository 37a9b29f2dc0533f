//! COCO's average precision and recall (pycocotools' `COCOeval` for boxes
//! and masks, in the fork the BOP toolkit installs, MartinSmeyer/cocoapi,
//! which honours the ground truth's `ignore` flag), step for step: the
//! same stable sorts, greedy matching, ignore rules, 101-point precision
//! and numpy's summation order, so that the twelve numbers agree with
//! `eval_bop22_coco.py` to the last bit.

use crate::metrics::falling;
use crate::metrics::pose_error::np_mean;

/// IoU thresholds: `np.linspace(0.5, 0.95, 10)`, computed as numpy does.
pub fn iou_thresholds() -> Vec<f64> {
    linspace(0.5, 0.95, 10)
}

/// Recall levels: `np.linspace(0, 1, 101)`.
pub fn recall_levels() -> Vec<f64> {
    linspace(0.0, 1.0, 101)
}

/// numpy's `linspace` (start + i·step, the last one exactly `stop`).
fn linspace(start: f64, stop: f64, n: usize) -> Vec<f64> {
    let step = (stop - start) / (n - 1) as f64;
    let mut v: Vec<f64> = (0..n).map(|i| i as f64 * step + start).collect();
    v[n - 1] = stop;
    v
}

/// COCO's area ranges (all, small, medium, large), in pixels².
pub const AREA_RANGES: [(f64, f64); 4] = [(0.0, 1e10), (0.0, 1024.0), (1024.0, 9216.0), (9216.0, 1e10)];
/// COCO's detection caps per image and category.
pub const MAX_DETS: [usize; 3] = [1, 10, 100];

/// One ground-truth region of an image and category.
#[derive(Clone, Debug)]
pub struct GtRegion {
    /// Annotation id; 0 counts as "no match" in pycocotools' bookkeeping,
    /// so a detection matched to it counts as a false positive there too.
    pub id: i64,
    pub area: f64,
    pub crowd: bool,
    /// Ignored ground truth (BOP: visible less than 10 %): a detection
    /// matched to it counts for nothing.
    pub ignore: bool,
}

/// One detection of an image and category.
#[derive(Clone, Debug)]
pub struct DtRegion {
    pub score: f64,
    pub area: f64,
}

/// The ground truth and detections of one image and category, in file
/// order, with `iou(d, g)` for detection `d` and ground truth `g`.
pub struct Group<'a> {
    /// Position of the image in COCO's (sorted) image order.
    pub image: usize,
    pub category: u32,
    pub gt: Vec<GtRegion>,
    pub dt: Vec<DtRegion>,
    pub iou: Box<dyn Fn(usize, usize) -> f64 + Send + Sync + 'a>,
}

/// The per-image matching of one group at one area range (`evaluateImg`).
struct ImageEval {
    image: usize,
    /// Scores of the kept detections, highest first.
    scores: Vec<f64>,
    /// Per threshold and detection: matched (to a ground truth with a
    /// non-zero id) and ignored.
    matched: Vec<Vec<bool>>,
    ignored: Vec<Vec<bool>>,
    /// Ground truths not ignored at this area range.
    counted_gt: usize,
}

/// Falling score, stable (`np.argsort(-score, kind='mergesort')`).
fn by_falling_score(dt: &[DtRegion]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..dt.len()).collect();
    order.sort_by(|&a, &b| falling(dt[a].score, dt[b].score));
    order
}

/// A group's kept detections (highest score first, stable, at most 100)
/// and their IoUs with its ground truth in file order (`computeIoU`),
/// computed once for every area range.
struct Scored {
    dt_order: Vec<usize>,
    ious: Vec<Vec<f64>>,
}

fn score_group(g: &Group) -> Scored {
    let dt_order: Vec<usize> = by_falling_score(&g.dt).into_iter().take(MAX_DETS[MAX_DETS.len() - 1]).collect();
    let ious = dt_order.iter().map(|&d| (0..g.gt.len()).map(|gi| (g.iou)(d, gi)).collect()).collect();
    Scored { dt_order, ious }
}

fn evaluate_image(g: &Group, scored: &Scored, range: (f64, f64), thresholds: &[f64]) -> ImageEval {
    let outside = |a: f64| a < range.0 || a > range.1;
    let gt_ignore: Vec<bool> = g.gt.iter().map(|r| r.ignore || outside(r.area)).collect();
    // Ground truth: ignored last, stably; detections: highest score first.
    let mut gt_order: Vec<usize> = (0..g.gt.len()).collect();
    gt_order.sort_by_key(|&i| gt_ignore[i]);
    let dt_order = &scored.dt_order;
    let t_n = thresholds.len();
    let mut gt_match = vec![vec![false; gt_order.len()]; t_n];
    let mut dt_gt: Vec<Vec<Option<usize>>> = vec![vec![None; dt_order.len()]; t_n];
    let mut ignored = vec![vec![false; dt_order.len()]; t_n];
    if !gt_order.is_empty() && !dt_order.is_empty() {
        for (t, &thr) in thresholds.iter().enumerate() {
            for (di, row) in scored.ious.iter().enumerate() {
                let mut best = thr.min(1.0 - 1e-10);
                let mut m: Option<usize> = None;
                for (gi, &gt_index) in gt_order.iter().enumerate() {
                    let gt = &g.gt[gt_index];
                    if gt_match[t][gi] && !gt.crowd {
                        continue;
                    }
                    if let Some(mi) = m {
                        if !gt_ignore[gt_order[mi]] && gt_ignore[gt_index] {
                            break;
                        }
                    }
                    if row[gt_index] < best {
                        continue;
                    }
                    best = row[gt_index];
                    m = Some(gi);
                }
                if let Some(mi) = m {
                    ignored[t][di] = gt_ignore[gt_order[mi]];
                    dt_gt[t][di] = Some(gt_order[mi]);
                    gt_match[t][mi] = true;
                }
            }
        }
    }
    // Unmatched detections outside the area range are ignored.
    let matched: Vec<Vec<bool>> = dt_gt.iter().map(|row| row.iter().map(|m| m.is_some_and(|gi| g.gt[gi].id != 0)).collect()).collect();
    for t in 0..t_n {
        for (di, &d) in dt_order.iter().enumerate() {
            if !matched[t][di] && outside(g.dt[d].area) {
                ignored[t][di] = true;
            }
        }
    }
    ImageEval {
        image: g.image,
        scores: dt_order.iter().map(|&d| g.dt[d].score).collect(),
        matched,
        ignored,
        counted_gt: gt_ignore.iter().filter(|&&i| !i).count(),
    }
}

/// Precision at the 101 recall levels and the final recall of one
/// category, area range and cap, over the images' matchings in image
/// order (`accumulate`); `None` when no ground truth counts.
fn accumulate(evals: &[&ImageEval], max_det: usize, t_n: usize, levels: &[f64]) -> Option<(Vec<Vec<f64>>, Vec<f64>)> {
    let npig: usize = evals.iter().map(|e| e.counted_gt).sum();
    if npig == 0 {
        return None;
    }
    // (score, image position, rank in image) in concatenation order, then
    // a stable sort by falling score.
    let mut entries: Vec<(f64, usize, usize)> = Vec::new();
    for (ei, e) in evals.iter().enumerate() {
        for r in 0..e.scores.len().min(max_det) {
            entries.push((e.scores[r], ei, r));
        }
    }
    entries.sort_by(|a, b| falling(a.0, b.0));
    let mut precision = Vec::with_capacity(t_n);
    let mut recall = Vec::with_capacity(t_n);
    for t in 0..t_n {
        let (mut tp, mut fp) = (0usize, 0usize);
        let mut rc = Vec::with_capacity(entries.len());
        let mut pr = Vec::with_capacity(entries.len());
        for &(_, ei, r) in &entries {
            let e = evals[ei];
            if !e.ignored[t][r] {
                if e.matched[t][r] {
                    tp += 1;
                } else {
                    fp += 1;
                }
            }
            let (tpf, fpf) = (tp as f64, fp as f64);
            rc.push(tpf / npig as f64);
            pr.push(tpf / (fpf + tpf + f64::EPSILON));
        }
        recall.push(rc.last().copied().unwrap_or(0.0));
        for i in (1..pr.len()).rev() {
            if pr[i] > pr[i - 1] {
                pr[i - 1] = pr[i];
            }
        }
        // np.searchsorted(rc, levels, side='left'); levels past the last
        // recall keep precision 0.
        let mut q = vec![0.0; levels.len()];
        let mut i = 0;
        for (ri, &l) in levels.iter().enumerate() {
            while i < rc.len() && rc[i] < l {
                i += 1;
            }
            if i == rc.len() {
                break;
            }
            q[ri] = pr[i];
        }
        precision.push(q);
    }
    Some((precision, recall))
}

/// COCO's twelve summary numbers (`COCOeval.summarize`), −1 where nothing
/// counts, and AP per category (over thresholds and recall levels, all
/// areas, 100 detections).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    /// AP, AP50, AP75, AP_small, AP_medium, AP_large, AR1, AR10, AR100,
    /// AR_small, AR_medium, AR_large.
    pub stats: [f64; 12],
    pub per_category: Vec<(u32, f64)>,
}

/// Names of [`Summary::stats`] as the BOP toolkit writes them.
pub const STAT_NAMES: [&str; 12] =
    ["AP", "AP50", "AP75", "AP_small", "AP_medium", "AP_large", "AR1", "AR10", "AR100", "AR_small", "AR_medium", "AR_large"];

/// Evaluates the groups (`evaluate`, `accumulate`, `summarize`).
/// `categories` are COCO's category ids, sorted.
pub fn summarize(groups: &[Group], categories: &[u32]) -> Summary {
    use rayon::prelude::*;
    let thr = iou_thresholds();
    let levels = recall_levels();
    let (t_n, r_n, k_n, a_n, m_n) = (thr.len(), levels.len(), categories.len(), AREA_RANGES.len(), MAX_DETS.len());
    // precision[t][r][k][a][m] and recall[t][k][a][m], −1 where absent.
    let mut precision = vec![-1.0; t_n * r_n * k_n * a_n * m_n];
    let mut recall = vec![-1.0; t_n * k_n * a_n * m_n];
    let p_at = |t: usize, r: usize, k: usize, a: usize, m: usize| (((t * r_n + r) * k_n + k) * a_n + a) * m_n + m;
    let r_at = |t: usize, k: usize, a: usize, m: usize| ((t * k_n + k) * a_n + a) * m_n + m;
    let scored: Vec<Scored> = groups.par_iter().map(score_group).collect();
    for (a, &range) in AREA_RANGES.iter().enumerate() {
        let evals: Vec<ImageEval> = groups.par_iter().zip(&scored).map(|(g, sc)| evaluate_image(g, sc, range, &thr)).collect();
        for (k, &cat) in categories.iter().enumerate() {
            let mut mine: Vec<&ImageEval> = groups.iter().zip(&evals).filter(|(g, _)| g.category == cat).map(|(_, e)| e).collect();
            mine.sort_by_key(|e| e.image);
            for (m, &max_det) in MAX_DETS.iter().enumerate() {
                if let Some((p, rc)) = accumulate(&mine, max_det, t_n, &levels) {
                    for t in 0..t_n {
                        recall[r_at(t, k, a, m)] = rc[t];
                        for r in 0..r_n {
                            precision[p_at(t, r, k, a, m)] = p[t][r];
                        }
                    }
                }
            }
        }
    }
    let mean_present = |v: Vec<f64>| {
        let v: Vec<f64> = v.into_iter().filter(|&x| x > -1.0).collect();
        if v.is_empty() { -1.0 } else { np_mean(&v) }
    };
    let m100 = m_n - 1;
    let ap = |t_sel: Option<f64>, a: usize| {
        let ts: Vec<usize> = match t_sel {
            None => (0..t_n).collect(),
            Some(x) => (0..t_n).filter(|&t| thr[t] == x).collect(),
        };
        let mut v = Vec::new();
        for &t in &ts {
            for r in 0..r_n {
                for k in 0..k_n {
                    v.push(precision[p_at(t, r, k, a, m100)]);
                }
            }
        }
        mean_present(v)
    };
    let ar = |a: usize, m: usize| {
        let mut v = Vec::new();
        for t in 0..t_n {
            for k in 0..k_n {
                v.push(recall[r_at(t, k, a, m)]);
            }
        }
        mean_present(v)
    };
    let stats = [ap(None, 0), ap(Some(0.5), 0), ap(Some(0.75), 0), ap(None, 1), ap(None, 2), ap(None, 3), ar(0, 0), ar(0, 1), ar(0, 2), ar(1, m100), ar(2, m100), ar(3, m100)];
    let per_category = categories
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            let mut v = Vec::new();
            for t in 0..t_n {
                for r in 0..r_n {
                    v.push(precision[p_at(t, r, k, 0, m100)]);
                }
            }
            (c, mean_present(v))
        })
        .collect();
    Summary { stats, per_category }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds_are_numpys() {
        let t = iou_thresholds();
        assert_eq!(t.len(), 10);
        assert_eq!(t[0], 0.5);
        assert_eq!(t[5], 0.75, "AP75 selects this threshold by equality");
        assert_eq!(t[9], 0.95);
        let r = recall_levels();
        assert_eq!((r.len(), r[1], r[100]), (101, 0.01, 1.0));
    }

    fn group(image: usize, gt: &[(f64, bool)], dt: &[(f64, f64)], iou: Vec<Vec<f64>>) -> Group<'static> {
        Group {
            image,
            category: 1,
            gt: gt.iter().enumerate().map(|(i, &(area, ignore))| GtRegion { id: i as i64 + 1, area, crowd: false, ignore }).collect(),
            dt: dt.iter().map(|&(score, area)| DtRegion { score, area }).collect(),
            iou: Box::new(move |d, g| iou[d][g]),
        }
    }

    #[test]
    fn one_perfect_detection_gives_one() {
        let s = summarize(&[group(0, &[(5000.0, false)], &[(0.9, 5000.0)], vec![vec![1.0]])], &[1]);
        // Precision is tp / (tp + fp + eps), as pycocotools has it: 1 - 2^-52
        // for a single hit.
        assert_eq!(s.stats[0], 1.0 / (1.0 + f64::EPSILON));
        assert_eq!(s.stats[4], s.stats[0], "medium");
        assert_eq!(s.stats[3], -1.0, "no small ground truth");
        assert_eq!(s.stats[8], 1.0);
    }

    #[test]
    fn a_false_positive_ranked_first_halves_early_precision() {
        // Two images: the higher-scored detection misses; the lower one hits.
        let g = [group(0, &[(5000.0, false)], &[(0.5, 5000.0)], vec![vec![0.9]]), group(1, &[], &[(0.8, 5000.0)], vec![])];
        let s = summarize(&g, &[1]);
        // At thresholds up to 0.9 precision is 1/2 at every recall level
        // (interpolated); at 0.95 the hit misses: recall 0.
        let expect = (9.0 * 0.5 * 101.0) / (10.0 * 101.0);
        assert!((s.stats[0] - expect).abs() < 1e-12, "{}", s.stats[0]);
        assert_eq!(s.stats[6], 0.9, "AR1: 9 of 10 thresholds");
    }

    #[test]
    fn ignored_ground_truth_neither_counts_nor_penalises() {
        let g = [group(0, &[(5000.0, true), (5000.0, false)], &[(0.9, 5000.0), (0.8, 5000.0)], vec![vec![0.9, 0.0], vec![0.0, 0.9]])];
        let s = summarize(&g, &[1]);
        // The first detection matches the ignored one (ignored itself), the
        // second the counted one: precision 1 up to 0.9.
        assert!((s.stats[1] - 1.0).abs() < 1e-15);
    }
}
