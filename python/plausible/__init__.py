"""plausible: visual and physical plausibility of 6D object poses.

numpy in, numpy out, no files needed. Thousands of pose hypotheses are
scored at once on any GPU (Mesa's lavapipe included) or with the CPU twin::

    import numpy as np
    import plausible

    scorer = plausible.Scorer("duck.obj", K, depth, mask, units="m")
    rec = scorer.score(R, t)                 # R (N, 3, 3), t (N, 3)
    best = rec[np.argsort(rec["rank"])][:10]

Conventions: OpenCV camera, poses map model to camera, lengths in the
``units`` given (``"m"`` or ``"mm"``: BOP data is in millimetres), depth 0
or NaN where there is no measurement. Bad input raises ``ValueError`` with
the library's message; the GIL is released while kernels run.
"""

from __future__ import annotations

import json
import os
import stat
import threading
from numbers import Real
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

# On a headless server Mesa's device-select Vulkan layer looks for a Wayland
# display and prints "XDG_RUNTIME_DIR is invalid" whenever a device opens;
# without a display session it has nothing to select by. Switched off as the
# CLI does, before the native module opens any device.
if not any(k in os.environ for k in ("XDG_RUNTIME_DIR", "NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT")):
    os.environ["NODEVICE_SELECT"] = "1"

from . import _native  # noqa: E402
from ._native import Mesh, device_info  # noqa: E402

__version__ = _native.__version__
__all__ = [
    "Mesh",
    "Scorer",
    "SCORE_DTYPE",
    "PHYSICS_DTYPE",
    "check",
    "device_info",
    "eval",
    "fit_plane",
    "hypotheses",
    "load_mesh",
    "read_frame",
    "refine",
    "estimate",
    "stable_poses",
]

#: Fields of :meth:`Scorer.score`'s records (visual terms, eq. 3-5).
SCORE_DTYPE = np.dtype(
    [
        ("score", "f4"),
        ("a_d", "f4"),
        ("a_n", "f4"),
        ("valid", "u4"),
        ("rendered", "u4"),
        ("observed", "u4"),
        ("rank", "u4"),
    ]
)

#: Fields added with a support plane (physical terms, eq. 6-13); distances
#: in the scorer's units, NaN margin where the object is not supported.
PHYSICS_DTYPE = np.dtype(
    SCORE_DTYPE.descr
    + [
        ("verdict", "U12"),
        ("intersecting", "u4"),
        ("contact", "u4"),
        ("supported", "u4"),
        ("min_distance", "f8"),
        ("stability_margin", "f8"),
        ("feasible", "?"),
        ("stable", "?"),
    ]
)

MeshLike = Union[Mesh, str, os.PathLike, Tuple[Any, Any], Any]
PlaneLike = Union[Mapping[str, Any], str, os.PathLike, Tuple[Any, Any]]


def _scale(units: str) -> float:
    """Metres per unit."""
    if units == "m":
        return 1.0
    if units == "mm":
        return 1e-3
    raise ValueError(f'units {units!r}: expected "m" or "mm"')


def _uint(name: str, value: Any) -> int:
    """A non-negative integer argument (seeds, counts), or ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0 or value >= 2**64:
        raise ValueError(f"{name} {value!r}: expected a non-negative integer")
    return int(value)


def _bool(name: str, value: Any) -> bool:
    """A True/False argument, or ValueError (``bool("no")`` is True)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} {value!r}: expected True or False")
    return bool(value)


def _float(name: str, value: Any) -> float:
    """A real-number argument (tolerances, distances), or TypeError naming
    it: a string such as "0.02" is refused, not parsed."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Real):
        raise TypeError(f"{name} {value!r}: expected a number")
    return float(value)


def _opt_float(name: str, value: Any) -> Optional[float]:
    """:func:`_float`, or None."""
    return None if value is None else _float(name, value)


#: Largest text files read (bytes), as the native side caps them: a scene
#: JSON, a plane JSON, a stable-pose export.
_MAX_SCENE_BYTES = 64 << 20
_MAX_PLANE_BYTES = 1 << 20
_MAX_EXPORT_BYTES = 256 << 20


def _read_text(path: Union[str, os.PathLike], what: str, cap: int) -> str:
    """The UTF-8 text of the file ``path`` given as argument ``what``, read
    to at most ``cap`` bytes: a regular file larger than that is refused by
    its size before anything is read, anything else (a device such as
    /dev/zero, a pipe) once it has given more, so an endless stream is an
    error rather than memory growing until the process is killed. A binary
    file is a ValueError naming the argument and the path; a leading byte
    order mark is dropped (as the native readers drop it)."""
    p = os.fspath(path)
    try:
        with open(p, "rb") as f:
            st = os.fstat(f.fileno())
            if stat.S_ISREG(st.st_mode) and st.st_size > cap:
                raise ValueError(f"{what} {p!r}: a file of {st.st_size} bytes, more than the {cap >> 20} MiB read")
            data = f.read(cap + 1)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {p!r}: not found") from None
    except IsADirectoryError:
        raise IsADirectoryError(f"{what} {p!r}: is a folder, expected a file") from None
    if len(data) > cap:
        raise ValueError(f"{what} {p!r}: not a regular file, and more than the {cap >> 20} MiB read (an endless stream?)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{what} {p!r}: not a UTF-8 text file (byte {e.start}: {e.reason}); expected JSON") from None
    return text[1:] if text.startswith("\ufeff") else text


def _json_file(path: Union[str, os.PathLike], what: str, cap: int) -> Any:
    """The JSON in the file ``path`` (argument ``what``), read by :func:`_read_text`."""
    try:
        return json.loads(_read_text(path, what, cap))
    except json.JSONDecodeError as e:
        raise ValueError(f"{what} {os.fspath(path)!r}: not JSON ({e})") from None


def _jsonable(o: Any) -> Any:
    """``json.dumps``' fallback: numpy arrays as lists, numpy scalars as
    numbers, paths as strings."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    raise TypeError(f"{type(o).__name__} {o!r:.60}: not a JSON value (numbers, strings, lists, dicts, numpy arrays)")


