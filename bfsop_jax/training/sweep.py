"""Hyper-parameter grids: parsing, validation, and grouping into compiled programs.

A grid maps keys to lists of values; a *combination* takes one value of every key (the
Cartesian product, in the order the keys were given). Keys come in two kinds:

- **replica keys** (:data:`REPLICA_KEYS`: seed, learning rate, clip, decay, warm-up,
  label smoothing, augmentation) change no array shape: combinations that differ only in
  them are replicas of **one** vmapped, jitted training program
  (:func:`bfsop_jax.training.train` with ``replicas=``);
- **group keys** (:data:`GROUP_KEYS`: layers, width, heads, feed-forward width, geometric
  bias, decoder flags, batch size, epochs) change the parameter tree, the batch shape or
  the run length: each distinct set of their values is a *group*, compiled once.

``parse_grid_args(["lr=3e-4,1e-3", "seed=0,1"])`` and ``read_grid_file("grid.toml")``
(a ``[grid]`` table, or top-level keys, of lists) both return a validated ``Grid``; a bad
grid (unknown key, empty list, a value of the wrong type, a duplicate key or value) is a
``ValueError`` naming the key, raised before anything runs.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import tomllib

from bfsop_jax.training.config import Replica, RunConfig

__all__ = [
    "Combination",
    "GROUP_KEYS",
    "Grid",
    "Group",
    "REPLICA_KEYS",
    "combinations",
    "groups",
    "merge_grids",
    "parse_grid_args",
    "read_grid_file",
    "validate_grid",
]

Grid = dict[str, list[Any]]

# grid key -> (type, Replica field)
REPLICA_KEYS: dict[str, tuple[type, str]] = {
    "seed": (int, "seed"),
    "lr": (float, "lr"),
    "grad_clip": (float, "grad_clip"),
    "lr_decay": (float, "lr_decay"),
    "decay_every": (int, "decay_every"),
    "warmup": (float, "warmup_epochs"),
    "label_smoothing": (float, "label_smoothing"),
    "augment": (bool, "augment"),
    "on_policy": (float, "on_policy"),
}
# grid key -> (type, "model" | "train", field)
GROUP_KEYS: dict[str, tuple[type, str, str]] = {
    "layers": (int, "model", "n_layers"),
    "width": (int, "model", "d_model"),
    "heads": (int, "model", "n_heads"),
    "ff": (int, "model", "d_ff"),
    "geometric_bias": (bool, "model", "geometric_bias"),
    "budget_aware": (bool, "model", "budget_aware"),
    "budget_mask": (bool, "model", "budget_mask"),
    "step_features": (bool, "model", "step_features"),
    "decoder": (str, "model", "decoder"),  # append | insertion
    "refine": (bool, "model", "refine"),  # insertion: improve the route after each insertion
    "batch_size": (int, "train", "batch_size"),
    "epochs": (int, "train", "epochs"),
}
_TYPE_NAMES = {int: "an integer", float: "a number", bool: "true or false", str: "a name"}


def _key_type(key: str) -> type:
    if key in REPLICA_KEYS:
        return REPLICA_KEYS[key][0]
    if key in GROUP_KEYS:
        return GROUP_KEYS[key][0]
    valid = ", ".join(sorted([*REPLICA_KEYS, *GROUP_KEYS]))
    raise ValueError(f"unknown grid key {key!r}; valid keys: {valid}")


def _coerce(key: str, value: Any) -> Any:
    """``value`` as the key's type (strings from the command line are parsed)."""
    kind = _key_type(key)
    want = _TYPE_NAMES[kind]
    if kind is str:  # checked against the model's choices with the other settings
        if not isinstance(value, str):
            raise ValueError(f"grid key {key!r}: {value!r} is not {want}")
        return value.strip()
    if isinstance(value, str):
        text = value.strip()
        if kind is bool:
            if text.lower() in ("true", "1", "yes", "on"):
                return True
            if text.lower() in ("false", "0", "no", "off"):
                return False
            raise ValueError(f"grid key {key!r}: {value!r} is not {want}")
        try:
            number = float(text)
        except ValueError:
            raise ValueError(f"grid key {key!r}: {value!r} is not {want}") from None
        value = number
        if kind is int:
            if not number.is_integer():
                raise ValueError(f"grid key {key!r}: {text!r} is not {want}")
            return int(number)
        return float(number)
    if kind is bool:
        if not isinstance(value, bool):
            raise ValueError(f"grid key {key!r}: {value!r} is not {want}")
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"grid key {key!r}: {value!r} is not {want}")
    if kind is int:
        if isinstance(value, float) and not value.is_integer():
            raise ValueError(f"grid key {key!r}: {value!r} is not {want}")
        return int(value)
    return float(value)


