"""Test fixtures shared by every test module."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings

REPO_ROOT = Path(__file__).resolve().parents[1]

# Most of the suite's time is XLA compilation, and many tests compile the same programs
# (house generation, rollouts of one strategy at one batch size) from fresh closures, in
# either of the two xdist workers. JAX's persistent compilation cache, shared by the
# workers (and by the experiments the tests start as subprocesses), compiles each one
# that takes 0.5 s or more once (docs/benchmarks.md, "The test suite").
# - The folder is new for every test session (made here, in the process that starts the
#   workers, which inherit the variable) and removed at its end: an entry left half
#   written by a killed run, or by another checkout, is never read (XLA aborts the
#   process on an executable it cannot deserialize).
# - A size limit turns on JAX's file lock around every cache read and write, so one
#   worker never reads a file the other is still writing.
# Set JAX_COMPILATION_CACHE_DIR to keep a folder of your own between runs instead.
_OWN_CACHE_DIR: str | None = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _OWN_CACHE_DIR = tempfile.mkdtemp(prefix="bfsop-jax-test-xla-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _OWN_CACHE_DIR
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(16 << 30))


# Property tests draw the same examples on every run (seeded from each test's name), so
# the suite's verdict does not change from one run to the next. To search for new
# counterexamples with fresh random examples, run with HYPOTHESIS_PROFILE=explore.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


def pytest_unconfigure(config: pytest.Config) -> None:
    """Remove this session's compilation cache (in the process that made it)."""
    if _OWN_CACHE_DIR is not None and not hasattr(config, "workerinput"):
        shutil.rmtree(_OWN_CACHE_DIR, ignore_errors=True)


def shared_path(*parts: str) -> Path:
    """Path into the developers' shared data folder (set BFSOP_SHARED to override).

    The project never needs it at run time; tests that read it skip when it is absent.
    """
    root = Path(os.environ.get("BFSOP_SHARED", REPO_ROOT.parent / "shared"))
    return root.joinpath(*parts)


@pytest.fixture
def shared():
    """Callable returning a path inside the shared data folder, or skipping the test."""

    def _get(*parts: str) -> Path:
        p = shared_path(*parts)
        if not p.exists():
            pytest.skip(f"shared data not available: {'/'.join(parts)}")
        return p

    return _get


@pytest.fixture(scope="session")
def smoke_data_dir(tmp_path_factory) -> Path:
    """The ``smoke`` distillation dataset, generated once per test session (a cache that
    ``experiments.distill`` and ``experiments.sweep`` reuse through ``--data-dir``)."""
    from bfsop_jax.data.generate import generate_dataset
    from experiments.distill import PRESETS

    root = tmp_path_factory.mktemp("distill-smoke-data")
    generate_dataset(root, PRESETS["smoke"].data, progress=False)
    return root