def _to_json(value: Any, what: str) -> str:
    """``value`` (argument ``what``) as JSON text, numpy arrays and scalars
    included; NaN and infinity, which JSON has no words for, are refused."""
    try:
        return json.dumps(value, default=_jsonable, allow_nan=False)
    except TypeError as e:
        raise TypeError(f"{what}: {e}") from None
    except ValueError as e:
        raise ValueError(f"{what}: cannot be written as JSON ({e}: NaN and infinity have no JSON form)") from None


def load_mesh(path: Union[str, os.PathLike], units: str = "auto") -> Mesh:
    """Loads .obj, .ply, .stl, .gltf or .glb; ``units`` "m", "cm", "mm" or "auto"."""
    return Mesh.load(os.fspath(path), units)


def read_frame(
    camera: Union[str, os.PathLike],
    depth: Union[str, os.PathLike],
    mask: Optional[Union[str, os.PathLike]] = None,
    frame: Optional[Union[str, int]] = None,
) -> Tuple[np.ndarray, np.ndarray, Optional[np.ndarray]]:
    """Reads a BOP frame from files: ``camera`` (a scene_camera.json entry,
    a whole scene_camera.json with ``frame``, or a dataset camera.json), the
    16-bit ``depth`` PNG and optionally an 8-bit ``mask`` PNG. Returns K (3,
    3), depth (H, W) in metres and the mask (H, W) booleans or None, checked
    against each other; pass them on with ``units="m"``."""
    return _native.read_frame(
        os.fspath(camera), os.fspath(depth), None if mask is None else os.fspath(mask), None if frame is None else str(frame)
    )


def _mesh(mesh: MeshLike, units: str, mesh_units: str) -> Mesh:
    """A :class:`Mesh` from a Mesh, a path, (vertices, faces) arrays or any
    object with ``.vertices`` and ``.faces`` (a trimesh.Trimesh)."""
    if isinstance(mesh, Mesh):
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        return load_mesh(mesh, mesh_units)
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces = mesh.vertices, mesh.faces
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        vertices, faces = mesh
    else:
        raise ValueError("mesh: give a plausible.Mesh, a file path, (vertices, faces) arrays or a trimesh.Trimesh")
    v = _array(vertices, np.float64, "vertices", (None, 3))
    f = _numbers(faces, "faces")
    if f.dtype.kind not in "iu":
        raise ValueError(f"faces: expected integer vertex indices, got dtype {f.dtype}")
    _check_shape(f, "faces", (None, 3))
    # As they are: Mesh reads unsigned indices as uint64 and signed ones as
    # int64 (a cast here would turn uint64 2**64 - 1 into -1).
    return Mesh(v, np.ascontiguousarray(f), units)


def _numbers(a: Any, what: str) -> np.ndarray:
    """``a`` (argument ``what``) as an array of real numbers, not yet
    converted: an array given stays as it is (a broadcast view costs
    nothing until copied), so its shape can be checked first. Ragged
    lists, None, strings and complex numbers (numpy would drop their
    imaginary part) are ValueErrors naming the argument."""
    try:
        arr = np.asarray(a)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: cannot be read as an array of numbers ({e})") from None
    if arr.dtype.kind == "c":
        raise ValueError(f"{what}: expected real numbers, got complex ones")
    if arr.dtype.kind == "O" and arr.ndim == 0:
        raise ValueError(f"{what}: expected an array of numbers, got {type(a).__name__} {a!r:.60}")
    if arr.dtype.kind not in "biufO":
        raise ValueError(f"{what}: expected numbers, got dtype {arr.dtype}")
    return arr


def _check_shape(arr: np.ndarray, what: str, shape: Sequence[Optional[int]]) -> None:
    """ValueError unless ``arr`` has ``shape`` (None = any), naming ``what``."""
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{what}: expected shape {want}, got {arr.shape}")


def _convert(arr: np.ndarray, dtype: Any, what: str) -> np.ndarray:
    """``arr`` as a C-contiguous array of ``dtype`` (the copy, once its shape is checked)."""
    try:
        return np.ascontiguousarray(arr, dtype=dtype)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: cannot be read as {np.dtype(dtype).name} numbers ({e})") from None


