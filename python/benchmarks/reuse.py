"""Reuse of a Scorer across calls: 100 calls of 64 poses against one call of
6400 poses on the demo's inputs (the pipeline, mesh and observation stay
loaded, so many small calls should cost little more than one big one).

    python python/benchmarks/reuse.py DEMO_DIR [--device cpu|gpu] [--repeat 3]

DEMO_DIR is the output of `plausible demo --out DEMO_DIR`. Prints a line per
device and a JSON summary (best of --repeat runs of each)."""

import argparse
import json
import time
from pathlib import Path

import numpy as np

import plausible as pl


def poses(demo: Path, n: int):
    p = json.loads((demo / "poses.json").read_text())
    R = np.array([q["cam_R_m2c"] for q in p], dtype=float).reshape(-1, 3, 3)
    t = np.array([q["cam_t_m2c"] for q in p], dtype=float) * 1e-3
    idx = np.arange(n) % len(R)
    return R[idx], t[idx]


def best(f, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("demo", type=Path)
    ap.add_argument("--device", action="append", default=None)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    K, depth, mask = pl.read_frame(a.demo / "camera.json", a.demo / "depth.png", a.demo / "mask.png")
    R, t = poses(a.demo, 6400)
    rows = []
    for device in a.device or ["cpu", "gpu"]:
        scorer = pl.Scorer(a.demo / "duck_0.15m.obj", K, depth, mask, device=device)
        scorer.score(R[:64], t[:64])  # warm-up: pipeline compiled, buffers made
        one = best(lambda: scorer.score(R, t), a.repeat)
        many = best(lambda: [scorer.score(R[i:i + 64], t[i:i + 64]) for i in range(0, 6400, 64)], a.repeat)
        rows.append({"device": scorer.device, "one_call_6400_s": one, "100_calls_64_s": many, "ratio": many / one})
        print(f"{scorer.device:<50} 1 x 6400: {one:.3f} s ({6400 / one:,.0f} hyp/s)   100 x 64: {many:.3f} s   ratio {many / one:.2f}")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
