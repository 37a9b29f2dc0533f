#!/usr/bin/env python3
"""Builds a shadow of a dataset in HOT3D's layout that the BOP toolkit accepts as `hot3d`, without
writing into the dataset (used by scripts/hot3d_reference.sh and scripts/coco_reference.sh).

    hot3d_shadow.py DATASET SHADOW [--all-scenes]

SHADOW/models_eval/: the 33 model files the toolkit loads for hot3d, the dataset's own where it has
them, the others linked to its first and given its models_info entry (never annotated, so they score
nothing). SHADOW/test/: each scene a folder of links to the dataset's files (its scene_gt_coco* left
out, so the toolkit's calc_gt_coco.py writes its own there); with --all-scenes also every other HOT3D
test scene id (1288-1848 Quest 3, 3365-3831 Aria: calc_gt_coco.py walks them all) with empty
annotations of its evaluated camera. SHADOW/test_targets_bop24.json: a link to the dataset's.
"""
import json
import os
import sys

data, shadow = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
all_scenes = "--all-scenes" in sys.argv[3:]
src = os.path.join(data, "models_eval")
if not os.path.isdir(src):
    src = os.path.join(data, "models")
os.makedirs(os.path.join(shadow, "models_eval"))
info = json.load(open(os.path.join(src, "models_info.json")))
first = min(int(k) for k in info)
for i in range(1, 34):
    name = f"obj_{i:06d}.ply"
    have = str(i) in info and os.path.exists(os.path.join(src, name))
    os.symlink(os.path.join(src, name if have else f"obj_{first:06d}.ply"), os.path.join(shadow, "models_eval", name))
    if not have:
        info[str(i)] = info[str(first)]
json.dump(info, open(os.path.join(shadow, "models_eval", "models_info.json"), "w"), indent=1)
os.symlink(os.path.join(data, "test_targets_bop24.json"), os.path.join(shadow, "test_targets_bop24.json"))
test = os.path.join(data, "test")
ids = {int(s) for s in os.listdir(test) if s.isdigit()}
if all_scenes:
    ids |= set(range(1288, 1849)) | set(range(3365, 3832))
for sid in sorted(ids):
    d = os.path.join(shadow, "test", f"{sid:06d}")
    os.makedirs(d)
    real = os.path.join(test, f"{sid:06d}")
    if os.path.isdir(real):
        for e in os.listdir(real):
            if not e.startswith("scene_gt_coco"):
                os.symlink(os.path.join(real, e), os.path.join(d, e))
    else:
        cam = "gray1" if sid < 1849 else "rgb"
        for stem in ("scene_gt", "scene_gt_info", "scene_camera"):
            open(os.path.join(d, f"{stem}_{cam}.json"), "w").write("{}")
