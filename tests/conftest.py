"""Test fixtures shared by every test module."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


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