def validate_grid(raw: Mapping[str, Sequence[Any]], base: RunConfig | None = None) -> Grid:
    """Typed, checked copy of a grid; ValueError naming the first bad key.

    Every combination must also be a valid setting on ``base`` (default: the tiny preset),
    e.g. a positive learning rate, heads that divide the width.
    """
    if not raw:
        raise ValueError("the grid is empty: give at least one key (e.g. --grid lr=1e-3)")
    grid: Grid = {}
    for key, values in raw.items():
        if isinstance(values, str | bytes) or not isinstance(values, Sequence):
            values = [values]
        if len(values) == 0:
            raise ValueError(f"grid key {key!r} has an empty list of values")
        typed = [_coerce(key, v) for v in values]
        if len(set(typed)) != len(typed):
            raise ValueError(f"grid key {key!r} lists a value twice: {list(values)}")
        grid[key] = typed
    # every value must also be a valid setting (e.g. lr > 0, heads dividing the width)
    base = base or RunConfig.named("tiny")
    for combo in combinations(grid):
        try:
            combo.replica(combo.run_config(base))
        except ValueError as err:
            raise ValueError(f"grid combination {combo.name}: {err}") from None
    return grid


def parse_grid_args(items: Sequence[str], base: RunConfig | None = None) -> Grid:
    """A grid from ``key=v1,v2,...`` strings (``--grid`` arguments); a repeated key is an
    error."""
    raw: dict[str, list[str]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--grid {item!r}: expected key=v1,v2,...")
        _key_type(key)
        if key in raw:
            raise ValueError(f"grid key {key!r} is given twice")
        raw[key] = [v for v in values.split(",") if v.strip()]
    return validate_grid(raw, base)


def read_grid_file(path: str | Path, base: RunConfig | None = None) -> Grid:
    """A grid from a TOML file: a ``[grid]`` table (or top-level keys) of lists."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"grid file {path} does not exist") from None
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"grid file {path} is not valid TOML: {err}") from None
    table = data.get("grid", data)
    if not isinstance(table, dict):
        raise ValueError(f"grid file {path}: [grid] must be a table of lists")
    return validate_grid(table, base)


def merge_grids(*grids: Grid, base: RunConfig | None = None) -> Grid:
    """One grid from several (e.g. a file and command-line keys); a key in two is an error."""
    out: Grid = {}
    for grid in grids:
        for key, values in grid.items():
            if key in out:
                raise ValueError(f"grid key {key!r} is given twice")
            out[key] = values
    return validate_grid(out, base)


@dataclasses.dataclass(frozen=True)
class Combination:
    """One point of the grid: ``values`` in the grid's key order."""

    values: tuple[tuple[str, Any], ...]

    @property
    def settings(self) -> dict[str, Any]:
        return dict(self.values)

    @property
    def name(self) -> str:
        """Readable, filesystem-safe and unique within a grid, e.g. ``lr-0.001_seed-0``."""
        parts = [f"{k}-{_fmt(v)}" for k, v in self.values]
        return re.sub(r"[^A-Za-z0-9._=-]", "_", "_".join(parts)) or "default"

    @property
    def group_values(self) -> tuple[tuple[str, Any], ...]:
        return tuple((k, v) for k, v in self.values if k in GROUP_KEYS)

    def run_config(self, base: RunConfig) -> RunConfig:
        """``base`` with this combination's group keys applied (validated)."""
        model, recipe = {}, {}
        for key, value in self.group_values:
            _, part, field = GROUP_KEYS[key]
            (model if part == "model" else recipe)[field] = value
        return RunConfig(
            model=dataclasses.replace(base.model, **model),
            train=dataclasses.replace(base.train, **recipe),
            preset=base.preset,
        )

    def replica(self, config: RunConfig, default_seed: int = 0, default_lr: float = 1e-4):
        """This combination's :class:`Replica` on the recipe of ``config``."""
        fields = {REPLICA_KEYS[k][1]: v for k, v in self.values if k in REPLICA_KEYS}
        seed = fields.pop("seed", default_seed)
        lr = fields.pop("lr", default_lr)
        return Replica.of(config.train, seed, lr, **fields)


def _fmt(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def combinations(grid: Grid) -> list[Combination]:
    """Every combination of the grid (Cartesian product, first key slowest)."""
    keys = list(grid)
    return [
        Combination(tuple(zip(keys, values, strict=True)))
        for values in itertools.product(*(grid[k] for k in keys))
    ]


@dataclasses.dataclass(frozen=True)
class Group:
    """Combinations that share every group key: one compiled training program."""

    values: tuple[tuple[str, Any], ...]
    members: tuple[Combination, ...]

    @property
    def name(self) -> str:
        parts = [f"{k}-{_fmt(v)}" for k, v in self.values]
        return "_".join(parts) or "all"


def groups(grid: Grid) -> list[Group]:
    """The grid's combinations grouped by their group-key values (first-seen order)."""
    table: dict[tuple[tuple[str, Any], ...], list[Combination]] = {}
    for combo in combinations(grid):
        table.setdefault(combo.group_values, []).append(combo)
    return [Group(values, tuple(members)) for values, members in table.items()]
