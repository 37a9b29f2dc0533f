"""The module's functions: plane fitting, scene checks, stable poses,
hypotheses, reading BOP frames and BOP evaluation."""

import _thread
import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import plausible as pl
from conftest import ROOT, run

ASSETS = ROOT / "assets"


def test_fit_plane_finds_the_demo_table(demo):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    fit = pl.fit_plane(K, depth, mask)
    truth = json.loads((demo / "plane.json").read_text())
    n = np.asarray(truth["normal"]) / np.linalg.norm(truth["normal"])
    assert abs(np.dot(fit["normal"], n)) > 0.999
    assert abs(np.dot(fit["normal"], fit["point"]) - np.dot(n, np.asarray(truth["point"]) * 1e-3)) < 2e-3
    assert fit["inliers"] > 0.5 * fit["candidates"]
    with pytest.raises(ValueError):
        pl.fit_plane(K, depth, mask, inlier=0)


def test_check_matches_the_cli_on_the_shipped_stack():
    scene = ASSETS / "physics" / "stack.json"
    objects = pl.check(scene)
    cli = json.loads(run("check", str(scene), "--json").stdout)["objects"]
    assert [o["name"] for o in objects] == [o["name"] for o in cli]
    for ours, theirs in zip(objects, cli):
        assert ours["verdict"] == theirs["verdict"], ours["name"]
        assert ours["intersecting"] == theirs["intersecting"]
        assert ours["min_distance"] == pytest.approx(theirs["min_distance"], abs=1e-12)
    as_dict = json.loads(scene.read_text())
    for o in as_dict["objects"]:
        o["mesh"] = str(scene.parent / o["mesh"])
    assert [o["verdict"] for o in pl.check(as_dict)] == [o["verdict"] for o in objects]
    with pytest.raises(ValueError):
        pl.check({"objects": "nope"})
    with pytest.raises(FileNotFoundError):
        pl.check(ASSETS / "no-such-scene.json")


def test_stable_poses_of_a_cube_are_its_six_faces():
    poses = pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=120, seed=3)
    faces = [c for c in poses if c["kind"] == "pose"]
    assert len(faces) == 6, poses
    assert sum(c["probability"] for c in poses) == pytest.approx(1.0)
    for c in faces:
        lo, hi = c["ci95"]
        assert lo < 1 / 6 < hi
        R = c["R_model_to_plane"]
        assert R.shape == (3, 3) and np.allclose(R @ R.T, np.eye(3), atol=1e-9)
    again = pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=120, seed=3)
    assert [c["count"] for c in again] == [c["count"] for c in poses]
    with pytest.raises(ValueError):
        pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=0)
    with pytest.raises(ValueError):
        pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=8, threads=100_000)


def _ends_on_ctrl_c(call, within: float) -> None:
    """Runs ``call`` with Ctrl-C as the interpreter sees it (the SIGINT flag
    set from another thread) 0.5 s in: it must raise KeyboardInterrupt, and
    within ``within`` seconds of its start."""
    start = time.monotonic()
    timer = threading.Timer(0.5, _thread.interrupt_main)
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        call()
    timer.join()
    assert time.monotonic() - start < within


