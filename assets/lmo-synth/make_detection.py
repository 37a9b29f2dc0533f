"""Makes assets/lmo-synth/detection.csv: BOP'24 6D-detection test estimates for
the shipped subset, stdlib only, seeded (same output every run):

    python3 assets/lmo-synth/make_detection.py assets/lmo-synth

Per image: each annotated instance (of all 8 objects) perturbed by a random
rotation of 0-30 degrees and a translation of sigma 10 mm, or left out (15 %);
duplicates of some instances; false estimates near and far, for objects in the
image and objects absent from it. Scores are rounded to one decimal so that
many tie across images and objects, some are negative or huge; one image holds
130 estimates (over the toolkit's cap of 100 per image, with ties at the cut).
reference_detection.json holds the BOP toolkit's numbers for this file and for
perturbed.csv (scripts/eval_bop24_pose.py at commit cea62d6, unchanged).
"""
import json
import math
import os
import random
import sys

root = sys.argv[1]
rng = random.Random(24)
gt = json.load(open(os.path.join(root, "test/000002/scene_gt.json")))
objs = [int(k) for k in json.load(open(os.path.join(root, "models/models_info.json")))]


def matmul(a, b):
    return [sum(a[3 * i + k] * b[3 * k + j] for k in range(3)) for i in range(3) for j in range(3)]


def turn(deg):
    x, y, z = (rng.gauss(0, 1) for _ in range(3))
    n = math.sqrt(x * x + y * y + z * z)
    x, y, z = x / n, y / n, z / n
    a = math.radians(deg)
    c, s, C = math.cos(a), math.sin(a), 1 - math.cos(a)
    return [c + x * x * C, x * y * C - z * s, x * z * C + y * s,
            y * x * C + z * s, c + y * y * C, y * z * C - x * s,
            z * x * C - y * s, z * y * C + x * s, c + z * z * C]


def row(im, obj, r, t, score):
    return "2,%d,%d,%r,%s,%s,-1" % (im, obj, score, " ".join(repr(v) for v in r), " ".join(repr(v) for v in t))


def noisy(inst, deg, mm):
    r = matmul(turn(rng.uniform(0, deg)), inst["cam_R_m2c"])
    t = [v + rng.gauss(0, mm) for v in inst["cam_t_m2c"]]
    return r, t


lines = []
ims = sorted(int(k) for k in gt)
for im in ims:
    insts = gt[str(im)]
    present = sorted({g["obj_id"] for g in insts})
    for g in insts:
        if rng.random() < 0.15:
            continue
        r, t = noisy(g, 30, 10)
        lines.append(row(im, g["obj_id"], r, t, round(rng.random(), 1)))
        if rng.random() < 0.2:  # a duplicate, a little worse
            r, t = noisy(g, 40, 15)
            lines.append(row(im, g["obj_id"], r, t, round(rng.random(), 1)))
    for _ in range(rng.randint(1, 3)):  # false estimates
        g = rng.choice(insts)
        r, t = noisy(g, 90, 80 if rng.random() < 0.5 else 400)
        obj = rng.choice(objs if rng.random() < 0.5 else present)
        lines.append(row(im, obj, r, t, rng.choice([round(rng.random(), 1), -5.0, 1e9, 0.0])))
crowd = ims[1]
for _ in range(130):  # one crowded image, ties at the cap
    g = rng.choice(gt[str(crowd)])
    r, t = noisy(g, 20, 8)
    lines.append(row(crowd, g["obj_id"], r, t, round(rng.random(), 1)))
rng.shuffle(lines)
with open(os.path.join(root, "detection.csv"), "w") as f:
    f.write("scene_id,im_id,obj_id,score,R,t,time\n" + "\n".join(lines) + "\n")
print(len(lines), "estimates")