def _array(a: Any, dtype: Any, what: str, shape: Sequence[Optional[int]]) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype`` with ``shape`` (None =
    any); the shape is checked on the input, before any copy."""
    arr = _numbers(a, what)
    _check_shape(arr, what, shape)
    return _convert(arr, dtype, what)


def _camera(K: Any) -> np.ndarray:
    """The row-major 3x3 camera matrix, from (3, 3), 9 numbers or (fx, fy, cx, cy)."""
    given = _numbers(K, "K")
    if given.size not in (4, 9):
        raise ValueError(f"K: expected a 3x3 matrix, 9 numbers or (fx, fy, cx, cy), got shape {given.shape}")
    k = _convert(given, np.float64, "K").reshape(-1)
    if k.size == 4:
        fx, fy, cx, cy = k
        k = np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    return np.ascontiguousarray(k)


def _depth(depth: Any, scale: float) -> np.ndarray:
    """Depth (H, W) in metres, float32."""
    d = _numbers(depth, "depth")
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[:, :, 0]
    if d.ndim != 2:
        raise ValueError(f"depth: expected an (H, W) image, got shape {d.shape}")
    _check_side("depth", d.shape)
    if d.dtype.kind not in "fiu":
        raise ValueError(f"depth: expected numbers, got dtype {d.dtype}")
    return np.ascontiguousarray(d.astype(np.float64) * scale, dtype=np.float32)


#: Largest image side read (pixels), as the native side checks: checked
#: here first, so a huge array is refused before it is copied.
MAX_IMAGE_SIDE = 4096


def _check_side(what: str, shape: Tuple[int, ...]) -> None:
    if not all(1 <= n <= MAX_IMAGE_SIDE for n in shape[:2]):
        raise ValueError(f"{what}: {shape[1]}x{shape[0]} pixels: each side must lie in 1..={MAX_IMAGE_SIDE}")


def _mask(mask: Any) -> Optional[np.ndarray]:
    """Mask (H, W) as booleans (non-zero = object)."""
    if mask is None:
        return None
    m = _numbers(mask, "mask")
    if m.ndim == 3 and m.shape[2] == 1:
        m = m[:, :, 0]
    if m.ndim != 2:
        raise ValueError(f"mask: expected an (H, W) image, got shape {m.shape}")
    # Its sides first: np.isnan below makes an array as large as the mask.
    _check_side("mask", m.shape)
    if m.dtype.kind not in "biuf":
        raise ValueError(f"mask: expected booleans or numbers, got dtype {m.dtype}")
    if m.dtype.kind == "f" and np.isnan(m).any():
        raise ValueError("mask: holds NaN (neither object nor background)")
    return np.ascontiguousarray(m != 0)


def _required_mask(mask: Any) -> np.ndarray:
    """The object's mask where a function cannot work without one."""
    if mask is None:
        raise ValueError("mask: hypotheses need the object's mask (H, W) to find its observed points")
    return _mask(mask)


def _poses(R: Any, t: Any, scale: float) -> Tuple[np.ndarray, np.ndarray]:
    """Rotations (N, 3, 3) and translations (N, 3) in metres, from R and t,
    or from 4x4 matrices (N, 4, 4) given as R alone. Shapes are checked as
    given, before any copy (a broadcast view costs nothing until then)."""
    r = _numbers(R, "R" if t is not None else "poses")
    n = r.shape[0] if r.ndim == 3 else 1
    if n > _native.MAX_POSES:
        raise ValueError(f"{n} poses: at most {_native.MAX_POSES} are scored at once; give them in chunks")
    if t is None:
        T = r[None] if r.shape == (4, 4) else r
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ValueError(f"poses: give R (N, 3, 3) and t (N, 3), or 4x4 matrices (N, 4, 4); got shape {r.shape}")
        T = _convert(T, np.float64, "poses")
        # (np.linalg.inv leaves ~1e-17 there: rounding, not another matrix)
        bad = np.flatnonzero(np.any(~(np.abs(T[:, 3, :] - [0.0, 0.0, 0.0, 1.0]) <= 1e-9), axis=1))
        if bad.size:
            raise ValueError(f"pose {bad[0]}: the bottom row of a 4x4 pose must be [0, 0, 0, 1], got {T[bad[0], 3].tolist()}")
        r, tt = T[:, :3, :3], T[:, :3, 3]
    else:
        if r.shape == (3, 3):
            r = r[None]
        if r.ndim != 3 or r.shape[1:] != (3, 3):
            raise ValueError(f"R: expected shape (N, 3, 3) or (3, 3), got {r.shape}")
        tt = _numbers(t, "t")
        given = tt.shape
        if tt.shape == (3,):
            tt = tt[None]
        if tt.shape != (r.shape[0], 3):
            raise ValueError(f"t: expected shape ({r.shape[0]}, 3) for {r.shape[0]} rotation{'s' if r.shape[0] != 1 else ''}, got {given}")
    r = _convert(r, np.float64, "R")
    tt = _convert(tt, np.float64, "t")
    return r, np.ascontiguousarray(tt * scale)


