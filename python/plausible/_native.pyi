"""Type stubs of the native module (pyo3). The public API is re-exported,
with argument coercion, by :mod:`plausible`."""

from os import PathLike
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
MAX_POSES: int

_Path = Union[str, PathLike]

class Mesh:
    """A validated triangle mesh in metres."""

    def __init__(self, vertices: npt.ArrayLike, faces: npt.ArrayLike, units: str = "m", name: str = "<arrays>") -> None: ...
    @staticmethod
    def load(path: _Path, units: str = "auto") -> Mesh: ...
    @property
    def vertices(self) -> npt.NDArray[np.float64]: ...
    @property
    def faces(self) -> npt.NDArray[np.uint32]: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def diagonal(self) -> float: ...
    @property
    def sha256(self) -> str: ...
    def __len__(self) -> int: ...
    def __reduce__(self) -> Tuple[Any, Tuple[Any, ...]]: ...
    @staticmethod
    def _restore(vertices: npt.NDArray[np.float64], faces: npt.NDArray[np.uint32], source: Optional[_Path], warnings: List[str]) -> Mesh: ...

class Scorer:
    def __init__(
        self,
        mesh: Mesh,
        k: npt.NDArray[np.float64],
        depth: npt.NDArray[np.float32],
        mask: Optional[npt.NDArray[np.bool_]] = None,
        *,
        res: int = 128,
        tau: float = 0.02,
        alpha: float = 0.7,
        margin: float = 0.25,
        device: str = "auto",
        adapter: Optional[str] = None,
        lod: str = "auto",
    ) -> None: ...
    def score(
        self,
        r: npt.NDArray[np.float64],
        t: npt.NDArray[np.float64],
        plane: Optional[Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = None,
        *,
        samples: int = 1024,
        seed: int = 0,
        epsilon: Optional[float] = None,
        orthonormalize: bool = False,
    ) -> Dict[str, Any]: ...
    @property
    def device(self) -> str: ...
    @property
    def scoring_mesh(self) -> str: ...
    @property
    def region(self) -> Tuple[Tuple[int, int], Tuple[float, float, float, float]]: ...

def fit_plane(
    k: npt.NDArray[np.float64],
    depth: npt.NDArray[np.float32],
    mask: Optional[npt.NDArray[np.bool_]] = None,
    *,
    inlier: float = 0.005,
    iterations: int = 500,
    seed: int = 0,
    mask_margin: int = 5,
) -> Dict[str, Any]: ...
def check(
    scene_json: str,
    base: _Path,
    name: _Path,
    *,
    samples: int = ...,
    seed: int = ...,
    epsilon: Optional[float] = None,
    sdf_resolution: int = ...,
    friction: float = ...,
    simulate: bool = False,
) -> List[Dict[str, Any]]: ...
def stable_poses(mesh: Mesh, *, drops: int = 1000, seed: int = 0, collider: str = "hull", threads: Optional[int] = None) -> Dict[str, Any]: ...
def hypotheses(
    mesh: Mesh,
    k: npt.NDArray[np.float64],
    depth: npt.NDArray[np.float32],
    mask: npt.NDArray[np.bool_],
    plane_point: npt.NDArray[np.float64],
    plane_normal: npt.NDArray[np.float64],
    *,
    stable_export: Optional[str] = None,
    yaw_steps: int = 24,
    grid_radius: int = 0,
    grid_step: float = 0.005,
    min_probability: float = 0.01,
) -> Dict[str, npt.NDArray[Any]]: ...
def evaluate(
    dataset: _Path,
    results: _Path,
    *,
    targets: Optional[_Path] = None,
    split: str = "test",
    errors: Optional[List[str]] = None,
    add_threshold: float = 0.1,
    dataset_name: Optional[str] = None,
    device: str = "auto",
    adapter: Optional[str] = None,
    records: bool = False,
    task: str = "localization",
    max_estimates_per_image: Optional[int] = None,
    sensor: Optional[str] = None,
    boxes: Optional[str] = None,
) -> Dict[str, Any]: ...
def device_info(adapter: Optional[str] = None) -> Tuple[str, str]: ...
def read_frame(
    camera: _Path, depth: _Path, mask: Optional[_Path] = None, frame: Optional[str] = None
) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float32], Optional[npt.NDArray[np.bool_]]]: ...
def refine(
    k: npt.NDArray[np.float64],
    depth: npt.NDArray[np.float32],
    meshes: List[Mesh],
    masks_in: List[npt.NDArray[np.bool_]],
    rs: List[npt.NDArray[np.float64]],
    ts: List[npt.NDArray[np.float64]],
    leads: List[int],
    *,
    plane: Optional[Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = None,
    method: str = "rir",
    steps: int = 2,
    budget: Optional[int] = None,
    physics: bool = True,
    res: int = 128,
    seed: int = 0,
    device: str = "auto",
    adapter: Optional[str] = None,
) -> Dict[str, Any]: ...
def estimate(
    k: npt.NDArray[np.float64],
    depth: npt.NDArray[np.float32],
    meshes: List[Mesh],
    masks_in: List[npt.NDArray[np.bool_]],
    stable: List[Optional[str]],
    *,
    plane: Optional[Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = None,
    method: str = "rir",
    steps: int = 2,
    top: int = 5,
    yaw_steps: int = 24,
    physics: bool = True,
    res: int = 128,
    seed: int = 0,
    device: str = "auto",
    adapter: Optional[str] = None,
) -> Dict[str, Any]: ...
