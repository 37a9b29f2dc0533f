#!/usr/bin/env python3
"""Writes hot3d-synth: a small dataset in HOT3D's BOP layout (BOP-H3) with fisheye cameras, and a
results CSV to evaluate on it.

    python3 assets/hot3d-synth/make_hot3d.py [--seed 7]

HOT3D's test split has Quest 3 scenes (ids 1288-1848, evaluated on their first monochrome camera,
`gray1`, 1280x1024) and Aria scenes (3365-3831, evaluated on their RGB camera, `rgb`, 1408x1408).
Every camera is a `CameraModelType.FISHEYE624` lens: Aria's with one focal length (15 parameters),
Quest 3's with two (16). Each scene here is annotated for every camera of its headset
(`scene_gt_{camera}.json`, `scene_gt_info_{camera}.json`, `scene_camera_{camera}.json`): the same
objects seen through each camera, so that reading the wrong camera's files gives other numbers. The
objects are LM-O's (models -> ../lmo-synth/models), placed up to 58 degrees off the axis where the
lens distorts most. The estimates are the ground truth moved by seeded noise: small and large
errors, symmetric flips, duplicates, misses, false detections and one estimate behind the camera.
The evaluated camera of each scene also gets masks (`mask_{camera}/`, `mask_visib_{camera}/`): an
ellipse about the object's projected centre, of its projected size, cut by a straight edge to the
instance's visible fraction (drawn from a second generator, so the 6D data stay as they were).
numpy and imageio.
"""
import argparse
import json
import math
import os

import imageio.v2 as imageio
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
OBJ_IDS = [1, 5, 6, 8, 9, 10, 11, 12]

# FISHEYE624 coefficients k1..k6, p1, p2, s1..s4 of an Aria-like RGB lens and a Quest-like
# monochrome lens (made up, checked monotone over the field of view below).
ARIA_RGB = [0.394, -0.365, -0.202, 1.55, -1.79, 0.610, 3.6e-4, -9e-5, -2.7e-4, 1e-4, 1.4e-4, -1e-4]
MONO = [-0.0117, 0.0423, -0.0341, 0.0128, -0.00213, 1.2e-4, 4e-4, 2e-4, -3e-4, 5e-5, 2e-4, -6e-5]

# Per headset: camera name -> (width, height, params, extrinsic offset from the first camera:
# rotation about y in degrees, translation in mm).
HEADSETS = {
    "quest3": {
        "gray1": (1280, 1024, [455.2, 455.9, 640.6, 511.8] + MONO, (0.0, [0.0, 0.0, 0.0])),
        "gray2": (1280, 1024, [452.7, 453.1, 638.9, 514.2] + MONO, (-35.0, [95.0, 0.0, 0.0])),
    },
    "aria": {
        "rgb": (1408, 1408, [609.79, 703.2, 705.1] + ARIA_RGB, (0.0, [0.0, 0.0, 0.0])),
        "gray1": (640, 480, [241.1, 318.4, 237.6] + MONO, (25.0, [-60.0, 10.0, 5.0])),
        "gray2": (640, 480, [240.3, 321.0, 240.9] + MONO, (-25.0, [60.0, 10.0, 5.0])),
    },
}
SCENES = {1288: "quest3", 1300: "quest3", 3365: "aria", 3401: "aria"}
IMAGES_PER_SCENE = 4


