"""Command-line helpers shared by the benchmark scripts: checked argument types and an
entry point that turns bad input into a one-line error.

``type=positive_int`` (sizes, batches, repeats) and ``type=count`` (how many of something
to run, 0 to skip it) make argparse reject a bad value with its usual usage line and one
error line; :func:`run_main` prints ``error: <message>`` and exits with status 2 when the
script's ``main`` raises ``ValueError`` (an unknown preset, method or model).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["count", "positive_float", "positive_int", "run_main"]


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def positive_int(text: str) -> int:
    """An integer >= 1 (argparse type)."""
    value = _int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def count(text: str) -> int:
    """An integer >= 0, 0 meaning none (argparse type)."""
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def run_main(main: Callable[[], Any]) -> None:
    """Call ``main()``; a ``ValueError`` becomes ``error: <message>`` and exit status 2."""
    try:
        main()
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
