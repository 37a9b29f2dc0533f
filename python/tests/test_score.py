"""`plausible.Scorer`: parity with `plausible score` on the demo's inputs,
dtypes and shapes, reuse across calls, and bad input as ValueError."""

import json
from pathlib import Path

import numpy as np
import pytest

import plausible as pl
from conftest import gpu_required, run

VISUAL = ["score", "a_d", "a_n", "valid", "rendered", "observed", "rank"]
PHYSICAL = ["verdict", "intersecting", "contact", "supported", "min_distance", "feasible", "stable"]


def frame(demo: Path):
    return pl.read_frame(demo / "camera.json", demo / "depth.png", demo / "mask.png")


def poses(demo: Path):
    p = json.loads((demo / "poses.json").read_text())
    R = np.array([q["cam_R_m2c"] for q in p], dtype=float).reshape(-1, 3, 3)
    t = np.array([q["cam_t_m2c"] for q in p], dtype=float) * 1e-3
    return R, t


def cli_records(demo: Path, tmp_path: Path, device: str, physics: bool):
    out = tmp_path / f"cli_{device}_{physics}.json"
    args = ["score", "--mesh", str(demo / "duck_0.15m.obj"), "--camera", str(demo / "camera.json"), "--depth", str(demo / "depth.png"),
            "--mask", str(demo / "mask.png"), "--poses", str(demo / "poses.json"), "--device", device, "--quiet", "--out", str(out)]
    if physics:
        args += ["--plane", str(demo / "plane.json"), "--physics"]
    run(*args)
    return json.loads(out.read_text())


def assert_same(rec, ref, fields, exact=True):
    assert len(rec) == len(ref)
    for name in fields:
        ours = rec[name]
        theirs = np.array([r[name] for r in ref], dtype=ours.dtype)
        if exact or ours.dtype.kind not in "f":
            mism = np.flatnonzero(ours != theirs)
            assert mism.size == 0, f"{name}: {mism.size} records differ, first {mism[:5]}: {ours[mism[:3]]} vs {theirs[mism[:3]]}"
        else:
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-5, err_msg=name)


@pytest.mark.parametrize("physics", [False, True])
def test_cpu_scores_match_the_cli_exactly(demo, tmp_path, physics):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    assert len(R) == 4096
    scorer = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu")
    rec = scorer.score(R, t, plane=demo / "plane.json") if physics else scorer.score(R, t)
    assert_same(rec, cli_records(demo, tmp_path, "cpu", physics), VISUAL + (PHYSICAL if physics else []))


def gpu_scorer(*args, **kw):
    try:
        return pl.Scorer(*args, device="gpu", **kw)
    except RuntimeError as e:
        if gpu_required():
            raise
        pytest.skip(f"no GPU adapter: {e}")


def test_gpu_scores_match_the_cli(demo, tmp_path):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    scorer = gpu_scorer(demo / "duck_0.15m.obj", K, depth, mask)
    assert "CPU" not in scorer.device
    rec = scorer.score(R, t)
    ref = cli_records(demo, tmp_path, "gpu", False)
    # Same kernel, same batches: the counts agree exactly, the means to f32 rounding.
    assert_same(rec, ref, ["valid", "rendered", "observed"])
    assert_same(rec, ref, ["score", "a_d", "a_n"], exact=False)