def test_long_calls_end_on_ctrl_c(demo):
    # Ten million drops take more than an hour; Ctrl-C ends the call within
    # a world of drops, not after all of them.
    _ends_on_ctrl_c(lambda: pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=10_000_000), within=30)
    # The demo's hypotheses 256 times (a million poses) take minutes on the
    # CPU twin; Ctrl-C ends the call after the chunk of 4096 in flight. The
    # scorer stays usable.
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    scorer = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu")
    p = json.loads((demo / "poses.json").read_text())
    R = np.tile(np.array([q["cam_R_m2c"] for q in p], dtype=float).reshape(-1, 3, 3), (256, 1, 1))
    t = np.tile(np.array([q["cam_t_m2c"] for q in p], dtype=float) * 1e-3, (256, 1))
    _ends_on_ctrl_c(lambda: scorer.score(R, t), within=30)
    assert len(scorer.score(R[:8], t[:8])) == 8
    # 2000 hypotheses x 100 ICP steps take many minutes; Ctrl-C ends the
    # refinement at its next step.
    R0, t0 = R[0], t[0]
    _ends_on_ctrl_c(lambda: pl.refine(K, depth, [{"mesh": demo / "duck_0.15m.obj", "mask": mask, "R": np.tile(R0, (2000, 1, 1)), "t": np.tile(t0, (2000, 1))}],
                  method="ref", steps=100, device="cpu"), within=30)
    # A million RANSAC hypotheses on 20,000 points take many seconds;
    # Ctrl-C ends the fit at the next one.
    _ends_on_ctrl_c(lambda: pl.fit_plane(K, depth, mask, iterations=1_000_000), within=5)
    # 200 cubes at 20,000 samples each take about half a minute; Ctrl-C
    # ends the check at the next object.
    cube = str(ASSETS / "physics" / "cube.obj")
    objects = [{"name": f"c{i}", "mesh": cube, "units": "m", "R": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t": [0.1 * (i % 20), 0.1 * (i // 20), 0.035]} for i in range(200)]
    scene = {"gravity": [0, 0, -9.81], "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}], "objects": objects}
    _ends_on_ctrl_c(lambda: pl.check(scene, simulate=True, samples=20_000), within=5)


def test_hypotheses_on_the_plane_contain_a_good_one(demo):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    mesh = pl.load_mesh(demo / "duck_0.15m.obj")
    plane = pl.fit_plane(K, depth, mask)
    hyp = pl.hypotheses(mesh, K, depth, mask, plane, yaw_steps=24)
    n = len(hyp["t"])
    assert hyp["R"].shape == (n, 3, 3) and hyp["offset"].shape == (n, 2) and n > 0
    rec = pl.Scorer(mesh, K, depth, mask, device="cpu").score(hyp["R"], hyp["t"], plane=plane)
    assert rec["score"].max() > 0.6
    stable = pl.stable_poses(mesh, drops=60, seed=1)
    hyp2 = pl.hypotheses(mesh, K, depth, mask, plane, stable=stable, yaw_steps=12)
    assert len(hyp2["t"]) >= 12


def test_read_frame_checks_files_against_each_other(demo, tmp_path):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    assert K.shape == (3, 3) and depth.shape == mask.shape and depth.dtype == np.float32
    with pytest.raises(FileNotFoundError):
        pl.read_frame(demo / "camera.json", tmp_path / "none.png")
    with pytest.raises(ValueError):
        pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "alignment.png")
    with pytest.raises(ValueError, match="nothing to pick"):
        pl.read_frame(demo / "camera.json", demo / "depth.png", frame=3)


def test_eval_matches_the_bop_toolkit_on_the_shipped_subset():
    ds = ASSETS / "lmo-synth"
    ref = json.loads((ds / "reference_perturbed.json").read_text())
    rep = pl.eval(ds, ds / "perturbed.csv", dataset_name="lmo", device="cpu")
    assert rep["ar_mssd"] == pytest.approx(ref["AR_MSSD"], abs=1e-9)
    assert rep["ar_mspd"] == pytest.approx(ref["AR_MSPD"], abs=1e-9)
    assert rep["ar"] == pytest.approx(ref["AR"], abs=2e-3)
    with pytest.raises(ValueError):
        pl.eval(ds, ds / "perturbed.csv", errors=["nope"])
    with pytest.raises(ValueError):
        pl.eval(ds, ds / "perturbed.csv", dataset_name="not-a-dataset")


def test_eval_detection_matches_the_bop_toolkit_bit_for_bit():
    ds = ASSETS / "lmo-synth"
    ref = json.loads((ds / "reference_detection.json").read_text())["detection.csv"]
    rep = pl.eval(ds, ds / "detection.csv", task="detection", dataset_name="lmo", device="cpu")
    assert rep["task"] == "detection"
    for ours, theirs in [("ap", "bop24_mAP"), ("ap_mssd", "bop24_mAP_mssd"), ("ap_mspd", "bop24_mAP_mspd"), ("ap_mssd_mm", "bop24_mAP_mssd_mm")]:
        assert rep[ours] == ref[theirs], ours
    with pytest.raises(ValueError, match="localization or detection"):
        pl.eval(ds, ds / "detection.csv", task="tracking")
    with pytest.raises(ValueError, match="vsd"):
        pl.eval(ds, ds / "detection.csv", task="detection", errors=["vsd"])
    with pytest.raises(ValueError, match="max_estimates_per_image"):
        pl.eval(ds, ds / "detection.csv", task="detection", max_estimates_per_image=0)


def test_eval_hot3d_fisheye_cameras_match_the_bop_toolkit_bit_for_bit():
    # HOT3D's layout: FISHEYE624 cam_model cameras, the camera chosen per scene.
    ds = ASSETS / "hot3d-synth"
    ref = json.loads((ds / "reference_detection.json").read_text())
    rep = pl.eval(ds, ds / "estimates.csv", task="detection", dataset_name="hot3d", device="cpu")
    for ours, theirs in [("ap", "bop24_mAP"), ("ap_mssd", "bop24_mAP_mssd"), ("ap_mspd", "bop24_mAP_mspd"), ("ap_mssd_mm", "bop24_mAP_mssd_mm")]:
        assert rep[ours] == ref[theirs], ours
    with pytest.raises(ValueError, match="fisheye 624 lens model"):
        pl.eval(ds, ds / "estimates.csv", dataset_name="hot3d", errors=["vsd"])


def test_eval_2d_tasks_match_the_bop_toolkit_bit_for_bit():
    ds = ASSETS / "lmo-synth"
    ref = json.loads((ds / "reference_coco.json").read_text())["coco.json"]
    for task, boxes, key in [("segm", None, "segm"), ("bbox", None, "bbox"), ("bbox", "modal", "bbox_modal")]:
        rep = pl.eval(ds, ds / "coco.json", task=task, boxes=boxes, dataset_name="lmo")
        assert rep["task"] == task
        assert rep["scores"] == ref[key], key
    with pytest.raises(ValueError, match="boxes is for task='bbox'"):
        pl.eval(ds, ds / "coco.json", task="segm", boxes="modal")
    with pytest.raises(ValueError, match="amodal or modal"):
        pl.eval(ds, ds / "coco.json", task="bbox", boxes="square")
    with pytest.raises(ValueError, match="6D pose tasks"):
        pl.eval(ds, ds / "coco.json", task="bbox", errors=["vsd"])
    with pytest.raises(ValueError, match=r"\.json"):
        pl.eval(ds, ds / "perturbed.csv", task="segm")


def rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def demo_truth(demo):
    p = json.loads((demo / "poses.json").read_text())[0]  # the demo's first hypothesis is the true pose
    return np.array(p["cam_R_m2c"], float).reshape(3, 3), np.array(p["cam_t_m2c"], float) * 1e-3


@pytest.mark.parametrize("method", ["ref", "pir", "sir", "rir"])
def test_refine_brings_perturbed_poses_back(demo, method):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    R0, t0 = demo_truth(demo)
    rng = np.random.default_rng(7)
    R = np.stack([rotation(rng.normal(size=3), np.deg2rad(4)) @ R0 for _ in range(3)])
    t = t0 + rng.normal(size=(3, 3)) * 0.004
    out = pl.refine(K, depth * 1000, [{"mesh": demo / "duck_0.15m.obj", "mask": mask, "R": R, "t": t * 1000, "scores": [0.1, 0.9, 0.5]}],
                    method=method, units="mm", device="cpu")
    o = out["objects"][0]
    assert o["R"].shape == (3, 3, 3) and o["t"].shape == (3, 3) and o["score"].shape == (3,)
    err_mm = np.linalg.norm(o["t"] - t0 * 1000, axis=1)
    assert err_mm.min() < 1.0, err_mm
    assert out["support"] == [None] and out["order"] == [0]
    if method != "ref":
        assert out["plane"] is not None and out["plane"]["units"] == "mm"


def test_estimate_finds_the_duck_on_the_table(demo):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    R0, t0 = demo_truth(demo)
    out = pl.estimate(K, depth, [{"mesh": demo / "duck_0.15m.obj", "mask": mask}], device="cpu")
    best = out["best"][0]
    assert np.linalg.norm(best["t"] - t0) < 0.005
    angle = np.degrees(np.arccos(np.clip((np.trace(best["R"].T @ R0) - 1) / 2, -1, 1)))
    assert angle < 5, angle
    assert best["score"] > 0.8


def test_estimate_warns_of_a_mesh_in_other_units(demo, tmp_path):
    # The duck in centimetres read as metres: 15 m across where the mask
    # sees about 0.1 m of it. Warned about per object (a mesh smaller than
    # what its mask sees is not refused here: a loose mask must not end the
    # call), and the call goes on.
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    lines = (demo / "duck_0.15m.obj").read_text().splitlines()
    big = tmp_path / "duck_cm.obj"
    big.write_text("\n".join("v " + " ".join(str(float(c) * 100) for c in l.split()[1:4]) if l.startswith("v ") else l for l in lines))
    with pytest.warns(UserWarning, match="object 0: the mesh is 15"):
        out = pl.estimate(K, depth, [{"mesh": big, "mask": mask}], mesh_units="m", top=1, steps=1, yaw_steps=4, device="cpu")
    assert len(out["best"]) == 1


def test_refine_and_estimate_refuse_bad_input(demo):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    R0, t0 = demo_truth(demo)
    mesh = demo / "duck_0.15m.obj"
    ok = {"mesh": mesh, "mask": mask, "R": R0[None], "t": t0[None]}
    cases = {
        "method": lambda: pl.refine(K, depth, [ok], method="nope"),
        "no objects": lambda: pl.refine(K, depth, []),
        "no hypotheses": lambda: pl.refine(K, depth, [{"mesh": mesh, "mask": mask}]),
        "mask size": lambda: pl.refine(K, depth, [dict(ok, mask=mask[1:])]),
        "scores length": lambda: pl.refine(K, depth, [dict(ok, scores=[1, 2])]),
        "budget with ref": lambda: pl.refine(K, depth, [ok], method="ref", budget=4),
        "top": lambda: pl.estimate(K, depth, [{"mesh": mesh, "mask": mask}], top=0),
        "yaw steps": lambda: pl.estimate(K, depth, [{"mesh": mesh, "mask": mask}], yaw_steps=100000),
        "stable not dicts": lambda: pl.estimate(K, depth, [{"mesh": mesh, "mask": mask, "stable": [3]}]),
        "stable NaN": lambda: pl.estimate(K, depth, [{"mesh": mesh, "mask": mask, "stable": [{"probability": 1.0, "R_model_to_plane": np.full((3, 3), np.nan)}]}]),
        "stable probability": lambda: pl.estimate(K, depth, [{"mesh": mesh, "mask": mask, "stable": [{"probability": "high", "R_model_to_plane": np.eye(3)}]}]),
    }
    for what, call in cases.items():
        with pytest.raises(ValueError):
            call()


def test_files_are_read_capped_and_binary_ones_named(demo, tmp_path):
    """Every file the Python side reads (a scene, a plane, a stable-pose
    export) is read to a cap: an endless device is an error, not memory
    growing until the process is killed; a regular file over the cap is
    refused by its size; a binary file is a ValueError naming the argument."""
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    mesh = demo / "duck_0.15m.obj"
    s = pl.Scorer(mesh, K, depth, mask, device="cpu")
    R, t = demo_truth(demo)
    if Path("/dev/zero").exists():
        with pytest.raises(ValueError, match="scene '/dev/zero': not a regular file, and more than the 64 MiB"):
            pl.check("/dev/zero")
        with pytest.raises(ValueError, match="plane '/dev/zero': not a regular file, and more than the 1 MiB"):
            s.score(R, t, plane="/dev/zero")
        with pytest.raises(ValueError, match="stable '/dev/zero': not a regular file, and more than the 256 MiB"):
            pl.hypotheses(mesh, K, depth, mask, demo / "plane.json", stable="/dev/zero")
    big = tmp_path / "big.json"
    with open(big, "wb") as f:
        f.truncate((64 << 20) + 1)  # sparse: refused by its size, never read
    with pytest.raises(ValueError, match="a file of 67108865 bytes, more than the 64 MiB"):
        pl.check(big)
    with pytest.raises(ValueError, match="plane .*a file of 67108865 bytes, more than the 1 MiB"):
        s.score(R, t, plane=big)
    with pytest.raises(ValueError, match=r"scene '.*depth\.png': not a UTF-8 text file"):
        pl.check(demo / "depth.png")
    with pytest.raises(ValueError, match=r"plane '.*depth\.png': not a UTF-8 text file"):
        s.score(R, t, plane=demo / "depth.png")
    with pytest.raises(ValueError, match=r"object 0 stable '.*depth\.png': not a UTF-8 text file"):
        pl.estimate(K, depth, [{"mesh": mesh, "mask": mask, "stable": demo / "depth.png"}], device="cpu")
    with pytest.raises(IsADirectoryError, match="scene .*is a folder"):
        pl.check(tmp_path)
    with pytest.raises(FileNotFoundError, match="plane .*not found"):
        s.score(R, t, plane=tmp_path / "none.json")
    # A byte order mark (Windows editors) is dropped, as the native readers drop it.
    bom = tmp_path / "plane.json"
    bom.write_bytes(b"\xef\xbb\xbf" + (demo / "plane.json").read_bytes())
    assert s.score(R, t, plane=bom)["verdict"][0] == "plausible"


def test_stable_poses_of_another_mesh_warn_as_an_export_does(demo):
    """A stable_poses() list keeps its mesh's geometry hash: another mesh's
    list warns, as the same poses given as an export do; the mesh's own
    list does not."""
    import warnings

    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    mesh = demo / "duck_0.15m.obj"
    plane = pl.fit_plane(K, depth, mask)
    cube = pl.stable_poses(ASSETS / "physics" / "cube.obj", drops=50)
    with pytest.warns(UserWarning, match="matches neither the geometry of duck_0.15m.obj"):
        pl.hypotheses(mesh, K, depth, mask, plane, stable=cube, yaw_steps=4)
    with warnings.catch_warnings():
        # The warning as an error: estimate stops there, before its work.
        warnings.simplefilter("error")
        with pytest.raises(UserWarning, match="matches neither the geometry of duck_0.15m.obj"):
            pl.estimate(K, depth, [{"mesh": mesh, "mask": mask, "stable": cube}], device="cpu")
        own = pl.stable_poses(mesh, drops=30, seed=1)
        assert len(pl.hypotheses(mesh, K, depth, mask, plane, stable=own, yaw_steps=4)["t"]) > 0
    mixed = [dict(cube[0]), dict(own[0], probability=0.0)]
    with pytest.raises(ValueError, match="stable: its entries come from 2 different meshes"):
        pl.hypotheses(mesh, K, depth, mask, plane, stable=mixed)


def test_refine_objects_name_what_is_wrong(demo):
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    R0, t0 = demo_truth(demo)
    mesh = demo / "duck_0.15m.obj"
    R, t = np.tile(R0, (3, 1, 1)), np.tile(t0, (3, 1))
    with pytest.raises(ValueError, match="object 0: mask None"):
        pl.refine(K, depth, [{"mesh": mesh, "mask": None, "R": R, "t": t}], device="cpu")
    with pytest.raises(ValueError, match="object 0: mask None"):
        pl.estimate(K, depth, [{"mesh": mesh, "mask": None}], device="cpu")
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, t
    with pytest.raises(ValueError, match='object 0: give its hypotheses as "R" and "t" or as "poses" .*not both'):
        pl.refine(K, depth, [{"mesh": mesh, "mask": mask, "poses": T, "R": R, "t": t}], device="cpu")
    # physics=False means something to sir and rir only (as the CLI's --no-physics).
    for method in ("ref", "pir"):
        with pytest.raises(ValueError, match="without physics is for sir and rir"):
            pl.refine(K, depth, [{"mesh": mesh, "mask": mask, "R": R, "t": t}], method=method, physics=False, device="cpu")


def test_options_name_themselves(demo):
    """Numbers given as strings or None, negative counts and numpy values
    in a scene dict: each error names its argument."""
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    mesh = demo / "duck_0.15m.obj"
    stack = ASSETS / "physics" / "stack.json"
    for name in ("samples", "seed", "sdf_resolution"):
        with pytest.raises(ValueError, match=f"{name} -1: expected a non-negative integer"):
            pl.check(stack, **{name: -1})
    for name in ("epsilon", "friction"):
        with pytest.raises(TypeError, match=f"{name} 'x': expected a number"):
            pl.check(stack, **{name: "x"})
    with pytest.raises(TypeError, match="inlier '0.005': expected a number"):
        pl.fit_plane(K, depth, mask, inlier="0.005")
    with pytest.raises(TypeError, match="grid_step 'x': expected a number"):
        pl.hypotheses(mesh, K, depth, mask, demo / "plane.json", grid_step="x")
    with pytest.raises(TypeError, match="add_threshold None: expected a number"):
        pl.eval(ASSETS / "lmo-synth", ASSETS / "lmo-synth" / "perturbed.csv", add_threshold=None)
    # numpy arrays and scalars in a scene dict are written as JSON numbers.
    scene = json.loads(stack.read_text())
    for o in scene["objects"]:
        o["mesh"] = stack.parent / o["mesh"]
        o["R"], o["t"] = np.asarray(o["R"], dtype=np.float32).reshape(3, 3), [np.float64(x) for x in o["t"]]
    assert [o["verdict"] for o in pl.check(scene)] == [o["verdict"] for o in pl.check(stack)]
    with pytest.raises(ValueError, match="scene: cannot be written as JSON"):
        pl.check(dict(scene, gravity=[0, 0, float("nan")]))
    with pytest.raises(TypeError, match="scene: object .*not a JSON value"):
        pl.check(dict(scene, gravity=object()))
    # A folder as a mesh is said to be one.
    tmp = {"objects": [dict(scene["objects"][0], mesh=str(stack.parent))]}
    with pytest.raises(ValueError, match="is a folder, not a mesh file"):
        pl.check(tmp)


def test_ctrl_c_ends_a_high_res_score_promptly(demo):
    # At res=1024 a pose costs 64 times the pixels of the default 128: the
    # first chunk is 64 poses, not 4096, so Ctrl-C ends the call after about
    # a second on the CPU twin (a thousand poses take many seconds).
    K, depth, mask = pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")
    scorer = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu", res=1024)
    R0, t0 = demo_truth(demo)
    R, t = np.tile(R0, (1000, 1, 1)), np.tile(t0, (1000, 1))
    _ends_on_ctrl_c(lambda: scorer.score(R, t), within=5)
    assert len(scorer.score(R[:2], t[:2])) == 2
