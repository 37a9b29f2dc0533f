"""Makes COCO-format 2D detection and segmentation results (BOP'22 format) for a
BOP dataset's target images, seeded (same output every run):

    python3 assets/lmo-synth/make_coco.py DATASET OUT_PREFIX [SEED [hot3d]]

(`hot3d`: a dataset in HOT3D's layout, read as the toolkit reads it: the images of
test_targets_bop24.json, each scene's files of its evaluated camera, `_gray1` for scenes up to
1848, `_rgb` above.)

writes OUT_PREFIX.json (every result has "bbox", a compressed-RLE
"segmentation" and "time") and OUT_PREFIX_segm.json (no "bbox", half the
masks as uncompressed RLE, no times: the other branches of pycocotools'
loadRes). Needs numpy, imageio and pycocotools (the BOP toolkit's venv).

Per target image, each annotated instance with a visible mask is left out
(15 %) or detected: its visible mask shifted by up to 6 px and grown or shrunk
by a pixel, its amodal box (from mask/) jittered by up to 8 px in steps of
0.1 px; some are detected twice. False detections: boxes and blobs for objects
in the image and absent from it, a category the dataset lacks, an empty mask,
small (< 32² px) and huge ones, and in one image 110 tiny detections of one
object (over COCO's 100 per image and category). Scores are rounded to one
decimal so that many tie. reference_coco.json holds the BOP toolkit's numbers
(scripts/eval_bop22_coco.py at commit cea62d6, unchanged) for the shipped
subset's files.
"""
import json
import os
import sys

import imageio.v2 as imageio
import numpy as np
from pycocotools import mask as mu

root, prefix = sys.argv[1], sys.argv[2]
rng = np.random.default_rng(int(sys.argv[3]) if len(sys.argv) > 3 else 22)
hot3d = len(sys.argv) > 4 and sys.argv[4] == "hot3d"
targets = json.load(open(os.path.join(root, "test_targets_bop24.json" if hot3d else "test_targets_bop19.json")))


def cam(sid):
    """The file suffix of a scene's evaluated camera."""
    return ("_gray1" if sid <= 1848 else "_rgb") if hot3d else ""


images = []
for t in targets:
    if (t["scene_id"], t["im_id"]) not in images:
        images.append((t["scene_id"], t["im_id"]))
objs = sorted(int(k) for k in json.load(open(os.path.join(root, "models", "models_info.json"))))


def shift(m, dx, dy):
    out = np.zeros_like(m)
    h, w = m.shape
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = m[ys, xs]
    return out


def grow(m, k):
    if k == 0:
        return m
    n = [shift(m, dx, dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    return np.logical_or.reduce([m] + n) if k > 0 else np.logical_and.reduce([m] + n)


def rle(m):
    r = mu.encode(np.asfortranarray(m.astype(np.uint8)))
    return {"counts": r["counts"].decode("ascii"), "size": [int(s) for s in r["size"]]}


def box_of(m):
    ys, xs = np.nonzero(m)
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


res = []
scenes = {}
for n, (sid, iid) in enumerate(images):
    d = os.path.join(root, "test", "%06d" % sid)
    if sid not in scenes:
        scenes[sid] = json.load(open(os.path.join(d, f"scene_gt{cam(sid)}.json")))
    gt = scenes[sid][str(iid)]
    t_im = round(float(rng.uniform(0.1, 2.0)), 3)
    out = []
    h = w = None
    for k, inst in enumerate(gt):
        vis = imageio.imread(os.path.join(d, f"mask_visib{cam(sid)}", "%06d_%06d.png" % (iid, k))) > 0
        full = imageio.imread(os.path.join(d, f"mask{cam(sid)}", "%06d_%06d.png" % (iid, k))) > 0
        h, w = vis.shape
        if vis.sum() == 0 or rng.random() < 0.15:
            continue
        for _ in range(2 if rng.random() < 0.2 else 1):
            m = grow(shift(vis, int(rng.integers(-6, 7)), int(rng.integers(-6, 7))), int(rng.integers(-1, 2)))
            b = box_of(full)
            jb = [round(b[i] + float(rng.uniform(-8, 8)), 1) for i in range(4)]
            jb[2], jb[3] = max(jb[2], 1.0), max(jb[3], 1.0)
            out.append({"category_id": inst["obj_id"], "bbox": jb, "segmentation": rle(m), "score": round(float(rng.uniform(0, 1)), 1)})
    # False detections: blobs of random size (small, medium, large), for random objects.
    for _ in range(int(rng.integers(1, 5))):
        x0, y0 = int(rng.integers(0, w - 40)), int(rng.integers(0, h - 40))
        bw, bh = int(rng.integers(3, min(200, w - x0))), int(rng.integers(3, min(200, h - y0)))
        m = np.zeros((h, w), bool)
        m[y0:y0 + bh, x0:x0 + bw] = True
        cat = int(rng.choice(objs + [2]))
        out.append({"category_id": cat, "bbox": [x0, y0, bw, bh], "segmentation": rle(m), "score": round(float(rng.uniform(0, 1)), 1)})
    if n == 0:  # an empty mask, and a detection as large as the image
        out.append({"category_id": objs[0], "bbox": [0, 0, 1, 1], "segmentation": rle(np.zeros((h, w), bool)), "score": 0.5})
        out.append({"category_id": objs[-1], "bbox": [0, 0, w, h], "segmentation": rle(np.ones((h, w), bool)), "score": 0.9})
    if n == 1 and gt:  # 110 tiny detections of one object, with tied scores
        cat = gt[0]["obj_id"]
        for j in range(110):
            m = np.zeros((h, w), bool)
            y, x = 5 + (j // 20) * 6, 5 + (j % 20) * 6
            m[y:y + 4, x:x + 4] = True
            out.append({"category_id": cat, "bbox": [x, y, 4, 4], "segmentation": rle(m), "score": round(float(rng.uniform(0, 1)), 1)})
    for o in out:
        o.update({"scene_id": sid, "image_id": iid, "time": t_im})
    res += out
# Results for an image that is not a target: ignored.
if res:
    extra = dict(res[0])
    extra["image_id"] = 999999
    res.append(extra)
json.dump(res, open(prefix + ".json", "w"))
segm = []
for i, r in enumerate(res):
    s = {k: v for k, v in r.items() if k not in ("bbox", "time")}
    if i % 2:
        m = mu.decode({"counts": r["segmentation"]["counts"].encode("ascii"), "size": r["segmentation"]["size"]})
        flat = m.ravel(order="F")
        runs = np.diff(np.concatenate(([0], np.flatnonzero(np.diff(flat) != 0) + 1, [flat.size])))
        counts = ([0] if flat[0] else []) + runs.tolist()
        s["segmentation"] = {"counts": counts, "size": r["segmentation"]["size"]}
    segm.append(s)
json.dump(segm, open(prefix + "_segm.json", "w"))
print(len(images), "images,", len(res), "results", file=sys.stderr)
