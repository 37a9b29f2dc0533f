#!/usr/bin/env bash
# BOP 2D detection / segmentation evaluation (bop_toolkit scripts/calc_gt_coco.py and
# scripts/eval_bop22_coco.py @ cea62d6, unchanged) of one COCO results file on a dataset (LM-O's layout, or HOT3D's).
#
#   scripts/coco_reference.sh DATASET RESULTS.json OUTDIR
#
# OUTDIR gets: datasets/lmo/ (shadow dataset: symlinks to the dataset's entries, each scene a real folder
#   of symlinks so that calc_gt_coco.py writes its scene_gt_coco.json / scene_gt_coco_modal.json there, not
#   into DATASET), results/METHOD_lmo-test.json (copy of RESULTS.json), eval/ (the toolkit's
#   scores_bop22_coco_segm.json, scores_bop22_coco_bbox.json, scores_bop22_coco_bbox_modal.json),
#   logs/, summary.json (the three score files).
# Environment: BOP_TOOLKIT (required: a checkout of thodan/bop_toolkit, commit cea62d6), BOP24_VENV
#   (default ~/.cache/bop-toolkit-venv, made by ../shared/anchors/bop_toolkit/setup.sh, plus scikit-image
#   and the toolkit's own pycocotools, its `eval_coco` extra: MartinSmeyer/cocoapi, which honours the
#   ground truth's `ignore` flag and takes a dict; with numpy<2 build it with Cython<3:
#   `pip install "cython<3" setuptools scikit-image && pip install --no-build-isolation cocoapi/PythonAPI`),
#   ANN_TYPES (default "segm bbox bbox_modal"), DATASET_NAME (default lmo; hot3d for a dataset in
#   HOT3D's layout, e.g. assets/hot3d-synth: its shadow is made by scripts/hot3d_shadow.py --all-scenes,
#   with every HOT3D test scene id, since calc_gt_coco.py walks them all), TARGETS (default
#   test_targets_bop19.json; test_targets_bop24.json for hot3d-synth).
set -euo pipefail
if [ $# -ne 3 ]; then sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; fi
HERE="${BOP_TOOLKIT:?set BOP_TOOLKIT to a bop_toolkit checkout (commit cea62d6)}"
DATA="$(readlink -f "$1")"
RESULTS="$(readlink -f "$2")"
OUT="$3"
VENV="${BOP24_VENV:-$HOME/.cache/bop-toolkit-venv}"
PY="$VENV/bin/python"
"$PY" -c "import numpy, pycocotools, skimage, imageio, png" || { echo "venv $VENV lacks pycocotools/scikit-image" >&2; exit 1; }
DATASET="${DATASET_NAME:-lmo}"
TARGETS="${TARGETS:-test_targets_bop19.json}"
mkdir -p "$OUT"; OUT="$(readlink -f "$OUT")"
rm -rf "$OUT/datasets" "$OUT/results" "$OUT/eval" "$OUT/logs" "$OUT/summary.json"
mkdir -p "$OUT/results" "$OUT/eval" "$OUT/logs"
if [ "$DATASET" = hot3d ]; then
  "$PY" "$(dirname "$0")/hot3d_shadow.py" "$DATA" "$OUT/datasets/$DATASET" --all-scenes
else
  mkdir -p "$OUT/datasets/$DATASET/test"
  for e in "$DATA"/*; do
    [ "$(basename "$e")" = test ] || ln -s "$e" "$OUT/datasets/$DATASET/$(basename "$e")"
  done
  for s in "$DATA"/test/*/; do
    d="$OUT/datasets/$DATASET/test/$(basename "$s")"; mkdir -p "$d"
    for e in "$s"*; do case "$(basename "$e")" in scene_gt_coco*) ;; *) ln -s "$e" "$d/";; esac; done
  done
fi
base="$(basename "$RESULTS")"; stem="${base%.*}"; NAME="${stem//_/-}_${DATASET}-test.json"
cp "$RESULTS" "$OUT/results/$NAME"
export PYTHONPATH="$HERE" BOP_PATH="$OUT/datasets" BOP_RESULTS_PATH="$OUT/results" BOP_EVAL_PATH="$OUT/eval" PYTHONUNBUFFERED=1
for bt in amodal modal; do
  "$PY" "$HERE/scripts/calc_gt_coco.py" --dataset $DATASET --dataset_split test --bbox_type $bt \
    --targets_filename "$TARGETS" >"$OUT/logs/calc_gt_coco_$bt.log" 2>&1 \
    || { tail -20 "$OUT/logs/calc_gt_coco_$bt.log" >&2; exit 1; }
done
for at in ${ANN_TYPES:-segm bbox bbox_modal}; do
  case $at in bbox_modal) args=(--ann_type bbox --bbox_type modal);; *) args=(--ann_type "$at" --bbox_type amodal);; esac
  "$PY" "$HERE/scripts/eval_bop22_coco.py" --results_path "$OUT/results" --eval_path "$OUT/eval" \
    --result_filenames "$NAME" --targets_filename "$TARGETS" "${args[@]}" >"$OUT/logs/eval_$at.log" 2>&1 \
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