def test_gpu_and_cpu_twin_agree(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    gpu = gpu_scorer(demo / "duck_0.15m.obj", K, depth, mask).score(R[:512], t[:512])
    cpu = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu").score(R[:512], t[:512])
    np.testing.assert_allclose(gpu["score"], cpu["score"], atol=2e-3)


def test_records_are_a_structured_array_in_input_order(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    scorer = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu")
    rec = scorer.score(R[:64], t[:64])
    assert rec.dtype == pl.SCORE_DTYPE and rec.shape == (64,)
    assert sorted(rec["rank"]) == list(range(1, 65))
    assert rec["rank"][0] == 1  # the demo's first hypothesis is the true pose
    # 4x4 matrices, one pose, millimetres and reuse give the same records.
    T = np.tile(np.eye(4), (64, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R[:64], t[:64]
    np.testing.assert_array_equal(scorer.score(T)["score"], rec["score"])
    one = scorer.score(R[5], t[5])
    assert one.shape == (1,) and one["score"][0] == rec["score"][5]
    mm = pl.Scorer(demo / "duck_0.15m.obj", K, depth * 1000, mask, units="mm", device="cpu")
    np.testing.assert_allclose(mm.score(R[:64], t[:64] * 1000)["score"], rec["score"], atol=1e-6)
    chunks = np.concatenate([scorer.score(R[i:i + 16], t[i:i + 16])["score"] for i in range(0, 64, 16)])
    np.testing.assert_array_equal(chunks, rec["score"])
    # Level of detail: auto renders a simplification within a quarter of a pixel;
    # off the full mesh; a count about that many triangles.
    assert "of 4212 triangles" in scorer.scoring_mesh, scorer.scoring_mesh
    full = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu", lod="off")
    assert "full 4212" in full.scoring_mesh
    np.testing.assert_allclose(full.score(R[:64], t[:64])["score"], rec["score"], atol=0.02)
    assert "300 of 4212" in pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu", lod=300).scoring_mesh
    phys = scorer.score(R[:8], t[:8], plane=demo / "plane.json")
    assert phys.dtype == pl.PHYSICS_DTYPE
    assert phys["verdict"][0] == "plausible"


def test_meshes_from_arrays_and_trimesh_like_objects(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    m = pl.load_mesh(demo / "duck_0.15m.obj")
    assert m.vertices.shape[1] == 3 and m.faces.shape == (len(m), 3)

    class TrimeshLike:
        vertices, faces = m.vertices, m.faces.astype(np.int64)

    a = pl.Scorer(m, K, depth, mask, device="cpu").score(R[:32], t[:32])
    b = pl.Scorer((m.vertices, m.faces), K, depth, mask, device="cpu").score(R[:32], t[:32])
    c = pl.Scorer(TrimeshLike(), K, depth, mask, device="cpu").score(R[:32], t[:32])
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)


def test_bad_input_raises_value_error(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    mesh = demo / "duck_0.15m.obj"
    s = pl.Scorer(mesh, K, depth, mask, device="cpu")
    bad_R = R[:2].copy()
    bad_R[1] *= 2
    nan_t = t[:2].copy()
    nan_t[0, 1] = np.nan
    behind = t[:2].copy()
    behind[:, 2] = -1
    cases = {
        "R shape": lambda: s.score(R[:3, :2], t[:3]),
        "N mismatch": lambda: s.score(R[:3], t[:2]),
        "scaled rotation": lambda: s.score(bad_R, t[:2]),
        "NaN": lambda: s.score(R[:2], nan_t),
        "behind the camera": lambda: s.score(R[:2], behind),
        "physics without plane": lambda: s.score(R[:2], t[:2], physics=True),
        "plane through the camera": lambda: s.score(R[:2], t[:2], plane=([0, 0, 0], [0, 0, 1])),
        "zero normal": lambda: s.score(R[:2], t[:2], plane=([0, 0, 1], [0, 0, 0])),
        "epsilon": lambda: s.score(R[:2], t[:2], plane=demo / "plane.json", epsilon=float("nan")),
        "negative seed": lambda: s.score(R[:2], t[:2], plane=demo / "plane.json", seed=-1),
        "samples": lambda: s.score(R[:2], t[:2], plane=demo / "plane.json", samples=0),
        "tau": lambda: pl.Scorer(mesh, K, depth, mask, tau=-1, device="cpu"),
        "tau nan": lambda: pl.Scorer(mesh, K, depth, mask, tau=float("nan"), device="cpu"),
        "units": lambda: pl.Scorer(mesh, K, depth, mask, units="cm", device="cpu"),
        "res": lambda: pl.Scorer(mesh, K, depth, mask, res=100000, device="cpu"),
        "device": lambda: pl.Scorer(mesh, K, depth, mask, device="tpu"),
        "mask size": lambda: pl.Scorer(mesh, K, depth, mask[:-1], device="cpu"),
        "empty mask": lambda: pl.Scorer(mesh, K, depth, np.zeros_like(mask), device="cpu"),
        "negative depth": lambda: pl.Scorer(mesh, K, -depth, mask, device="cpu"),
        "depth in mm as m": lambda: pl.Scorer(mesh, K, depth * 1000, mask, device="cpu"),
        "depth 100x too small": lambda: pl.Scorer(mesh, K, depth / 100, mask, device="cpu"),
        "t in mm": lambda: s.score(R[:2], t[:2] * 1000),
        "t at the camera": lambda: s.score(R[:2], t[:2] * 0.01),
        "K": lambda: pl.Scorer(mesh, np.eye(2), depth, mask, device="cpu"),
        "K negative focal": lambda: pl.Scorer(mesh, -K, depth, mask, device="cpu"),
        "depth 1-D": lambda: pl.Scorer(mesh, K, depth.ravel(), mask, device="cpu"),
        "faces out of range": lambda: pl.Scorer((np.eye(3), [[0, 1, 7]]), K, depth, mask, device="cpu"),
        "faces negative": lambda: pl.Scorer((np.eye(3), [[0, 1, -1]]), K, depth, mask, device="cpu"),
        "faces float": lambda: pl.Scorer((np.eye(3), [[0.0, 1.0, 2.0]]), K, depth, mask, device="cpu"),
        "vertices NaN": lambda: pl.Scorer((np.full((3, 3), np.nan), [[0, 1, 2]]), K, depth, mask, device="cpu"),
        "mesh type": lambda: pl.Scorer(42, K, depth, mask, device="cpu"),
        "lod": lambda: pl.Scorer(mesh, K, depth, mask, lod="fine", device="cpu"),
        "lod 2 faces": lambda: pl.Scorer(mesh, K, depth, mask, lod=2, device="cpu"),
        "4x4 bottom row": lambda: s.score(np.tile(np.eye(4), (2, 1, 1)) + np.array([[0, 0, 0, 0]] * 3 + [[1, 2, 3, 4]])),
        "complex t": lambda: s.score(R[:2], t[:2] + 1j),
        "complex K": lambda: pl.Scorer(mesh, K + 0j, depth, mask, device="cpu"),
        "physics not a bool": lambda: s.score(R[:2], t[:2], plane=demo / "plane.json", physics="no"),
        # Refused from its shape, before a 4.6 GB copy of a broadcast view.
        "huge depth": lambda: pl.Scorer(mesh, [2e4, 2e4, 1e4, 1e4], np.broadcast_to(np.float32(0.7), (20000, 20000)), None, device="cpu"),
        # Refused before copying (an allocation failure would abort Python).
        "too many poses": lambda: s.score(np.broadcast_to(R[0], (pl._native.MAX_POSES + 1, 3, 3)), np.broadcast_to(t[0], (pl._native.MAX_POSES + 1, 3))),
        "res True": lambda: pl.Scorer(mesh, K, depth, mask, res=True, device="cpu"),
        "t far away": lambda: s.score(R[:2], t[:2] * 1e300),
    }
    for what, call in cases.items():
        with pytest.raises(ValueError) as e:
            call()
        assert str(e.value), what
    with pytest.raises(FileNotFoundError):
        pl.Scorer(demo / "no-such-mesh.obj", K, depth, mask, device="cpu")
    # A mesh in millimetres given as metres scores zero: said, as the CLI says it.
    m = pl.load_mesh(mesh)
    with pytest.warns(UserWarning, match="units may be wrong"):
        pl.Scorer((m.vertices * 1000, m.faces), K, depth, mask, device="cpu")
    assert s.region[0] == (128, 128)
    msg = None
    try:
        s.score(bad_R * 0.5 + R[:2] * 0.5 + 1e-4, t[:2])
    except ValueError as e:
        msg = str(e)
    assert msg is None or "--" not in msg, msg


def test_threads_share_a_scorer_and_meshes_come_from_any_arrays(demo):
    """Threads scoring with one Scorer queue instead of failing; a Mesh
    takes trimesh's uint32 faces, float32 vertices and lists."""
    import threading

    K, depth, mask = frame(demo)
    R, t = poses(demo)
    m = pl.load_mesh(demo / "duck_0.15m.obj")
    s = pl.Scorer(m, K, depth, mask, device="cpu")
    want = s.score(R, t)["score"]
    got, errors = [], []

    def work():
        try:
            got.append(s.score(R, t)["score"])
        except Exception as e:  # noqa: BLE001 - the test reports any failure
            errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for th in threads:
        th.start()
    work()
    for th in threads:
        th.join()
    assert not errors, errors
    assert len(got) == 4 and all(np.array_equal(g, want) for g in got)
    copy = pl.Mesh(m.vertices.astype(np.float32), m.faces)
    assert copy.faces.shape == m.faces.shape
    assert pl.Mesh(m.vertices.tolist(), m.faces.tolist()).faces.shape == m.faces.shape
    for v, f in [(m.vertices, m.faces.astype(np.float64)), (m.vertices + 0j, m.faces), (m.vertices.ravel(), m.faces)]:
        with pytest.raises(ValueError):
            pl.Mesh(v, f)


def test_errors_name_the_argument_and_the_shape_given(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    mesh = demo / "duck_0.15m.obj"
    s = pl.Scorer(mesh, K, depth, mask, device="cpu")
    value_errors = {
        "R: cannot be read as an array of numbers .*inhomogeneous": lambda: s.score([[[1, 0, 0], [0, 1, 0]], [[1, 0, 0]]], t[:2]),
        "K: cannot be read as an array of numbers .*inhomogeneous": lambda: pl.Scorer(mesh, [[1, 2], [3]], depth, mask, device="cpu"),
        r"R: expected shape \(N, 3, 3\) or \(3, 3\), got \(64, 9\)": lambda: s.score(R[:64].reshape(-1, 9), t[:64]),
        "R: expected an array of numbers, got NoneType None": lambda: s.score(None, t[:2]),
        r"t: expected shape \(2, 3\) for 2 rotations, got \(3,\)": lambda: s.score(R[:2], t[0]),
        r"t: expected an array of numbers, got ndarray array\(None": lambda: s.score(R[0], np.array(None)),
        "R: expected numbers, got dtype <U1": lambda: s.score(np.full((3, 3), "1"), t[0]),
    }
    for message, call in value_errors.items():
        with pytest.raises(ValueError, match=message):
            call()
    for name in ("tau", "alpha", "margin"):
        for value in ("x", "0.02", None, True):
            with pytest.raises(TypeError, match=f"{name} {value!r}: expected a number"):
                pl.Scorer(mesh, K, depth, mask, device="cpu", **{name: value})
    assert len(pl.Scorer(mesh, K, depth, mask, device="cpu", tau=np.float32(0.02), alpha=1, margin=np.float64(0.25)).score(R[:2], t[:2])) == 2


def test_tolerances_too_small_for_f32_are_refused_as_given(demo):
    K, depth, mask = frame(demo)
    mesh = demo / "duck_0.15m.obj"
    with pytest.raises(ValueError, match="tau 1e-50: too small for the kernels' 32-bit floats"):
        pl.Scorer(mesh, K, depth, mask, tau=1e-50, device="cpu")
    with pytest.raises(ValueError, match="alpha 1e-50: too small for the kernels' 32-bit floats"):
        pl.Scorer(mesh, K, depth, mask, alpha=1e-50, device="cpu")
    pl.Scorer(mesh, K, depth, mask, tau=1e-30, device="cpu")  # small, but an f32


def test_physics_options_are_checked_without_a_plane(demo):
    K, depth, mask = frame(demo)
    R, t = poses(demo)
    s = pl.Scorer(demo / "duck_0.15m.obj", K, depth, mask, device="cpu")
    with pytest.raises(ValueError, match="epsilon -5"):
        s.score(R[:2], t[:2], epsilon=-5)
    with pytest.raises(ValueError, match="samples -5"):
        s.score(R[:2], t[:2], samples=-5)
    with pytest.raises(ValueError, match="samples 0"):
        s.score(R[:2], t[:2], samples=0)
    with pytest.raises(ValueError, match="seed -1"):
        s.score(R[:2], t[:2], seed=-1)
    for epsilon in ("x", "0.001"):
        with pytest.raises(TypeError, match=f"epsilon '{epsilon}': expected a number"):
            s.score(R[:2], t[:2], epsilon=epsilon)
    assert len(s.score(R[:2], t[:2], epsilon=0.001, samples=10)) == 2


def test_shapes_are_checked_before_any_copy(demo):
    """A huge broadcast view with the wrong shape is refused from its shape:
    no gigabytes are allocated to find it out."""
    import tracemalloc

    K, depth, mask = frame(demo)
    R, t = poses(demo)
    mesh = pl.load_mesh(demo / "duck_0.15m.obj")
    s = pl.Scorer(mesh, K, depth, mask, device="cpu")
    cases = {
        r"t: expected shape \(1, 3\) for 1 rotation, got \(100000000, 3\)": lambda: s.score(R[0], np.broadcast_to(t[0], (100_000_000, 3))),
        r"plane point: expected shape \(3\), got \(300000000,\)": lambda: s.score(R[:2], t[:2], plane=(np.broadcast_to(1.0, (300_000_000,)), [0, 0, 1])),
        "mask: 40000x100000 pixels": lambda: pl.Scorer(mesh, K, depth, np.broadcast_to(np.float32(1), (100_000, 40_000)), device="cpu"),
        r"K: expected a 3x3 matrix, 9 numbers or \(fx, fy, cx, cy\), got shape \(100000000,\)": lambda: pl.Scorer(mesh, np.broadcast_to(np.float32(1), (100_000_000,)), depth, mask, device="cpu"),
    }
    for message, call in cases.items():
        tracemalloc.start()
        try:
            with pytest.raises(ValueError, match=message):
                call()
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 50 << 20, (message, peak)


def test_meshes_pickle_exactly_and_scorers_refuse_clearly(demo):
    import copy
    import pickle

    K, depth, mask = frame(demo)
    R, t = poses(demo)
    for m in (pl.load_mesh(demo / "duck_0.15m.obj"), pl.load_mesh(demo / "duck_0.15m.obj", units="mm"), pl.Mesh(np.eye(3) * 0.1, [[0, 1, 2]], units="m")):
        for back in (pickle.loads(pickle.dumps(m)), copy.deepcopy(m), copy.copy(m)):
            assert back.vertices.tobytes() == m.vertices.tobytes()
            assert back.faces.tobytes() == m.faces.tobytes()
            assert back.sha256 == m.sha256 and repr(back) == repr(m) and back.warnings == m.warnings
    m = pl.load_mesh(demo / "duck_0.15m.obj")
    back = pickle.loads(pickle.dumps(m))
    a = pl.Scorer(m, K, depth, mask, device="cpu").score(R[:64], t[:64])
    b = pl.Scorer(back, K, depth, mask, device="cpu").score(R[:64], t[:64])
    np.testing.assert_array_equal(a, b)
    s = pl.Scorer(m, K, depth, mask, device="cpu")
    for how in (pickle.dumps, copy.copy, copy.deepcopy):
        with pytest.raises(TypeError, match="a plausible.Scorer cannot be pickled or copied"):
            how(s)


def test_mesh_faces_are_read_without_wrapping_or_copying(demo):
    """uint64 faces are read as they are (2**64 - 1 had been cast to -1), and
    a Mesh's arrays are refused from their shape, before any copy."""
    import tracemalloc

    K, depth, mask = frame(demo)
    with pytest.raises(ValueError, match="face 0 refers to vertex 18446744073709551615"):
        pl.Scorer((np.eye(3), np.array([[2**64 - 1, 1, 2]], dtype=np.uint64)), K, depth, mask, device="cpu")
    with pytest.raises(ValueError, match="face 0 refers to vertex 18446744073709551615"):
        pl.Mesh(np.eye(3), np.array([[0, 1, 2**64 - 1]], dtype=np.uint64))
    with pytest.warns(UserWarning, match="mesh is open"):
        assert len(pl.Mesh(np.eye(3), np.array([[0, 1, 2]], dtype=np.uint64))) == 1
    m = pl.load_mesh(demo / "duck_0.15m.obj")
    for faces in (np.broadcast_to(np.uint64(0), (100_000_000, 4)), np.broadcast_to(np.int32(0), (100_000_000, 4))):
        tracemalloc.start()
        try:
            with pytest.raises(ValueError, match=r"faces: expected shape \(N, 3\), got \(100000000, 4\)"):
                pl.Mesh(m.vertices, faces)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 50 << 20, peak