def _plane(plane: PlaneLike, scale: float) -> Tuple[np.ndarray, np.ndarray]:
    """(point in metres, normal) of a support plane given as a dict
    (``fit_plane``'s, or the plane JSON's with its "units", default mm), a
    path to a plane JSON, or a (point, normal) pair in the caller's units."""
    if isinstance(plane, (str, os.PathLike)):
        path = os.fspath(plane)
        plane = _json_file(path, "plane", _MAX_PLANE_BYTES)
        if not isinstance(plane, Mapping):
            raise ValueError(f'plane {path!r}: expected a plane JSON {{"point": [x, y, z], "normal": [nx, ny, nz], "units": "mm"|"m"}}')
    if isinstance(plane, Mapping):
        if "point" not in plane or "normal" not in plane:
            raise ValueError('plane: expected {"point": [x, y, z], "normal": [nx, ny, nz], "units": "mm"|"m"}')
        units = plane.get("units", "mm")
        point, normal, scale = plane["point"], plane["normal"], _scale(units)
    elif isinstance(plane, (tuple, list)) and len(plane) == 2:
        point, normal = plane
    else:
        raise ValueError("plane: give a dict with point and normal, a plane JSON path, or (point, normal)")
    p = _array(point, np.float64, "plane point", (3,)) * scale
    n = _array(normal, np.float64, "plane normal", (3,))
    return np.ascontiguousarray(p), n


def _records(cols: Dict[str, Any], dtype: np.dtype, scale: float) -> np.ndarray:
    """The native columns as one structured array; distances in the caller's units."""
    n = len(cols["score"])
    out = np.zeros(n, dtype=dtype)
    for name in dtype.names:
        out[name] = cols[name]
    if "min_distance" in dtype.names:
        out["min_distance"] /= scale
        out["stability_margin"] /= scale
    return out


class Scorer:
    """Scores pose hypotheses of one mesh against one depth observation.

    Built once, called many times: the GPU pipeline, the mesh and the
    observation stay loaded between calls to :meth:`score`.

    Args:
        mesh: a :class:`Mesh`, a mesh file path, (vertices, faces) arrays
            in ``units``, or a trimesh.Trimesh.
        K: camera matrix (3, 3), or (fx, fy, cx, cy), pixels.
        depth: (H, W) depth in ``units``; 0 or NaN = no measurement.
        mask: (H, W) object mask (non-zero = object), or None for the frame.
        units: "m" or "mm" for the depth, translations, array vertices and
            reported distances (BOP data is in mm).
        res: the square around the mask is resampled to res x res pixels,
            clipped to the image (0 = native pixels).
        tau: depth tolerance of eq. 4, metres.
        alpha: normal tolerance of eq. 5.
        margin: growth of the mask's box on each side (fraction).
        device: "auto" (a hardware GPU, else the faster CPU twin), "gpu"
            (any adapter, lavapipe included) or "cpu".
        adapter: pick the first adapter whose name contains this (with
            "auto", used even when it is a software one, and an error when
            missing; with "cpu", refused).
        mesh_units: units of a mesh file: "m", "cm", "mm" or "auto".
        lod: level of detail of the mesh the visual score renders: "auto"
            (the coarsest simplification within a quarter of a pixel at the
            observed object), "off" (the full mesh) or a triangle count;
            the physical terms always use the full mesh.
    """

    def __init__(
        self,
        mesh: MeshLike,
        K: Any,
        depth: Any,
        mask: Any = None,
        *,
        units: str = "m",
        res: int = 128,
        tau: float = 0.02,
        alpha: float = 0.7,
        margin: float = 0.25,
        device: str = "auto",
        adapter: Optional[str] = None,
        mesh_units: str = "auto",
        lod: Union[str, int] = "auto",
    ) -> None:
        self._scale = _scale(units)
        self.units = units
        self.mesh = _mesh(mesh, units, mesh_units)
        if isinstance(res, bool) or not isinstance(res, (int, np.integer)) or res < 0 or res > 4096:
            raise ValueError(f"res {res!r}: the region's side in pixels must lie in 0..=4096 (0 = native pixels)")
        # One call at a time: the native scorer keeps per-call scratch and
        # releases the GIL while it works, so threads sharing a Scorer queue
        # here instead of meeting a borrow error.
        self._lock = threading.Lock()
        self._native = _native.Scorer(
            self.mesh,
            _camera(K),
            _depth(depth, self._scale),
            _mask(mask),
            res=int(res),
            tau=_float("tau", tau),
            alpha=_float("alpha", alpha),
            margin=_float("margin", margin),
            device=device,
            adapter=adapter,
            lod=str(lod),
        )

    @property
    def scoring_mesh(self) -> str:
        """Which mesh the visual score renders (level of detail) and why."""
        with self._lock:
            return self._native.scoring_mesh

    @property
    def device(self) -> str:
        """Where the kernels run, e.g. "CPU twin (2 threads)"."""
        with self._lock:
            return self._native.device

    @property
    def region(self) -> Tuple[Tuple[int, int], Tuple[float, float, float, float]]:
        """Size of the scored region in pixels (width, height), and its
        crop in the image (x0, y0, width, height) in image pixels."""
        with self._lock:
            return self._native.region

    def score(
        self,
        R: Any,
        t: Any = None,
        *,
        plane: Optional[PlaneLike] = None,
        physics: Optional[bool] = None,
        samples: int = 1024,
        seed: int = 0,
        epsilon: Optional[float] = None,
        orthonormalize: bool = False,
    ) -> np.ndarray:
        """Scores poses: R (N, 3, 3) and t (N, 3) in ``units``, or 4x4
        matrices (N, 4, 4) as R alone. Returns a structured array in input
        order (:data:`SCORE_DTYPE`; rank 1 = best). With ``plane`` (and
        ``physics``, its default then) also the physical terms on that
        support plane (:data:`PHYSICS_DTYPE`), ranked physically plausible
        first as ``plausible score --physics`` does. ``samples``, ``seed``
        and ``epsilon`` (metres) set the physical sampling."""
        r, tt = _poses(R, t, self._scale)
        orthonormalize = _bool("orthonormalize", orthonormalize)
        physics = plane is not None if physics is None else _bool("physics", physics)
        if physics and plane is None:
            raise ValueError("physics=True needs the support plane: pass plane=... (plausible.fit_plane fits one)")
        # Checked on every call, used or not: a wrong value is wrong
        # whether or not this call has a plane.
        epsilon = _opt_float("epsilon", epsilon)
        if epsilon is not None and not (0.0 < epsilon < 0.05):
            raise ValueError(f"epsilon {epsilon}: the contact tolerance is in metres and must lie in (0, 0.05)")
        if not (0 < _uint("samples", samples) <= 50_000):
            raise ValueError(f"samples {samples}: between 1 and 50,000 surface samples")
        seed = _uint("seed", seed)
        if not physics:
            with self._lock:
                cols = self._native.score(r, tt, orthonormalize=orthonormalize)
            return _records(cols, SCORE_DTYPE, self._scale)
        p, n = _plane(plane, self._scale)
        with self._lock:
            cols = self._native.score(
                r, tt, (p, n), samples=int(samples), seed=seed, epsilon=epsilon, orthonormalize=orthonormalize
            )
        return _records(cols, PHYSICS_DTYPE, self._scale)

    def __repr__(self) -> str:
        with self._lock:
            return repr(self._native)

    def __reduce__(self) -> Any:
        raise TypeError(
            "a plausible.Scorer cannot be pickled or copied: it holds an open device and its uploaded buffers; "
            "send its Mesh (which pickles) and arrays instead and build a Scorer in each process"
        )


