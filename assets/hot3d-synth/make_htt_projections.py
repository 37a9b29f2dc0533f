#!/usr/bin/env python3
"""Writes htt_projections.json: camera-frame points projected by the Hand Tracking Toolkit's camera
models (facebookresearch/hand_tracking_toolkit, hand_tracking_toolkit.camera), the models the BOP
toolkit projects HOT3D with. src/lens.rs is tested against it (tests/eval.rs).

    PYTHONPATH=HAND_TRACKING_TOOLKIT_CHECKOUT python3 make_htt_projections.py

Every model of its `model_by_name`, seeded coefficients of realistic size, points from on the axis to
80 degrees off it (and one behind a fisheye). numpy and scipy.
"""
import json
import os

import numpy as np
from hand_tracking_toolkit.camera import model_by_name

HERE = os.path.dirname(os.path.abspath(__file__))
rng = np.random.default_rng(5)
N_COEFFS = {"PinholePlane": 0, "OpenCV": 5, "Rational": 8, "OculusVisionFishEye": 8, "OculusVisionFishEye62": 8,
            "OculusVisionFishEye624": 12, "CameraModelType.FISHEYE624": 12}
SCALE = {0: 0.0, 5: [0.05, 0.02, 0.01, 1e-3, 1e-3], 8: 0.02, 12: 0.02}
cases = []
for name, n in N_COEFFS.items():
    for aria in ([False, True] if name == "CameraModelType.FISHEYE624" else [False]):
        scale = np.asarray(SCALE[n] if n != 5 else SCALE[5])
        coeffs = (rng.normal(size=n) * scale).tolist() if n else []
        fisheye = "Fish" in name or "FISHEYE" in name
        params = ([610.5, 703.25, 705.75] if aria else [455.5, 456.25, 640.5, 511.75]) + coeffs
        f, c = ((params[0], params[0]), params[1:3]) if aria else (params[0:2], params[2:4])
        cam = model_by_name[name](1408, 1408, f, c, coeffs)
        max_off = 80 if fisheye else 55
        pts = []
        for off in np.linspace(0, max_off, 9):
            for az in (0.3, 2.1, 4.4):
                d = rng.uniform(200, 1500)
                o = np.radians(off)
                pts.append([d * np.sin(o) * np.cos(az), d * np.sin(o) * np.sin(az), d * np.cos(o)])
        if fisheye:
            pts.append([300.0, -200.0, -50.0])
        pts = np.asarray(pts)
        win = cam.eye_to_window(pts)
        cases.append({"projection_model_type": name, "projection_params": params, "image_width": 1408,
                      "image_height": 1408, "points": pts.tolist(), "window": win.tolist()})
json.dump({"_about": "hand_tracking_toolkit.camera eye_to_window (facebookresearch/hand_tracking_toolkit ffb20d0) "
           "of camera-frame points; make_htt_projections.py", "cases": cases},
          open(os.path.join(HERE, "htt_projections.json"), "w"), indent=1)
print(len(cases), "cameras")
