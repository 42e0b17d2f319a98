"""Versioned, resumable array shards on disk (docs/design.md §8.2, §12).

A dataset directory holds ``meta.json`` and ``shard-00000.npz``, ``shard-00001.npz``, ...
Every shard is written to a temporary file and renamed into place, and ``meta.json`` is
rewritten (atomically too) only after the shard is complete, so an interrupted run never
leaves a half-written shard that a later run would take as complete: a shard counts only
when ``meta.json`` lists it and its file loads.

``meta.json``: ``{"format": FORMAT_VERSION, "config": {...}, "shards": {"0": {...}, ...}}``.
A directory whose ``config`` differs from the requested one is not reused (a clear error
says so), which makes the cache safe: same config in, same data out.

Several machines: each process writes its part of the shards into its *own* directory
(one ``meta.json`` per writer; two processes sharing a directory would overwrite each
other's ``meta.json``), and :func:`merge_datasets` then gathers the directories into one.
From the command line (``docs/scale-out.md``)::

    python -m experiments.distill --preset P --merge-data DIR_A,DIR_B [--data-dir DST]

The merge copies each shard that ``DST`` lacks atomically and records it in
``DST/meta.json`` right after the copy, so an interrupted merge is simply run again.
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from bfsop_jax.files import atomic_write

__all__ = ["FORMAT_VERSION", "ShardStore", "merge_datasets"]

FORMAT_VERSION = 1

_CHUNK = 1 << 20


def _atomic_write_bytes(path: Path, write) -> None:
    atomic_write(path, write, mode="wb", fsync=True)


def _read_meta(root: Path) -> dict[str, Any] | None:
    """``root/meta.json`` checked for its format, or None when there is none."""
    meta_path = root / "meta.json"
    if not meta_path.exists():
        return None
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"corrupt dataset metadata {meta_path}: {e}") from None
    if meta.get("format") != FORMAT_VERSION:
        raise ValueError(
            f"{meta_path} has format {meta.get('format')}, this code reads "
            f"{FORMAT_VERSION}; use a new dataset directory"
        )
    return meta


class ShardStore:
    """A directory of numbered ``.npz`` shards plus ``meta.json``."""

    def __init__(self, root: str | os.PathLike, config: dict[str, Any]):
        self.root = Path(root)
        self.config = json.loads(json.dumps(config))  # normalise to JSON types
        self.root.mkdir(parents=True, exist_ok=True)
        meta = _read_meta(self.root)
        if meta is not None:
            if meta.get("config") != self.config:
                raise ValueError(
                    f"dataset directory {self.root} was made with another configuration; "
                    "use a new directory (or delete it) to generate this one"
                )
            self.meta = meta
        else:
            self.meta = {"format": FORMAT_VERSION, "config": self.config, "shards": {}}
            self._write_meta()

    @classmethod
    def open(cls, root: str | os.PathLike) -> ShardStore:
        """An existing dataset directory, with the configuration its ``meta.json`` holds."""
        meta = _read_meta(Path(root))
        if meta is None:
            raise ValueError(f"{root} is not a dataset directory (no meta.json)")
        return cls(root, meta.get("config"))

    # -- queries ------------------------------------------------------------------------
    def shard_path(self, index: int) -> Path:
        """Where shard ``index`` lives (whether or not it is complete)."""
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
        """Indices of the complete shards, ascending."""
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

    def reconfigure(self, config: dict[str, Any], keep: Iterable[int]) -> None:
        """Record a new configuration for this directory, keeping only the shards
        ``keep`` (the others are forgotten and will be generated again). For a caller
        that knows those shards are what ``config`` would produce, e.g. a dataset grown
        to more houses."""
        keep = {str(i) for i in keep}
        self.config = json.loads(json.dumps(config))
        shards = {k: v for k, v in self.meta["shards"].items() if k in keep}
        self.meta = {**self.meta, "config": self.config, "shards": shards}
        self._write_meta()

    def _copy_shard(self, index: int, src: Path, info: dict[str, Any]) -> None:
        """Copy a complete shard file in atomically, then record it in ``meta.json``."""

        def copy(f):
            with open(src, "rb") as g:
                shutil.copyfileobj(g, f, _CHUNK)

        _atomic_write_bytes(self.shard_path(index), copy)
        self.meta["shards"][str(index)] = dict(info)
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


# -- merging ----------------------------------------------------------------------------
def _same_stream(a, b) -> bool:
    while True:
        x, y = a.read(_CHUNK), b.read(_CHUNK)
        if x != y:
            return False
        if not x:
            return True


def _same_shard(a: Path, b: Path) -> bool:
    """Whether two shard files hold the same bytes: same archive members, each with the
    same ``.npy`` bytes (dtype, shape and data). Zip timestamps are ignored, so the same
    shard generated twice (at different times, on different machines) compares equal."""
    if a.samefile(b):
        return True
    if a.stat().st_size == b.stat().st_size:
        with open(a, "rb") as fa, open(b, "rb") as fb:
            if _same_stream(fa, fb):
                return True
    with zipfile.ZipFile(a) as za, zipfile.ZipFile(b) as zb:
        names = sorted(za.namelist())
        if names != sorted(zb.namelist()):
            return False
        for name in names:
            if za.getinfo(name).file_size != zb.getinfo(name).file_size:
                return False
            with za.open(name) as ma, zb.open(name) as mb:
                if not _same_stream(ma, mb):
                    return False
    return True


def _config_diff(a: dict[str, Any], b: dict[str, Any]) -> str:
    keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    shown = ", ".join(f"{k}: {a.get(k)!r} vs {b.get(k)!r}" for k in keys[:4])
    return shown + (f", ... ({len(keys)} keys)" if len(keys) > 4 else "")


def merge_datasets(
    dst: str | os.PathLike,
    sources: Iterable[str | os.PathLike],
    config: dict[str, Any] | None = None,
) -> ShardStore:
    """Merge dataset directories made with the same configuration into ``dst``.

    Each source is a directory written by :class:`ShardStore` (for instance by one
    process of ``generate_dataset(..., shard=(i, n))``); ``dst`` may be one of them or a
    new directory. Every complete shard of a source that ``dst`` lacks is copied in
    atomically (temporary file, then rename) and recorded in ``dst/meta.json`` right
    after its copy, so an interrupted merge can simply be run again. Sources are left
    untouched; shards a source lists but cannot read are skipped with a warning.

    Args:
        dst: the merged dataset directory (created if needed).
        sources: the directories to merge (at least one).
        config: if given, every directory must have been made with this configuration.

    Returns:
        The :class:`ShardStore` of ``dst``.

    Raises:
        ValueError: a source is not a dataset directory; two directories (sources,
            ``dst`` if it already exists, ``config``) disagree on the configuration
            (the message names the directory that differs); or a shard index is present
            in two of them with different contents (the message names the index).
            Nothing is copied in these cases.
    """
    dst = Path(dst)
    roots: dict[Path, Path] = {}  # resolved -> as given; a directory named twice counts once
    for src in sources:
        roots.setdefault(Path(src).resolve(), Path(src))
    if not roots:
        raise ValueError("merge_datasets needs at least one source directory")
    stores = [ShardStore.open(r) for r in roots.values()]
    if config is not None:
        ref, ref_name = json.loads(json.dumps(config)), "the requested configuration"
    else:
        ref, ref_name = stores[0].config, f"{stores[0].root}"
    if dst.resolve() not in roots and _read_meta(dst) is not None:
        stores.append(ShardStore.open(dst))  # an existing destination must agree too
    for s in stores:
        if s.config != ref:
            raise ValueError(
                f"dataset directory {s.root} was made with another configuration than "
                f"{ref_name} ({_config_diff(s.config, ref)}); only datasets of one "
                "configuration can be merged"
            )

    # the directories holding a complete copy of each shard index, in source order
    found: dict[int, list[ShardStore]] = {}
    for s in stores:
        listed = sorted(int(k) for k in s.meta["shards"])
        complete = s.complete_shards()
        for i in sorted(set(listed) - set(complete)):
            warnings.warn(f"{s.shard_path(i)} is listed but unreadable; skipped", stacklevel=2)
        for i in complete:
            found.setdefault(i, []).append(s)
    labels: dict[str, tuple[Any, Path]] = {}  # how shards were labelled, where first seen
    for s in stores:
        for info in s.meta["shards"].values():
            for key in ("prior", "vns_config"):  # recorded since they are
                if key in info and labels.setdefault(key, (info[key], s.root))[0] != info[key]:
                    raise ValueError(
                        f"dataset directories {labels[key][1]} and {s.root} were labelled with "
                        f"another {'co-occurrence prior' if key == 'prior' else 'VNS teacher'}"
                        "; only datasets labelled alike can be merged"
                    )
    for i, holders in sorted(found.items()):
        first = holders[0]
        for other in holders[1:]:
            if not _same_shard(first.shard_path(i), other.shard_path(i)):
                raise ValueError(
                    f"shard {i} differs between {first.root} and {other.root}; the same "
                    "index must hold the same data (made by different code or settings?)"
                )

    target = ShardStore(dst, ref)
    for i, holders in sorted(found.items()):
        if target.is_complete(i):
            continue
        src = holders[0]  # dst itself holds no complete copy of shard i here
        target._copy_shard(i, src.shard_path(i), src.meta["shards"][str(i)])
    return target