def fit_plane(
    K: Any,
    depth: Any,
    mask: Any = None,
    *,
    units: str = "m",
    inlier: float = 0.005,
    iterations: int = 500,
    seed: int = 0,
    mask_margin: int = 5,
) -> Dict[str, Any]:
    """Fits the support plane to the depth outside the (grown) mask by
    RANSAC. Returns {"point", "normal", "units", "inliers", "candidates",
    "rms"} in ``units``; pass it as ``plane=`` to :meth:`Scorer.score`.
    ``inlier`` is in metres."""
    s = _scale(units)
    fit = _native.fit_plane(
        _camera(K), _depth(depth, s), _mask(mask), inlier=_float("inlier", inlier), iterations=_uint("iterations", iterations), seed=_uint("seed", seed), mask_margin=_uint("mask_margin", mask_margin)
    )
    fit["point"] = fit["point"] / s
    fit["rms"] = fit["rms"] / s
    fit["units"] = units
    return fit


def check(scene: Union[Mapping[str, Any], str, os.PathLike], *, simulate: bool = False, **options: Any) -> List[Dict[str, Any]]:
    """Physical plausibility of a scene (the ``plausible check`` JSON, as a
    dict or a path; mesh paths in a dict are relative to the working
    folder): per object its verdict (plausible, floating, intersecting,
    unstable), contact counts, minimum distance and stability margin
    (metres), friction equilibrium, and with ``simulate`` the displacement
    under rapier. Options: samples, seed, epsilon, sdf_resolution, friction.
    A dict may hold numpy arrays and numbers, rotations as (3, 3)."""
    opts: Dict[str, Any] = {}
    for name, value in options.items():
        if name in ("samples", "seed", "sdf_resolution"):
            opts[name] = _uint(name, value)
        elif name in ("epsilon", "friction"):
            opts[name] = _opt_float(name, value) if name == "epsilon" else _float(name, value)
        else:
            opts[name] = value  # the native side names an unknown option
    simulate = _bool("simulate", simulate)
    if isinstance(scene, (str, os.PathLike)):
        path = Path(scene)
        text = _read_text(path, "scene", _MAX_SCENE_BYTES)
        return _native.check(text, str(path.parent), str(path), simulate=simulate, **opts)
    if not isinstance(scene, Mapping):
        raise ValueError("scene: give a dict in the plausible check format or a path to its JSON")
    objects = scene.get("objects")
    if isinstance(objects, (list, tuple)):
        # Rotations as (3, 3) arrays or nested lists: the format's 9 numbers, row-major.
        objects = [
            dict(o, **{k: np.asarray(o[k]).reshape(9) for k in ("R", "cam_R_m2c") if k in o and _is_3x3(o[k])}) if isinstance(o, Mapping) else o
            for o in objects
        ]
        scene = dict(scene, objects=objects)
    return _native.check(_to_json(scene, "scene"), os.getcwd(), "<scene dict>", simulate=simulate, **opts)


