"""Versioned, resumable array shards on disk (SPEC 9.2, 14).

A dataset directory holds ``meta.json`` and ``shard-00000.npz``, ``shard-00001.npz``, ...
Every shard is written to a temporary file and renamed into place, and ``meta.json`` is
rewritten (atomically too) only after the shard is complete, so an interrupted run never
leaves a half-written shard that a later run would take as complete: a shard counts only
when ``meta.json`` lists it and its file loads.

``meta.json``: ``{"format": FORMAT_VERSION, "config": {...}, "shards": {"0": {...}, ...}}``.
A directory whose ``config`` differs from the requested one is not reused (a clear error
says so), which makes the cache safe: same config in, same data out.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["FORMAT_VERSION", "ShardStore"]

FORMAT_VERSION = 1


def _atomic_write_bytes(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ShardStore:
    """A directory of numbered ``.npz`` shards plus ``meta.json``."""

    def __init__(self, root: str | os.PathLike, config: dict[str, Any]):
        self.root = Path(root)
        self.config = json.loads(json.dumps(config))  # normalise to JSON types
        self.root.mkdir(parents=True, exist_ok=True)
        meta_path = self.root / "meta.json"
        if meta_path.exists():
            try:
                meta = json.loads(meta_path.read_text())
            except json.JSONDecodeError as e:
                raise ValueError(f"corrupt dataset metadata {meta_path}: {e}") from None
            if meta.get("format") != FORMAT_VERSION:
                raise ValueError(
                    f"{meta_path} has format {meta.get('format')}, this code reads "
                    f"{FORMAT_VERSION}; use a new dataset directory"
                )
            if meta.get("config") != self.config:
                raise ValueError(
                    f"dataset directory {self.root} was made with another configuration; "
                    "use a new directory (or delete it) to generate this one"
                )
            self.meta = meta
        else:
            self.meta = {"format": FORMAT_VERSION, "config": self.config, "shards": {}}
            self._write_meta()

    # -- queries ------------------------------------------------------------------------
    def shard_path(self, index: int) -> Path:
        return self.root / f"shard-{index:05d}.npz"

    def is_complete(self, index: int) -> bool:
        """Listed in ``meta.json`` and its file is a readable archive."""
        if str(index) not in self.meta["shards"]:
            return False
        path = self.shard_path(index)
        try:
            with zipfile.ZipFile(path) as z:
                return z.testzip() is None
        except (OSError, zipfile.BadZipFile):
            return False

    def complete_shards(self) -> list[int]:
        return sorted(int(k) for k in self.meta["shards"] if self.is_complete(int(k)))

    # -- writing ------------------------------------------------------------------------
    def write(self, index: int, arrays: dict[str, np.ndarray], info: dict | None = None) -> None:
        """Write shard ``index`` atomically, then record it in ``meta.json``."""
        if not arrays:
            raise ValueError("a shard needs at least one array")
        lengths = {k: len(v) for k, v in arrays.items()}
        if len(set(lengths.values())) != 1:
            raise ValueError(f"shard arrays disagree on their leading length: {lengths}")
        _atomic_write_bytes(
            self.shard_path(index),
            lambda f: np.savez(f, **{k: np.asarray(v) for k, v in arrays.items()}),
        )
        self.meta["shards"][str(index)] = {"rows": next(iter(lengths.values())), **(info or {})}
        self._write_meta()

    def _write_meta(self) -> None:
        data = json.dumps(self.meta, indent=1, sort_keys=True).encode()
        _atomic_write_bytes(self.root / "meta.json", lambda f: f.write(data))

    # -- reading ------------------------------------------------------------------------
    def load(self, shards: list[int] | None = None) -> dict[str, np.ndarray]:
        """Concatenate complete shards (all by default) into one dict of arrays."""
        shards = self.complete_shards() if shards is None else shards
        if not shards:
            raise ValueError(f"dataset {self.root} has no complete shard")
        parts: dict[str, list[np.ndarray]] = {}
        for i in shards:
            try:
                with np.load(self.shard_path(i)) as z:
                    for k in z.files:
                        parts.setdefault(k, []).append(z[k])
            except (OSError, ValueError, zipfile.BadZipFile) as e:
                raise ValueError(f"corrupt dataset shard {self.shard_path(i)}: {e}") from None
        return {k: np.concatenate(v) for k, v in parts.items()}
