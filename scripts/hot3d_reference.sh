#!/usr/bin/env bash
# BOP'24 6D-detection evaluation (bop_toolkit scripts/eval_bop24_pose.py @ cea62d6, unchanged) of one
# BOP'19 CSV on a dataset in HOT3D's layout (fisheye cameras as cam_model, annotations per camera).
#
#   scripts/hot3d_reference.sh DATASET RESULTS.csv OUTDIR
#
# DATASET: e.g. assets/hot3d-synth. OUTDIR gets: datasets/hot3d/ (shadow dataset made by
#   scripts/hot3d_shadow.py: links to the scenes and targets, models_eval/ with the 33 model files the
#   toolkit loads for hot3d), results/METHOD_hot3d-test.csv, eval/ (toolkit
#   output), logs/eval.log, summary.json (scores_bop24.json, the AP of each object per error type and
#   threshold, the targets per object, wall time).
# Environment: BOP_TOOLKIT (required: a checkout of thodan/bop_toolkit, commit cea62d6), HTT (required:
#   a checkout of facebookresearch/hand_tracking_toolkit; only its camera module is imported, which
#   needs numpy, scipy and typing_extensions), BOP24_VENV (default ~/.cache/bop-toolkit-venv, made by
#   ../shared/anchors/bop_toolkit/setup.sh).
set -euo pipefail
if [ $# -ne 3 ]; then sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; fi
HERE="${BOP_TOOLKIT:?set BOP_TOOLKIT to a bop_toolkit checkout (commit cea62d6)}"
HTT_DIR="${HTT:?set HTT to a hand_tracking_toolkit checkout}"
DATA="$(readlink -f "$1")"
RESULTS="$(readlink -f "$2")"
OUT="$3"
VENV="${BOP24_VENV:-$HOME/.cache/bop-toolkit-venv}"
PY="$VENV/bin/python"
"$PY" -c "import numpy, scipy, typing_extensions, png, imageio" || { echo "venv $VENV lacks numpy/scipy/typing_extensions" >&2; exit 1; }
DATASET=hot3d
mkdir -p "$OUT"; OUT="$(readlink -f "$OUT")"
rm -rf "$OUT/datasets" "$OUT/results" "$OUT/eval" "$OUT/logs" "$OUT/summary.json"
mkdir -p "$OUT/results" "$OUT/eval" "$OUT/logs"
"$PY" "$(dirname "$0")/hot3d_shadow.py" "$DATA" "$OUT/datasets/$DATASET"
base="$(basename "$RESULTS")"; stem="${base%.*}"; NAME="${stem//_/-}_${DATASET}-test.csv"
cp "$RESULTS" "$OUT/results/$NAME"
export PATH="$VENV/bin:$PATH" PYTHONPATH="$HERE:$HTT_DIR" BOP_PATH="$OUT/datasets" BOP_RESULTS_PATH="$OUT/results"
export BOP_EVAL_PATH="$OUT/eval" BOP_NUM_WORKERS=1 PYTHONUNBUFFERED=1
CMD=(python "$HERE/scripts/eval_bop24_pose.py" --results_path "$OUT/results" --eval_path "$OUT/eval"
     --result_filenames "$NAME" --num_workers 1 --targets_filename test_targets_bop24.json)
echo "running: ${CMD[*]}" | tee "$OUT/logs/eval.log" >&2
t0=$(date +%s.%N)
if ! "${CMD[@]}" >>"$OUT/logs/eval.log" 2>&1; then
  tail -30 "$OUT/logs/eval.log" >&2; echo "eval_bop24_pose.py failed; see $OUT/logs/eval.log" >&2; exit 1; fi
t1=$(date +%s.%N)
"$PY" - "$OUT" "${NAME%.csv}" "$t0" "$t1" <<'EOF'
import json, os, sys
import numpy as np
out, result_name, t0, t1 = sys.argv[1:]
ev = os.path.join(out, "eval", result_name)
final = json.load(open(os.path.join(ev, "scores_bop24.json")))
# Per error type and threshold (eval_bop24_pose.py's lists and file names), the AP of each object
# with targets (the placeholder models have none).
errors = {"mssd": ("error=mssd_ntop=0", np.arange(0.05, 0.51, 0.05)),
          "mssd_mm": ("error=mssd_ntop=0", range(2, 21, 2)),
          "mspd": ("error=mspd_ntop=0", np.arange(5, 51, 5))}
per_th, targets = {}, {}
for et, (sign, ths) in errors.items():
    per_th[et] = []
    for th in ths:
        sc = json.load(open(os.path.join(ev, sign, "scores_th={:.3f}_min-visib={:.3f}.json".format(th, 0.1))))
        n = sc["num_targets_per_object"]
        targets = {o: c for o, c in n.items() if c > 0}
        per_th[et].append({o: ap for o, ap in sc["scores"].items() if n.get(o, 0) > 0})
summary = dict(final, per_threshold_per_object_ap=per_th, num_targets_per_object=targets,
               wall_s=round(float(t1) - float(t0), 2))
json.dump(summary, open(os.path.join(out, "summary.json"), "w"), indent=1)
print(json.dumps(final))
EOF