def _is_3x3(value: Any) -> bool:
    try:
        return np.shape(value) == (3, 3)
    except ValueError:  # ragged: left to the native side's message
        return False


def stable_poses(mesh: MeshLike, *, drops: int = 1000, seed: int = 0, collider: str = "hull", threads: Optional[int] = None, units: str = "m", mesh_units: str = "auto") -> List[Dict[str, Any]]:
    """Stable resting poses of ``mesh`` from seeded rapier drop tests,
    clustered modulo yaw. Returns one dict per resting pose or family, most
    probable first: kind ("pose", "circle" for a rolling family, "scattered"),
    probability, ci95 (Wilson 95 % interval), count, and for poses the
    rotation R_model_to_plane (3, 3) (gravity along -z of the plane frame),
    height of the model origin above the plane (metres) and representative
    drops. ``threads`` None or 0: every logical CPU. Same seed, same
    result."""
    m = _mesh(mesh, units, mesh_units)
    out = _native.stable_poses(m, drops=_uint("drops", drops), seed=_uint("seed", seed), collider=collider, threads=None if threads is None else _uint("threads", threads))
    poses = [dict(c, kind="pose", R_model_to_plane=np.asarray(c["R_model_to_plane"]).reshape(3, 3)) for c in out["clusters"]]
    families = [dict(f) for f in out["families"]]
    result = sorted(poses + families, key=lambda c: -c["probability"])
    for c in result:
        c["sha256"] = out["sha256"]
        c["settled"] = out["settled"]
    return result


def _finite(value: Any, what: str, size: int) -> List[float]:
    """``size`` finite real numbers (any shape holding them), or ValueError."""
    given = _numbers(value, what)
    if given.size != size:
        raise ValueError(f"{what}: expected {size} numbers, got shape {given.shape}")
    a = _convert(given, np.float64, what).reshape(size)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: holds NaN or infinite values")
    return a.tolist()


def _export_text(stable: Any, mesh: Mesh, what: str = "stable") -> Optional[str]:
    """A stable-pose export's JSON text from :func:`stable_poses`' list, an
    export dict, or a path to an export (argument ``what``). A list keeps
    the geometry hash its entries carry (the mesh they were dropped as), so
    the native side matches it as it matches an export's and warns when it
    is another mesh's; a list without one is taken to be ``mesh``'s."""
    if stable is None:
        return None
    if isinstance(stable, (str, os.PathLike)):
        return _read_text(stable, what, _MAX_EXPORT_BYTES)
    if isinstance(stable, Mapping):
        return _to_json(stable, what)
    if isinstance(stable, bytes) or not hasattr(stable, "__iter__"):
        raise ValueError(f"{what}: give stable_poses()' list, an export dict or the path of an export, got {type(stable).__name__}")
    clusters, families, hashes = [], [], set()
    for i, c in enumerate(stable):
        if not isinstance(c, Mapping) or "probability" not in c:
            raise ValueError(f"stable[{i}]: expected a dict of stable_poses() with a probability, got {type(c).__name__}")
        p = c["probability"]
        if not isinstance(p, Real) or not 0.0 <= float(p) <= 1.0:
            raise ValueError(f"stable[{i}]: probability {p!r} is not a number in [0, 1]")
        if c.get("sha256") is not None:
            if not isinstance(c["sha256"], str):
                raise ValueError(f"stable[{i}]: sha256 {c['sha256']!r} is not a geometry hash (a string)")
            hashes.add(c["sha256"])
        if c.get("kind", "pose") == "pose":
            if "R_model_to_plane" not in c:
                raise ValueError(f"stable[{i}]: a resting pose needs its R_model_to_plane (3, 3)")
            r = _finite(c["R_model_to_plane"], f"stable[{i}] R_model_to_plane", 9)
            clusters.append({"probability": float(p), "R_model_to_plane": r})
        else:
            axis = c.get("axis")
            if axis is not None:
                axis = _finite(axis, f"stable[{i}] axis", 3)
            families.append({"kind": c["kind"], "axis": axis, "probability": float(p)})
    if len(hashes) > 1:
        raise ValueError(f"{what}: its entries come from {len(hashes)} different meshes (sha256 {', '.join(sorted(h[:12] for h in hashes))}...): give one mesh's stable_poses()")
    sha256 = hashes.pop() if hashes else mesh.sha256
    return json.dumps({"format": "plausible-stable-poses/1", "meshes": [{"mesh": "", "sha256": sha256, "clusters": clusters, "families": families}]})


