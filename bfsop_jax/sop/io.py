"""Instance sources: ``.sop`` files of the public SOP benchmark, and random instances.

``read_sop`` reads the public Set Orienteering benchmark (docs/design.md §7.2); ``random_instance``
draws synthetic instances shaped like the navigation ones (start node + sets of
viewpoints around landmarks, open path), for tests and benchmarks.

Format (TSPLIB-like)::

    NAME: 11berlin52_RND_T60_p2
    TYPE: TSP
    COMMENT: ...
    DIMENSION: 52            # number of nodes
    TMAX: 2424               # budget
    START_SET: 0             # optional, default 0
    END_SET: 0               # optional, default START_SET (closed tour)
    SETS: 12                 # number of sets, the start set included
    EDGE_WEIGHT_TYPE: CEIL_2D
    NODE_COORD_SECTION
    1 565.0 575.0            # 1-based node id, x, y
    ...
    GTSP_SET_SECTION: set_id set_profit id-vertex-list
    0 0 1                    # set id, profit, 1-based node ids
    ...

Node ``i`` of the file becomes node ``i - 1``; set ids are kept. The start (end) node is
the single node of ``START_SET`` (``END_SET``); equal sets give a closed tour
(``end == start``). CEIL_2D costs are ``ceil`` of the Euclidean distance, EUC_2D costs the
nearest integer (TSPLIB ``nint``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from bfsop_jax.sop.types import SOPInstance, validate

__all__ = ["read_sop", "random_instance"]

_EDGE_WEIGHT_TYPES = ("CEIL_2D", "EUC_2D")
_REQUIRED = ("DIMENSION", "TMAX", "SETS", "EDGE_WEIGHT_TYPE")


class _Malformed(ValueError):
    pass


def read_sop(path: str | os.PathLike) -> SOPInstance:
    """Read a ``.sop`` file into a validated NumPy :class:`SOPInstance`.

    Shapes: ``cost`` [N, N] float32 (N = DIMENSION), ``set_id`` [N] int32 (nodes in no set
    get -1), ``set_reward`` [K] float32 (K = SETS), ``coords`` [N, 2] float32.
    Raises ``ValueError`` naming the file and line for malformed input.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not a text file ({err})") from None
    try:
        return _parse(text)
    except _Malformed as err:
        raise ValueError(f"{path}: {err}") from None


def _fail(lineno: int, msg: str) -> _Malformed:
    return _Malformed(f"line {lineno}: {msg}")


def _parse(text: str) -> SOPInstance:
    lines = text.splitlines()
    header: dict[str, tuple[str, int]] = {}
    coords: dict[int, tuple[float, float]] = {}
    sets: dict[int, tuple[float, list[int], int]] = {}
    section = "header"
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line:
            continue
        upper = line.upper()
        if upper == "EOF":
            break
        if upper.startswith("NODE_COORD_SECTION"):
            section = "coords"
            continue
        if upper.startswith("GTSP_SET_SECTION"):
            section = "sets"
            continue
        if section == "header":
            key, sep, value = line.partition(":")
            if not sep:
                raise _fail(lineno, f"expected 'KEY: value' in the header, got {line!r}")
            key = key.strip().upper()
            if key in header:
                raise _fail(lineno, f"duplicate header key {key}")
            header[key] = (value.strip(), lineno)
            continue
        tokens = line.split()
        if section == "coords":
            if len(tokens) != 3:
                raise _fail(lineno, f"node line needs 'id x y', got {line!r}")
            node = _int(tokens[0], lineno, "node id")
            x, y = _float(tokens[1], lineno, "x"), _float(tokens[2], lineno, "y")
            if node in coords:
                raise _fail(lineno, f"node {node} defined twice")
            coords[node] = (x, y)
        else:  # sets
            if len(tokens) < 3:
                raise _fail(lineno, f"set line needs 'set_id profit node_ids...', got {line!r}")
            sid = _int(tokens[0], lineno, "set id")
            profit = _float(tokens[1], lineno, "set profit")
            members = [_int(t, lineno, "node id") for t in tokens[2:]]
            if sid in sets:
                raise _fail(lineno, f"set {sid} defined twice")
            sets[sid] = (profit, members, lineno)

    last = len(lines)
    for key in _REQUIRED:
        if key not in header:
            raise _fail(last, f"missing header key {key}")
    n = _header_int(header, "DIMENSION")
    k = _header_int(header, "SETS")
    budget = _header_float(header, "TMAX")
    start_set = _header_int(header, "START_SET") if "START_SET" in header else 0
    end_set = _header_int(header, "END_SET") if "END_SET" in header else start_set
    weight_type, wt_line = header["EDGE_WEIGHT_TYPE"]
    if weight_type.upper() not in _EDGE_WEIGHT_TYPES:
        raise _fail(wt_line, f"EDGE_WEIGHT_TYPE {weight_type!r} unsupported {_EDGE_WEIGHT_TYPES}")
    if n < 1 or k < 1:
        raise _fail(header["DIMENSION"][1], f"DIMENSION {n} and SETS {k} must be positive")
    if budget < 0 or math.isnan(budget):
        raise _fail(header["TMAX"][1], f"TMAX must be a non-negative number, got {budget}")

    if len(coords) != n:
        raise _fail(
            header["DIMENSION"][1],
            f"DIMENSION is {n} but NODE_COORD_SECTION has {len(coords)} nodes",
        )
    if sorted(coords) != list(range(1, n + 1)):
        bad = min(set(coords) ^ set(range(1, n + 1)))
        raise _fail(last, f"node ids must be 1..{n}; node {bad} is missing or out of range")
    if len(sets) != k:
        raise _fail(header["SETS"][1], f"SETS is {k} but GTSP_SET_SECTION has {len(sets)} sets")

    set_id = np.full(n, -1, np.int32)
    set_reward = np.zeros(k, np.float32)
    for sid, (profit, members, lineno) in sets.items():
        if not 0 <= sid < k:
            raise _fail(lineno, f"set id {sid} outside [0, {k})")
        if profit < 0:
            raise _fail(lineno, f"negative profit {profit} of set {sid}")
        set_reward[sid] = profit
        for node in members:
            if not 1 <= node <= n:
                raise _fail(lineno, f"node {node} of set {sid} outside 1..{n}")
            if set_id[node - 1] >= 0:
                raise _fail(lineno, f"node {node} is in sets {set_id[node - 1]} and {sid}")
            set_id[node - 1] = sid

    for name, sid in (("START_SET", start_set), ("END_SET", end_set)):
        if sid not in sets:
            raise _fail(header[name][1] if name in header else last, f"{name} {sid} not defined")
        profit, members, lineno = sets[sid]
        if len(members) != 1 or profit != 0:
            raise _fail(lineno, f"{name} {sid} must hold exactly one node with profit 0")
    start = sets[start_set][1][0] - 1
    end = sets[end_set][1][0] - 1

    xy = np.array([coords[i + 1] for i in range(n)], np.float64)
    dist = np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1))
    if weight_type.upper() == "CEIL_2D":
        cost = np.ceil(dist)
    else:
        cost = np.floor(dist + 0.5)
    inst = SOPInstance(
        cost=cost.astype(np.float32),
        set_id=set_id,
        set_reward=set_reward,
        start=np.int32(start),
        end=np.int32(end),
        budget=np.float32(budget),
        coords=xy.astype(np.float32),
    )
    try:
        validate(inst)
    except ValueError as err:
        raise _Malformed(str(err)) from None
    return inst


