#!/bin/bash
# Reproduces the README's "Table 1 of the paper" on lmo-synth: resting poses
# from 1000 drop tests per model (columns: convex decomposition of the full
# shape, convex hull) x the mesh the visual score renders (rows). Each
# estimate is resumable (--out keeps finished images); about 7 minutes per
# cell on 2 cores. Usage: docs/table1/run.sh DATASET OUTDIR
set -euo pipefail
D=${1:?BOP dataset folder, e.g. ../shared/data/lmo-synth}
O=${2:?output folder}
P=${PLAUSIBLE:-target/release/plausible}
mkdir -p "$O"
for col in decomposition hull; do
  [ -f "$O/stable_$col.db" ] || "$P" stable-poses --db "$O/stable_$col.db" --drops 1000 --collider $col -q "$D"/models/*.ply
done
for col in hull decomposition; do
  for lod in off auto 704 352 70 34; do
    "$P" estimate --dataset "$D" --stable "$O/stable_$col.db" --lod $lod --out "$O/est_${col}_${lod}.csv" \
      --summary "$O/sum_${col}_${lod}.json" --quiet
    "$P" eval --dataset "$D" --results "$O/est_${col}_${lod}.csv" --out "$O/eval_${col}_${lod}.json"
  done
done