def hypotheses(
    mesh: MeshLike,
    K: Any,
    depth: Any,
    mask: Any,
    plane: PlaneLike,
    *,
    stable: Any = None,
    units: str = "m",
    mesh_units: str = "auto",
    yaw_steps: int = 24,
    grid_radius: int = 0,
    grid_step: float = 0.005,
    min_probability: float = 0.01,
) -> Dict[str, np.ndarray]:
    """Pose hypotheses of an object on its support plane: resting poses
    (``stable``: :func:`stable_poses`' list, a stable-pose export or its
    path; default: the quasi-static analysis of the convex hull) x
    ``yaw_steps`` yaws x in-plane offsets (``grid_radius`` steps of
    ``grid_step`` metres) around the observed object. Returns arrays R (N,
    3, 3), t (N, 3) in ``units``, rest, rest_probability, yaw (radians),
    offset (N, 2) metres; ready for :meth:`Scorer.score`."""
    s = _scale(units)
    m = _mesh(mesh, units, mesh_units)
    p, n = _plane(plane, s)
    out = _native.hypotheses(
        m, _camera(K), _depth(depth, s), _required_mask(mask), p, n,
        stable_export=_export_text(stable, m), yaw_steps=_uint("yaw_steps", yaw_steps), grid_radius=_uint("grid_radius", grid_radius),
        grid_step=_float("grid_step", grid_step), min_probability=_float("min_probability", min_probability),
    )
    out["t"] = out["t"] / s
    return out


def eval(  # noqa: A001 - the CLI's verb
    dataset: Union[str, os.PathLike],
    results: Union[str, os.PathLike],
    *,
    targets: Optional[Union[str, os.PathLike]] = None,
    split: str = "test",
    errors: Optional[Sequence[str]] = None,
    add_threshold: float = 0.1,
    dataset_name: Optional[str] = None,
    device: str = "auto",
    adapter: Optional[str] = None,
    records: bool = False,
    task: str = "localization",
    max_estimates_per_image: Optional[int] = None,
    sensor: Optional[str] = None,
    boxes: Optional[str] = None,
) -> Dict[str, Any]:
    """BOP'19 evaluation of a results CSV on a BOP dataset folder, as the BOP
    toolkit computes it (``plausible eval``): a dict with ar, ar_vsd,
    ar_mssd, ar_mspd, per_object, ... and with ``records`` every
    (estimate, instance) pair's errors. ``errors``: e.g. ["vsd", "mssd",
    "mspd", "ad"]. ``task="detection"``: BOP'24 6D detection (``eval_bop24_pose.py``):
    ap (bop24_mAP), ap_mssd, ap_mspd, ap_mssd_mm, per-object and
    per-threshold APs; targets default to the dataset's test_targets_bop24.json.
    ``sensor``: for a split annotated per sensor (BOP-H3, IPD, XYZ-IBD, ...;
    default: the one the toolkit evaluates for ``dataset_name``; for "hot3d"
    by scene, gray1 on Quest 3 and rgb on Aria). Lens cameras (``cam_model``,
    HOT3D's fisheyes) take MSSD and MSPD, as in the toolkit; VSD needs a pinhole.
    ``task="bbox"`` / ``task="segm"``: BOP's 2D detection / segmentation of a
    COCO results JSON (``eval_bop22_coco.py``): ``scores`` holds AP, AP50, AP75,
    AP/AR by size, AR1/AR10/AR100 and average_time_per_image; ``boxes``:
    "amodal" (default) or "modal" ground-truth boxes for bbox."""
    if max_estimates_per_image is not None and (isinstance(max_estimates_per_image, bool) or not isinstance(max_estimates_per_image, int) or max_estimates_per_image < 1):
        raise ValueError(f"max_estimates_per_image: a whole number of at least 1, got {max_estimates_per_image!r}")
    return _native.evaluate(
        os.fspath(dataset), os.fspath(results), targets=None if targets is None else os.fspath(targets), split=split,
        errors=None if errors is None else ([errors] if isinstance(errors, str) else list(errors)), add_threshold=_float("add_threshold", add_threshold), dataset_name=dataset_name,
        device=device, adapter=adapter, records=records, task=task, max_estimates_per_image=max_estimates_per_image, sensor=sensor,
        boxes=boxes,
    )


def _frame_objects(objects: Sequence[Mapping[str, Any]], units: str, mesh_units: str, depth_shape: Tuple[int, ...]) -> Tuple[List[Mesh], List[np.ndarray]]:
    """Each object's mesh and mask (H, W) from the dicts of refine/estimate."""
    if isinstance(objects, Mapping) or not len(objects):
        raise ValueError('objects: give a list of dicts, one per object: {"mesh": ..., "mask": ..., ...}')
    meshes, masks = [], []
    for i, o in enumerate(objects):
        if not isinstance(o, Mapping) or "mesh" not in o or "mask" not in o:
            raise ValueError(f'object {i}: expected a dict with "mesh" and "mask"')
        meshes.append(_mesh(o["mesh"], units, mesh_units))
        if o["mask"] is None:
            raise ValueError(f"object {i}: mask None: each object needs its mask (H, W), non-zero where the object is")
        m = _mask(o["mask"])
        if m.shape != depth_shape:
            raise ValueError(f"object {i}: mask shape {m.shape}, but the depth image is {depth_shape}")
        masks.append(m)
    return meshes, masks


