"""Shared fixtures: the demo's inputs written by the CLI, and the CLI itself
(the parity tests compare the package with `plausible score` on them)."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def cli() -> str:
    """The `plausible` binary: $PLAUSIBLE_BIN, else the repository's release
    or debug build, else one on PATH. A missing binary fails the tests that
    need it with the command that builds it."""
    env = os.environ.get("PLAUSIBLE_BIN")
    if env:
        return env
    for p in (ROOT / "target" / "release" / "plausible", ROOT / "target" / "debug" / "plausible"):
        if p.exists():
            return str(p)
    found = shutil.which("plausible")
    if found:
        return found
    pytest.fail("the plausible CLI is needed for the parity tests: build it with `cargo build --release` (or set PLAUSIBLE_BIN)")


def run(*args: str) -> subprocess.CompletedProcess:
    out = subprocess.run([cli(), *args], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out


@pytest.fixture(scope="session")
def demo(tmp_path_factory) -> Path:
    """The demo's inputs (4096 hypotheses of the duck on a table):
    $PLAUSIBLE_DEMO_DIR when set (CI points it at the README demo's
    output), else written now by `plausible demo`."""
    env = os.environ.get("PLAUSIBLE_DEMO_DIR")
    if env and (Path(env) / "poses.json").exists():
        return Path(env)
    out = tmp_path_factory.mktemp("demo")
    run("demo", "--out", str(out), "--device", "cpu")
    return out


def gpu_required() -> bool:
    return os.environ.get("PLAUSIBLE_REQUIRE_GPU") == "1"
