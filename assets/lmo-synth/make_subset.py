"""Makes assets/lmo-synth: a 12-frame subset of shared/data/lmo-synth (BOP layout)
whose BOP'19 targets are 3 objects, with every object's model and every
instance's masks (BOP'24 detection and the 2D tasks evaluate every annotated
object), its BOP'24 image list, a perturbed results file for it, and the BOP
toolkit's numbers for it.

    python3 assets/lmo-synth/make_subset.py ../shared/data/lmo-synth assets/lmo-synth

Files are copied unchanged or filtered (JSON entries of the chosen frames and
objects); nothing is re-encoded. Standard library only.
"""
import json
import os
import shutil
import sys

src, dst = sys.argv[1], sys.argv[2]
OBJS = [1, 10, 11]  # ape; eggbox and glue (symmetric)
scene = "test/000002"
targets = json.load(open(os.path.join(src, "test_targets_bop19.json")))
ims = sorted({t["im_id"] for t in targets})
FRAMES = ims[::17]  # 12 frames across the sequence's arrangements
os.makedirs(os.path.join(dst, "models"), exist_ok=True)
os.makedirs(os.path.join(dst, scene, "depth"), exist_ok=True)
for f in ["camera.json", "CC-BY-SA-4.0.txt", "models/models_info.json"]:
    shutil.copyfile(os.path.join(src, f), os.path.join(dst, f))
for o in sorted(int(k) for k in json.load(open(os.path.join(src, "models", "models_info.json")))):
    shutil.copyfile(os.path.join(src, "models", "obj_%06d.ply" % o), os.path.join(dst, "models", "obj_%06d.ply" % o))
for name in ["scene_gt.json", "scene_camera.json", "scene_gt_info.json"]:
    d = json.load(open(os.path.join(src, scene, name)))
    json.dump({str(i): d[str(i)] for i in FRAMES}, open(os.path.join(dst, scene, name), "w"))
for i in FRAMES:
    shutil.copyfile(os.path.join(src, scene, "depth", "%06d.png" % i), os.path.join(dst, scene, "depth", "%06d.png" % i))
# The visible and full masks of every instance (named by the instance's index
# in scene_gt, which the filtered scene_gt keeps), for `refine` and BOP's 2D
# tasks (whose ground truth is every annotated instance of the images).
gt = json.load(open(os.path.join(src, scene, "scene_gt.json")))
for kind in ["mask_visib", "mask"]:
    os.makedirs(os.path.join(dst, scene, kind), exist_ok=True)
    for i in FRAMES:
        for k in range(len(gt[str(i)])):
            name = "%06d_%06d.png" % (i, k)
            shutil.copyfile(os.path.join(src, scene, kind, name), os.path.join(dst, scene, kind, name))
sub = [t for t in targets if t["im_id"] in FRAMES and t["obj_id"] in OBJS]
with open(os.path.join(dst, "test_targets_bop19.json"), "w") as f:
    f.write("[\n" + ",\n".join("  " + json.dumps(t, sort_keys=True) for t in sub) + "\n]\n")
# BOP'24's targets name images only (scene, image), in the BOP'19 file's order.
images = []
for t in sub:
    if {"scene_id": t["scene_id"], "im_id": t["im_id"]} not in images:
        images.append({"scene_id": t["scene_id"], "im_id": t["im_id"]})
with open(os.path.join(dst, "test_targets_bop24.json"), "w") as f:
    f.write("[\n" + ",\n".join("  " + json.dumps(t, sort_keys=True) for t in images) + "\n]\n")
keep = {(t["im_id"], t["obj_id"]) for t in sub}
with open(os.path.join(src, "reference", "perturbed_open.csv")) as f, open(os.path.join(dst, "perturbed.csv"), "w") as g:
    lines = f.read().splitlines()
    g.write(lines[0] + "\n")
    for l in lines[1:]:
        s, i, o = l.split(",")[:3]
        if (int(i), int(o)) in keep:
            g.write(l + "\n")
print(len(FRAMES), "frames", FRAMES, len(sub), "targets")