def _scene_out(out: Dict[str, Any], scale: float) -> Dict[str, Any]:
    """Translations and the plane point back in the caller's units."""
    for o in out["objects"]:
        if o is not None:
            o["t"] = o["t"] / scale
    for b in out.get("best", []):
        if b is not None:
            b["t"] = b["t"] / scale
    if out.get("plane") is not None:
        point, normal = out["plane"]
        out["plane"] = {"point": np.asarray(point) / scale, "normal": np.asarray(normal), "units": "m" if scale == 1.0 else "mm"}
    return out


def refine(
    K: Any,
    depth: Any,
    objects: Sequence[Mapping[str, Any]],
    *,
    plane: Optional[PlaneLike] = None,
    method: str = "rir",
    steps: int = 2,
    budget: Optional[int] = None,
    physics: bool = True,
    res: int = 128,
    seed: int = 0,
    units: str = "m",
    mesh_units: str = "auto",
    device: str = "auto",
    adapter: Optional[str] = None,
) -> Dict[str, Any]:
    """Refines pose hypotheses of a frame's objects against the depth, as
    ``plausible refine`` does per image: REF (robust point-to-plane ICP),
    PIR (with rapier on the support plane), SIR (steps kept only where the
    visual score improves) or RIR (UCB1 over an object's hypotheses), each
    object among the others' current estimates, in support order.

    ``objects``: one dict per object with "mesh", "mask" (H, W), its
    hypotheses "R" (N, 3, 3) and "t" (N, 3) (or "poses" (N, 4, 4)) in
    ``units``, and optionally "scores" (N,) of the estimator (the best one
    stands for the object among the others until it is refined). The plane
    is fitted outside the masks when the method simulates and none is
    given. Returns {"objects": per object {"R", "t", "score", "steps",
    "kept"} in input order (None: too few observed points), "order",
    "support" (None = the plane, else an object index), "plane"}."""
    s = _scale(units)
    d = _depth(depth, s)
    meshes, masks = _frame_objects(objects, units, mesh_units, d.shape)
    rs, ts, leads = [], [], []
    for i, o in enumerate(objects):
        if "poses" in o and ("R" in o or "t" in o):
            raise ValueError(f'object {i}: give its hypotheses as "R" and "t" or as "poses" (N, 4, 4), not both')
        if "poses" in o:
            r, t = _poses(o["poses"], None, s)
        elif "R" in o and "t" in o:
            r, t = _poses(o["R"], o["t"], s)
        else:
            raise ValueError(f'object {i}: give its hypotheses as "R" and "t", or "poses" (N, 4, 4)')
        scores = o.get("scores")
        if len(r) == 0:
            raise ValueError(f"object {i}: no hypotheses to refine")
        if scores is not None:
            sc = _array(scores, np.float64, f"object {i} scores", (len(r),))
            if np.any(np.isnan(sc)):
                raise ValueError(f"object {i} scores: NaN orders nothing (±inf is taken)")
            lead = int(np.argmax(sc))
        else:
            lead = 0
        rs.append(r)
        ts.append(t)
        leads.append(lead)
    pl = None if plane is None else _plane(plane, s)
    out = _native.refine(
        _camera(K), d, meshes, masks, rs, ts, leads, plane=pl, method=method, steps=_uint("steps", steps),
        budget=None if budget is None else _uint("budget", budget), physics=_bool("physics", physics), res=_uint("res", res),
        seed=_uint("seed", seed), device=device, adapter=adapter,
    )
    return _scene_out(out, s)


def estimate(
    K: Any,
    depth: Any,
    objects: Sequence[Mapping[str, Any]],
    *,
    plane: Optional[PlaneLike] = None,
    method: str = "rir",
    steps: int = 2,
    top: int = 5,
    yaw_steps: int = 24,
    physics: bool = True,
    res: int = 128,
    seed: int = 0,
    units: str = "m",
    mesh_units: str = "auto",
    device: str = "auto",
    adapter: Optional[str] = None,
) -> Dict[str, Any]:
    """Estimates the poses of a frame's objects from their masks, as
    ``plausible estimate`` does per image: resting poses x ``yaw_steps``
    yaws on the support plane (fitted outside the masks unless given),
    scored, the best ``top`` of each refined by ``method`` among the other
    objects in support order.

    ``objects``: one dict per object with "mesh", "mask" (H, W) and
    optionally "stable" (:func:`stable_poses`' list, an export or its path;
    default: the quasi-static analysis of the hull). Returns {"best": per
    object {"R", "t", "score"} or None, "objects": every refined hypothesis
    as :func:`refine` gives them, "order", "support", "plane"}."""
    s = _scale(units)
    d = _depth(depth, s)
    meshes, masks = _frame_objects(objects, units, mesh_units, d.shape)
    stable = [_export_text(o.get("stable"), m, f"object {i} stable") for i, (o, m) in enumerate(zip(objects, meshes))]
    pl = None if plane is None else _plane(plane, s)
    out = _native.estimate(
        _camera(K), d, meshes, masks, stable, plane=pl, method=method, steps=_uint("steps", steps), top=_uint("top", top),
        yaw_steps=_uint("yaw_steps", yaw_steps), physics=_bool("physics", physics), res=_uint("res", res), seed=_uint("seed", seed),
        device=device, adapter=adapter,
    )
    return _scene_out(out, s)