def _int(token: str, lineno: int, what: str) -> int:
    try:
        return int(token)
    except ValueError:
        try:
            value = float(token)
        except ValueError:
            raise _fail(lineno, f"{what} {token!r} is not a number") from None
        if not value.is_integer():
            raise _fail(lineno, f"{what} {token!r} is not an integer") from None
        return int(value)


def _float(token: str, lineno: int, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise _fail(lineno, f"{what} {token!r} is not a number") from None
    if not math.isfinite(value):
        raise _fail(lineno, f"{what} {token!r} is not finite")
    return value


def _header_int(header: dict[str, tuple[str, int]], key: str) -> int:
    value, lineno = header[key]
    return _int(value, lineno, key)


def _header_float(header: dict[str, tuple[str, int]], key: str) -> float:
    value, lineno = header[key]
    return _float(value, lineno, key)


def random_instance(
    seed: int | np.random.Generator,
    num_sets: int = 15,
    viewpoints: int = 5,
    closed: bool = False,
    budget_scale: float = 0.35,
    masked_sets: int = 0,
    box: tuple[float, float] = (30.0, 20.0),
) -> SOPInstance:
    """A random instance shaped like the navigation SOP (docs/design.md §7.1).

    Node 0 is the start (set 0, reward 0); set k = 1..num_sets has ``viewpoints`` nodes
    0.5-1.0 m around a landmark drawn uniformly in a ``box`` (metres); rewards are uniform
    in [0.1, 1]. Costs are Euclidean distances times a detour factor of 1.2. The budget is
    ``budget_scale`` times a nearest-neighbour tour through all landmarks, which lets about
    half of the sets fit at the default. The last ``masked_sets`` sets are masked: reward
    0, their nodes padding (set_id -1, unreachable), as for missing landmarks.

    Shapes: N = 1 + num_sets * viewpoints nodes, K = num_sets + 1 sets.
    """
    rng = np.random.default_rng(seed)
    k, v = num_sets, viewpoints
    centres = rng.uniform((0.0, 0.0), box, size=(k, 2))
    angle = rng.uniform(0.0, 2 * np.pi, size=(k, v))
    radius = rng.uniform(0.5, 1.0, size=(k, v))
    around = np.stack([np.cos(angle), np.sin(angle)], axis=-1) * radius[..., None]
    start = rng.uniform((0.0, 0.0), box)
    coords = np.concatenate([start[None], (centres[:, None, :] + around).reshape(-1, 2)])
    cost = 1.2 * np.linalg.norm(coords[:, None] - coords[None], axis=-1)
    set_id = np.concatenate([[0], np.repeat(np.arange(1, k + 1), v)]).astype(np.int32)
    reward = np.concatenate([[0.0], rng.uniform(0.1, 1.0, k)])
    # nearest-neighbour tour through the landmarks sets the budget scale
    here, left, length = start, list(range(k)), 0.0
    while left:
        dist = [np.linalg.norm(centres[j] - here) for j in left]
        j = left.pop(int(np.argmin(dist)))
        length += 1.2 * min(dist)
        here = centres[j]
    if masked_sets:
        masked = np.isin(set_id, np.arange(k - masked_sets + 1, k + 1))
        set_id[masked] = -1
        cost[masked, :] = np.inf
        cost[:, masked] = np.inf
        reward[k - masked_sets + 1 :] = 0.0
    return SOPInstance.create(
        cost=cost,
        set_id=set_id,
        set_reward=reward,
        start=0,
        end=0 if closed else -1,
        budget=budget_scale * length,
        coords=coords,
    )