def rot_y(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def axis_angle(axis, deg):
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def check_monotone(coeffs, theta_max):
    k = coeffs[:6]
    th = np.linspace(0, theta_max, 2000)
    r2 = th * th
    radial = 1 + sum(k[i] * r2 ** (i + 1) for i in range(6))
    rd = th * radial
    assert np.all(np.diff(rd) > 0), "lens not monotone"


def fisheye624(params, v):
    """Window coordinates of camera-frame point v (the Hand Tracking Toolkit's FISHEYE624)."""
    if len(params) == 15:
        f, c, k = [params[0]] * 2, params[1:3], params[3:]
    else:
        f, c, k = params[0:2], params[2:4], params[4:]
    r = math.hypot(v[0], v[1])
    s = math.atan2(r, v[2]) / max(r, 2.0 ** -128)
    x, y = v[0] * s, v[1] * s
    r2 = min(x * x + y * y, math.pi ** 2)
    radial = 1 + sum(k[i] * r2 ** (i + 1) for i in range(6))
    x, y = x * radial, y * radial
    q2 = x * x + y * y
    tx = x + 2 * k[7] * x * y + k[6] * (q2 + 2 * x * x)
    ty = y + 2 * k[6] * x * y + k[7] * (q2 + 2 * y * y)
    tx, ty = tx + k[8] * q2 + k[9] * q2 * q2, ty + k[10] * q2 + k[11] * q2 * q2
    return tx * f[0] + c[0], ty * f[1] + c[1]


def masks(mrng, w, h, params, t, diameter, visib):
    """Full and visible masks of an instance: an ellipse about its projected centre, the visible
    part the pixels furthest along a random direction, as many as the visible fraction says."""
    cx, cy = fisheye624(params, t)
    f = params[0]
    a = f * 0.5 * diameter / np.linalg.norm(t)
    b = a * mrng.uniform(0.6, 1.0)
    phi = mrng.uniform(0, math.pi)
    ys, xs = np.mgrid[0:h, 0:w]
    u, v = xs - cx, ys - cy
    p = (u * math.cos(phi) + v * math.sin(phi)) / a
    q = (-u * math.sin(phi) + v * math.cos(phi)) / b
    full = p * p + q * q <= 1.0
    vis = np.zeros_like(full)
    idx = np.flatnonzero(full)
    if idx.size:
        d = mrng.normal(size=2)
        along = xs.ravel()[idx] * d[0] + ys.ravel()[idx] * d[1]
        keep = idx[np.argsort(-along, kind="stable")[: int(round(visib * idx.size))]]
        vis.ravel()[keep] = True
    return full, vis


def symmetries(info):
    out = [np.eye(4)]
    for s in info.get("symmetries_discrete", []):
        out.append(np.array(s, float).reshape(4, 4))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    mrng = np.random.default_rng(args.seed + 1000)  # masks only
    check_monotone(ARIA_RGB, 1.2)
    check_monotone(MONO, 1.4)
    info = json.load(open(os.path.join(HERE, "..", "lmo-synth", "models", "models_info.json")))
    targets, rows = [], []
    for scene_id, headset in SCENES.items():
        cams = HEADSETS[headset]
        first = next(iter(cams))
        sdir = os.path.join(HERE, "test", f"{scene_id:06d}")
        os.makedirs(sdir, exist_ok=True)
        files = {c: ({}, {}, {}) for c in cams}
        for im_id in range(IMAGES_PER_SCENE):
            targets.append({"scene_id": scene_id, "im_id": im_id})
            n = int(rng.integers(3, 6))
            objs = list(rng.choice(OBJ_IDS, size=n, replace=True))
            poses = []
            for obj in objs:
                off = math.radians(rng.uniform(0, 58))
                az = rng.uniform(0, 2 * math.pi)
                d = rng.uniform(350, 900)
                direction = np.array([math.sin(off) * math.cos(az), math.sin(off) * math.sin(az), math.cos(off)])
                poses.append((int(obj), random_rotation(rng), d * direction))
            visib = [float(round(v, 6)) for v in rng.uniform(0, 1, size=n)]
            visib[int(rng.integers(n))] = float(round(rng.uniform(0, 0.09), 6))  # one below 10 %: not a target
            for cam, (w, h, params, (ry, tt)) in cams.items():
                r_c, t_c = rot_y(ry), np.array(tt, float)  # first camera -> this camera
                gt, gti, camf = files[cam]
                gt[str(im_id)] = [
                    {"cam_R_m2c": (r_c @ r).flatten().tolist(), "cam_t_m2c": (r_c @ t + t_c).tolist(), "obj_id": o}
                    for o, r, t in poses
                ]
                gti[str(im_id)] = [{"visib_fract": v} for v in visib]
                camf[str(im_id)] = {
                    "cam_model": {
                        "image_height": h, "image_width": w, "label": f"{headset}-{cam}",
                        "projection_model_type": "CameraModelType.FISHEYE624", "projection_params": params,
                    },
                    "cam_R_w2c": r_c.flatten().tolist(), "cam_t_w2c": t_c.tolist(),
                }
            # Masks and estimates for the evaluated camera (gray1 / rgb, the first listed).
            eval_cam = first
            r_e, t_e = rot_y(cams[eval_cam][3][0]), np.array(cams[eval_cam][3][1], float)
            w, h, params = cams[eval_cam][:3]
            for gt_id, ((o, _, t), v) in enumerate(zip(poses, visib)):
                full, vis = masks(mrng, w, h, params, r_e @ t + t_e, info[str(o)]["diameter"], v)
                for sub, m in ((f"mask_{eval_cam}", full), (f"mask_visib_{eval_cam}", vis)):
                    os.makedirs(os.path.join(sdir, sub), exist_ok=True)
                    imageio.imwrite(os.path.join(sdir, sub, f"{im_id:06d}_{gt_id:06d}.png"), m.astype(np.uint8) * 255)
            time = round(float(rng.uniform(0.05, 0.4)), 3)
            present = set()
            for o, r, t in poses:
                r, t = r_e @ r, r_e @ t + t_e
                present.add(o)
                u = rng.uniform()
                if u < 0.12:
                    continue  # missed
                if u < 0.55:
                    angle, sigma = rng.exponential(3.0), rng.exponential(4.0)  # good
                elif u < 0.85:
                    angle, sigma = rng.exponential(15.0), rng.exponential(15.0)  # rough
                else:
                    angle, sigma = rng.uniform(20, 180), rng.exponential(40.0)  # wrong
                syms = symmetries(info[str(o)])
                s = syms[int(rng.integers(len(syms)))]
                r_sym = r @ s[:3, :3]
                t_sym = r @ s[:3, 3] + t
                r_est = axis_angle(rng.normal(size=3), angle) @ r_sym
                t_est = t_sym + rng.normal(scale=sigma, size=3) * np.array([1, 1, 2.5])
                rows.append((scene_id, im_id, o, float(rng.uniform(0.05, 1)), r_est, t_est, time))
                if rng.uniform() < 0.1:  # duplicate with a lower score
                    rows.append((scene_id, im_id, o, float(rng.uniform(0.01, 0.05)), r_est, t_est + rng.normal(scale=3, size=3), time))
            for _ in range(int(rng.integers(0, 3))):  # false detections: present or absent objects
                o = int(rng.choice(OBJ_IDS))
                off, az = math.radians(rng.uniform(0, 50)), rng.uniform(0, 2 * math.pi)
                d = rng.uniform(300, 1000)
                t = d * np.array([math.sin(off) * math.cos(az), math.sin(off) * math.sin(az), math.cos(off)])
                rows.append((scene_id, im_id, o, float(rng.uniform(0.0, 0.6)), random_rotation(rng), t, time))
        for cam, (gt, gti, camf) in files.items():
            for stem, data in (("scene_gt", gt), ("scene_gt_info", gti), ("scene_camera", camf)):
                with open(os.path.join(sdir, f"{stem}_{cam}.json"), "w") as f:
                    json.dump(data, f, indent=1)
    # One estimate behind the camera (z < 0): projected as the lens model projects it.
    s0, i0, o0, _, r0, t0, time0 = rows[0]
    rows.append((s0, i0, o0, 0.5, r0, t0 * np.array([1, 1, -1]), time0))
    with open(os.path.join(HERE, "test_targets_bop24.json"), "w") as f:
        json.dump(targets, f, indent=1)
    with open(os.path.join(HERE, "estimates.csv"), "w") as f:
        f.write("scene_id,im_id,obj_id,score,R,t,time\n")
        for scene_id, im_id, o, score, r, t, time in rows:
            rs = " ".join(f"{v:.9f}" for v in r.flatten())
            ts = " ".join(f"{v:.6f}" for v in t)
            f.write(f"{scene_id},{im_id},{o},{score:.6f},{rs},{ts},{time}\n")
    print(f"{len(SCENES)} scenes, {len(targets)} images, {len(rows)} estimates")


if __name__ == "__main__":
    main()
