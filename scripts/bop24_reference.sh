#!/usr/bin/env bash
# BOP'24 6D-detection evaluation (bop_toolkit scripts/eval_bop24_pose.py @ cea62d6, unchanged) of one
# BOP'19 CSV on lmo-synth.
#
#   scripts/bop24_reference.sh RESULTS.csv OUTDIR
#
# OUTDIR gets: datasets/lmo/ (shadow dataset: symlinks to every entry of the lmo-synth folder,
#   models_eval -> models, and a copy of its test_targets_bop24.json or, without one, the distinct
#   (scene_id, im_id) of test_targets_bop19.json in first-appearance order), results/METHOD_lmo-test.csv (copy of RESULTS.csv;
#   METHOD = file stem with "_" -> "-"), eval/ (toolkit output: errors, matches, scores_*.json,
#   scores_bop24.json), logs/eval.log, summary.json.
# Environment: BOP_TOOLKIT (required: a checkout of thodan/bop_toolkit, commit cea62d6), BOP24_VENV
#   (default ~/.cache/bop-toolkit-venv, made by ../shared/anchors/bop_toolkit/setup.sh), LMO_SYNTH (default
#   ../shared/data/lmo-synth; assets/lmo-synth for reference_detection.json),
#   NUM_WORKERS (default 1).
set -euo pipefail
if [ $# -ne 2 ]; then sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; fi
HERE="${BOP_TOOLKIT:?set BOP_TOOLKIT to a bop_toolkit checkout (commit cea62d6)}"
RESULTS="$(readlink -f "$1")"
OUT="$2"
DATA="$(readlink -f "${LMO_SYNTH:-$(dirname "$0")/../../shared/data/lmo-synth}")"
VENV="${BOP24_VENV:-$HOME/.cache/bop-toolkit-venv}"
NW="${NUM_WORKERS:-1}"
DATASET=lmo
[ -f "$RESULTS" ] || { echo "no results file $RESULTS" >&2; exit 2; }

# The anchor's setup.sh creates the venv (numpy<2, scipy, pypng, imageio, pillow, tqdm, open3d-cpu). Its
# final import check fails on this machine (open3d needs libusb-1.0.so.0), which does not matter here:
# MSSD/MSPD need no renderer. So: accept the venv as soon as the non-renderer packages import.
CHECK="import numpy, scipy, png, imageio, PIL, tqdm; assert numpy.__version__.startswith('1.')"
if ! "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
  BOP_VENV="$VENV" bash "$(dirname "$0")/../../shared/anchors/bop_toolkit/setup.sh" >/dev/null || true
  "$VENV/bin/python" -c "$CHECK" || { echo "venv $VENV unusable" >&2; exit 1; }
fi
PY="$VENV/bin/python"

mkdir -p "$OUT"
OUT="$(readlink -f "$OUT")"
rm -rf "$OUT/datasets" "$OUT/results" "$OUT/eval" "$OUT/logs" "$OUT/summary.json"
mkdir -p "$OUT/datasets/$DATASET" "$OUT/results" "$OUT/eval" "$OUT/logs"

# Shadow dataset folder (nothing is written into the dataset): symlinks to its entries, models_eval ->
# models if absent, and test_targets_bop24.json: the dataset's own when it has one, else made from
# test_targets_bop19.json (its images in first-appearance order).
for e in "$DATA"/*; do
  [ "$(basename "$e")" = test_targets_bop24.json ] && continue
  ln -s "$e" "$OUT/datasets/$DATASET/$(basename "$e")"
done
[ -e "$DATA/models_eval" ] || ln -s "$DATA/models" "$OUT/datasets/$DATASET/models_eval"
if [ -f "$DATA/test_targets_bop24.json" ]; then
  cp "$DATA/test_targets_bop24.json" "$OUT/datasets/$DATASET/test_targets_bop24.json"
else
"$PY" - "$DATA/test_targets_bop19.json" "$OUT/datasets/$DATASET/test_targets_bop24.json" <<'EOF'
import json, sys
seen, out = set(), []
for t in json.load(open(sys.argv[1])):
    k = (t["scene_id"], t["im_id"])
    if k not in seen:
        seen.add(k)
        out.append({"scene_id": k[0], "im_id": k[1]})
json.dump(out, open(sys.argv[2], "w"), indent=1)
print(f"test_targets_bop24.json: {len(out)} images", file=sys.stderr)
EOF
fi

# Result file under a name the toolkit accepts: METHOD_lmo-test.csv.
base="$(basename "$RESULTS")"
if [[ "$base" =~ ^[^_]+_${DATASET}-test(_[^.]+)?\.csv$ ]]; then NAME="$base"; else
  stem="${base%.*}"; NAME="${stem//_/-}_${DATASET}-test.csv"; fi
cp "$RESULTS" "$OUT/results/$NAME"
RESULT_NAME="${NAME%%.*}"

export PATH="$VENV/bin:$PATH"                     # the toolkit launches its sub-steps as "python ..."
export PYTHONPATH="$HERE"
export BOP_PATH="$OUT/datasets" BOP_RESULTS_PATH="$OUT/results" BOP_EVAL_PATH="$OUT/eval"
export BOP_NUM_WORKERS="$NW" PYTHONUNBUFFERED=1

CMD=(python "$HERE/scripts/eval_bop24_pose.py" --results_path "$OUT/results" --eval_path "$OUT/eval"
     --result_filenames "$NAME" --num_workers "$NW" --targets_filename test_targets_bop24.json)
echo "running: ${CMD[*]}" | tee "$OUT/logs/eval.log" >&2
t0=$(date +%s.%N)
if ! "${CMD[@]}" >>"$OUT/logs/eval.log" 2>&1; then
  tail -30 "$OUT/logs/eval.log" >&2; echo "eval_bop24_pose.py failed; see $OUT/logs/eval.log" >&2; exit 1; fi
t1=$(date +%s.%N)

"$PY" - "$OUT" "$RESULT_NAME" "$RESULTS" "$NAME" "$t0" "$t1" <<'EOF'
import json, os, sys
import numpy as np
out, result_name, results, name, t0, t1 = sys.argv[1:]
ev = os.path.join(out, "eval", result_name)
final = json.load(open(os.path.join(ev, "scores_bop24.json")))
# The threshold lists exactly as eval_bop24_pose.py builds them (its p["errors"]), and its file naming
# (misc.get_score_signature(correct_th, visib_gt_min=0.1)).
errors = {
    "mssd": ("error=mssd_ntop=0", [th for th in np.arange(0.05, 0.51, 0.05)]),
    "mssd_mm": ("error=mssd_ntop=0", [th for th in range(2, 21, 2)]),
    "mspd": ("error=mspd_ntop=0", [th for th in np.arange(5, 51, 5)]),
}
per_type = {}
for et, (sign, ths) in errors.items():
    files, obj_means = [], {}
    for th in ths:
        fn = "scores_th={:.3f}_min-visib={:.3f}.json".format(th, 0.1)
        s = json.load(open(os.path.join(ev, sign, fn)))
        files.append({"file": f"{sign}/{fn}", "correct_th_arg": str(th),
                      "ap_per_object": s["scores"], "num_targets_per_object": s["num_targets_per_object"]})
    # Re-derive the per-type mAP the way eval_bop24_pose.py does (mean over thresholds per object,
    # then mean over objects with >0 targets) as a consistency check.
    objs = list(files[0]["ap_per_object"].keys())
    per_obj = {o: float(np.mean([f["ap_per_object"][o] if f["num_targets_per_object"][o] > 0 else 0
                                 for f in files])) for o in objs}
    valid = [o for o in objs if files[-1]["num_targets_per_object"][o] > 0]
    mAP = float(np.mean([per_obj[o] for o in valid]))
    key = "bop24_mAP_" + et
    assert mAP == final[key], (et, mAP, final[key])
    per_type[et] = {"mAP": final[key], "ap_per_object_mean_over_thresholds": per_obj,
                    "objects_counted": valid, "thresholds": files}
summary = {
    "results_file": results, "bop_result_name": name, "dataset": "lmo",
    "targets_filename": "test_targets_bop24.json", "eval_dir": ev,
    "scores_bop24": final,
    "bop24_mAP": final["bop24_mAP"], "bop24_mAP_mssd": final["bop24_mAP_mssd"],
    "bop24_mAP_mspd": final["bop24_mAP_mspd"], "bop24_mAP_mssd_mm": final["bop24_mAP_mssd_mm"],
    "bop25_mAP": final["bop25_mAP"], "bop25_mAP_mm": final["bop25_mAP_mm"],
    "bop24_average_time_per_image": final["bop24_average_time_per_image"],
    "per_error_type": per_type,
    "wall_s": round(float(t1) - float(t0), 2),
}
json.dump(summary, open(os.path.join(out, "summary.json"), "w"), indent=1)
print(json.dumps({k: summary[k] for k in ("bop24_mAP", "bop24_mAP_mssd", "bop24_mAP_mspd",
      "bop24_mAP_mssd_mm", "bop25_mAP", "bop25_mAP_mm", "bop24_average_time_per_image", "wall_s")}))
EOF
