#!/usr/bin/env bash
# BOP 2D detection / segmentation evaluation (bop_toolkit scripts/calc_gt_coco.py and
# scripts/eval_bop22_coco.py @ cea62d6, unchanged) of one COCO results file on a dataset in HOT3D's
# layout (annotations and masks per camera, the camera chosen by scene).
#
#   scripts/hot3d_coco_reference.sh DATASET RESULTS.json OUTDIR
#
# OUTDIR gets: datasets/hot3d/ (shadow dataset: models_eval/ with the 33 models the toolkit lists for
#   hot3d, the missing ones linked to the dataset's first; test/ with every HOT3D test scene id, the
#   dataset's scenes as folders of links, the others with empty annotations of their evaluated camera,
#   since calc_gt_coco.py walks all of them; calc_gt_coco.py writes its scene_gt_coco_{camera}.json
#   files there), results/METHOD_hot3d-test.json, eval/ (scores_bop22_coco_{segm,bbox,bbox_modal}.json),
#   logs/, summary.json (the three score files). Targets: the dataset's test_targets_bop24.json.
# Environment: BOP_TOOLKIT (required: a checkout of thodan/bop_toolkit, commit cea62d6), BOP24_VENV
#   (default ~/.cache/bop-toolkit-venv) with the toolkit's pycocotools fork and scikit-image (see
#   scripts/coco_reference.sh).
set -euo pipefail
if [ $# -ne 3 ]; then sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; fi
HERE="${BOP_TOOLKIT:?set BOP_TOOLKIT to a bop_toolkit checkout (commit cea62d6)}"
DATA="$(readlink -f "$1")"
RESULTS="$(readlink -f "$2")"
OUT="$3"
VENV="${BOP24_VENV:-$HOME/.cache/bop-toolkit-venv}"
PY="$VENV/bin/python"
"$PY" -c "import numpy, pycocotools, skimage, imageio, png" || { echo "venv $VENV lacks pycocotools/scikit-image" >&2; exit 1; }
DATASET=hot3d
mkdir -p "$OUT"; OUT="$(readlink -f "$OUT")"
rm -rf "$OUT/datasets" "$OUT/results" "$OUT/eval" "$OUT/logs" "$OUT/summary.json"
D="$OUT/datasets/$DATASET"
mkdir -p "$D/models_eval" "$D/test" "$OUT/results" "$OUT/eval" "$OUT/logs"
ln -s "$DATA/test_targets_bop24.json" "$D/test_targets_bop24.json"
MODELS="$DATA/models_eval"; [ -d "$MODELS" ] || MODELS="$DATA/models"
"$PY" - "$MODELS" "$D/models_eval" "$DATA/test" "$D/test" <<'EOF'
import json, os, sys
src, dst, test, shadow = sys.argv[1:]
info = json.load(open(os.path.join(src, "models_info.json")))
first = min(int(k) for k in info)
for i in range(1, 34):
    name = f"obj_{i:06d}.ply"
    have = str(i) in info and os.path.exists(os.path.join(src, name))
    os.symlink(os.path.join(src, name if have else f"obj_{first:06d}.ply"), os.path.join(dst, name))
    if not have:
        info[str(i)] = info[str(first)]
json.dump(info, open(os.path.join(dst, "models_info.json"), "w"), indent=1)
# dataset_params: test scenes 1288-1848 (Quest 3, gray1) and 3365-3831 (Aria, rgb).
for sid in list(range(1288, 1849)) + list(range(3365, 3832)):
    cam = "gray1" if sid < 1849 else "rgb"
    d = os.path.join(shadow, f"{sid:06d}")
    os.makedirs(d)
    real = os.path.join(test, f"{sid:06d}")
    if os.path.isdir(real):
        for e in os.listdir(real):
            if not e.startswith("scene_gt_coco"):
                os.symlink(os.path.join(real, e), os.path.join(d, e))
    else:
        for stem in ("scene_gt", "scene_gt_info", "scene_camera"):
            open(os.path.join(d, f"{stem}_{cam}.json"), "w").write("{}")
EOF
base="$(basename "$RESULTS")"; stem="${base%.*}"; NAME="${stem//_/-}_${DATASET}-test.json"
cp "$RESULTS" "$OUT/results/$NAME"
export PYTHONPATH="$HERE" BOP_PATH="$OUT/datasets" BOP_RESULTS_PATH="$OUT/results" BOP_EVAL_PATH="$OUT/eval" PYTHONUNBUFFERED=1
for bt in amodal modal; do
  "$PY" "$HERE/scripts/calc_gt_coco.py" --dataset $DATASET --dataset_split test --bbox_type $bt \
    --targets_filename test_targets_bop24.json >"$OUT/logs/calc_gt_coco_$bt.log" 2>&1 \
    || { tail -20 "$OUT/logs/calc_gt_coco_$bt.log" >&2; exit 1; }
done
for at in ${ANN_TYPES:-segm bbox bbox_modal}; do
  case $at in bbox_modal) args=(--ann_type bbox --bbox_type modal);; *) args=(--ann_type "$at" --bbox_type amodal);; esac
  "$PY" "$HERE/scripts/eval_bop22_coco.py" --results_path "$OUT/results" --eval_path "$OUT/eval" \
    --result_filenames "$NAME" --targets_filename test_targets_bop24.json "${args[@]}" >"$OUT/logs/eval_$at.log" 2>&1 \
    || { tail -20 "$OUT/logs/eval_$at.log" >&2; exit 1; }
done
"$PY" - "$OUT" "${NAME%.json}" <<'PYEOF'
import glob, json, os, sys
out, name = sys.argv[1:]
s = {os.path.basename(f)[len("scores_bop22_coco_"):-5]: json.load(open(f))
     for f in sorted(glob.glob(os.path.join(out, "eval", name, "scores_bop22_coco_*.json")))}
json.dump(s, open(os.path.join(out, "summary.json"), "w"), indent=1)
print(json.dumps({k: v["AP"] for k, v in s.items()}))
PYEOF
