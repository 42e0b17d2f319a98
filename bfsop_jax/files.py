"""Atomic file writes: the one way the project writes a result, cache or config file.

Every writer goes through :func:`atomic_write`: the content goes to a temporary file in the
same folder, which is renamed over the target only when complete, so a reader (or a run
resumed after an interruption) sees the old file or the new one, never half of one.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_write", "write_json", "write_text"]


def atomic_write(
    path: str | os.PathLike,
    write: Callable[[IO], Any],
    mode: str = "w",
    fsync: bool = False,
) -> Path:
    """Call ``write(f)`` on a temporary file next to ``path``, then rename it into place.

    ``mode``: ``"w"`` (text, newline as written) or ``"wb"``; ``fsync``: flush to disk
    before the rename (dataset shards). The folder is created; the file gets mode 0644.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        kwargs = {"newline": ""} if "b" not in mode else {}
        with os.fdopen(fd, mode, **kwargs) as f:
            write(f)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates owner-only files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` atomically."""
    return atomic_write(path, lambda f: f.write(text))


def write_json(path: str | os.PathLike, obj: Any, indent: int = 1, **kwargs: Any) -> Path:
    """Write ``obj`` as JSON (sorted keys unless ``sort_keys=False``) atomically."""
    kwargs.setdefault("sort_keys", True)
    return write_text(path, json.dumps(obj, indent=indent, **kwargs) + "\n")
