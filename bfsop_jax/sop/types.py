"""Set Orienteering Problem data: the instance, a solution, validation and a reference evaluator.

One format serves the NumPy solvers (VNS teacher, exact DP) and the JAX code (2-opt,
budget gate, model): the leaves of :class:`SOPInstance` and :class:`Solution` are plain
arrays, NumPy or JAX, and a batch simply carries a leading batch axis on every leaf.

Conventions (docs/design.md §7.1):

* nodes ``0..N-1``; ``set_id[i]`` is the set of node ``i``, ``-1`` marks a padding node;
* sets ``0..K-1`` with reward ``set_reward[k]``; the start node forms its own zero-reward
  set; a set without nodes must have reward 0 (a masked slot);
* ``cost[i, j]`` is the travel cost from ``i`` to ``j`` (metres for navigation, CEIL_2D
  units for ``.sop`` files); ``inf`` marks an unreachable pair;
* ``end == -1``: open path (the tour ends at its last visited node); ``end == start``:
  closed tour; any other ``end`` is a fixed goal node alone in its own zero-reward set;
* a plan visits at most one node per set and its cost must not exceed ``budget``.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np
from flax import struct

__all__ = [
    "SOPInstance",
    "Solution",
    "validate",
    "evaluate",
    "plan_length",
    "budget_tolerance",
]


def budget_tolerance(budget: float) -> float:
    """Slack allowed when checking ``cost <= budget``.

    Solvers compare their own float64 sums strictly with the budget; the same tour summed in
    another order (or in float32) can differ in the last bits, which this slack absorbs.
    """
    return 1e-6 * max(1.0, abs(float(budget)))


def plan_length(num_sets: int) -> int:
    """Static length of a padded plan for an instance with ``num_sets`` sets (K).

    At most K-1 rewarding sets, plus the start node and, for a closed tour, the end node.
    """
    return num_sets + 1


@struct.dataclass
class SOPInstance:
    """One SOP instance (or a batch of them, with a leading batch axis on every leaf)."""

    cost: Any  # [N, N] float32: travel cost i -> j, inf = unreachable
    set_id: Any  # [N] int32: set of each node, -1 = padding node
    set_reward: Any  # [K] float32: reward of each set (0 for the start set and masked sets)
    start: Any  # [] int32: start node
    end: Any  # [] int32: -1 = open path; == start: closed tour; else a fixed goal node
    budget: Any  # [] float32: maximal tour cost
    coords: Any  # [N, 2] float32: node positions (metres or file units), for models/plots

    @property
    def num_nodes(self) -> int:
        """N (static)."""
        return int(np.shape(self.set_id)[-1])

    @property
    def num_sets(self) -> int:
        """K (static)."""
        return int(np.shape(self.set_reward)[-1])

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(np.shape(self.set_id)[:-1])

    @classmethod
    def create(
        cls,
        cost: Any,
        set_id: Any,
        set_reward: Any,
        start: int,
        end: int,
        budget: float,
        coords: Any | None = None,
    ) -> SOPInstance:
        """Build a validated single NumPy instance (dtypes float32 / int32).

        ``coords`` defaults to zeros. Raises ``ValueError`` naming the problem when the
        instance is malformed (see :func:`validate`).
        """
        set_id = np.asarray(set_id)
        if coords is None:
            coords = np.zeros((set_id.shape[-1] if set_id.ndim else 0, 2), np.float32)
        inst = cls(
            cost=np.asarray(cost, np.float32),
            set_id=_as_int32(set_id, "set_id"),
            set_reward=np.asarray(set_reward, np.float32),
            start=_as_int32(start, "start"),
            end=_as_int32(end, "end"),
            budget=np.asarray(budget, np.float32),
            coords=np.asarray(coords, np.float32),
        )
        validate(inst)
        return inst

    def to_numpy(self) -> SOPInstance:
        """Copy of the instance with NumPy leaves (from JAX arrays, for the host solvers)."""
        return jax.tree_util.tree_map(np.asarray, self)

    def __getitem__(self, index: Any) -> SOPInstance:
        """Instance ``index`` of a batch."""
        return jax.tree_util.tree_map(lambda x: x[index], self)


@struct.dataclass
class Solution:
    """A plan: visited node ids in order, start first (closed tour: end depot last).

    Padded with -1 to a fixed length when batched or produced by JAX code.
    """

    nodes: Any  # [T] int32 node ids in visiting order, -1 = padding (T = plan_length(K))
    reward: Any  # [] float32: total reward of the visited sets
    cost: Any  # [] float32: travel cost of the plan

    def node_list(self) -> list[int]:
        """The plan's node ids without padding (single, unbatched solution)."""
        nodes = np.asarray(self.nodes)
        if nodes.ndim != 1:
            raise ValueError(f"node_list needs one unbatched solution, got nodes {nodes.shape}")
        return [int(n) for n in nodes if n >= 0]

    def padded(self, length: int) -> Solution:
        """Same solution with ``nodes`` padded by -1 to ``length`` (NumPy)."""
        nodes = np.asarray(self.node_list(), np.int32)
        if len(nodes) > length:
            raise ValueError(f"plan of {len(nodes)} nodes does not fit length {length}")
        out = np.full(length, -1, np.int32)
        out[: len(nodes)] = nodes
        return Solution(nodes=out, reward=np.float32(self.reward), cost=np.float32(self.cost))

    def __getitem__(self, index: Any) -> Solution:
        return jax.tree_util.tree_map(lambda x: x[index], self)


def _as_int32(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise ValueError(f"{name} must hold integers, got {a!r}")
    elif a.dtype.kind not in "iub":
        raise ValueError(f"{name} must hold integers, got dtype {a.dtype}")
    return a.astype(np.int32)


def validate(instance: SOPInstance, max_batch_dims: int | None = None) -> SOPInstance:
    """Check one instance or a batch (leading batch axes); raise ``ValueError`` naming it.

    Checked: shapes, dtypes, NaN in costs / rewards / budget / coords, negative costs,
    rewards or budget, set ids outside ``[-1, K)``, a rewarding set without nodes, a start
    node that is padding or shares its set, a start set with reward, and an ``end`` that is
    neither -1, the start, nor a node alone in its own zero-reward set. Infinite costs are
    allowed (unreachable pairs); a set with no node is allowed only with reward 0. The
    value checks run vectorised over the batch; the message of a batch names its first bad
    element (``batch element (i,): ...``). An empty batch is refused.

    Args:
        instance: leaves NumPy or JAX, shapes as :class:`SOPInstance` says, with the same
            leading batch axes on every leaf.
        max_batch_dims: refuse more leading batch axes than this (None: any number).

    Returns:
        The instance with NumPy leaves (the arrays that were checked).
    """
    if not isinstance(instance, SOPInstance):
        raise ValueError(f"expected an SOPInstance, got {type(instance).__name__}")
    inst = jax.tree_util.tree_map(np.asarray, instance)
    if inst.set_id.ndim == 0:
        raise ValueError("set_id must be a [N] array, got a scalar")
    batch = inst.set_id.shape[:-1]
    if max_batch_dims is not None and len(batch) > max_batch_dims:
        raise ValueError(
            f"set_id must be [N] with at most {max_batch_dims} leading batch axes, "
            f"got shape {inst.set_id.shape}"
        )
    _check_shapes(inst, batch)
    if batch and math.prod(batch) == 0:
        raise ValueError(f"empty instance batch (batch shape {batch})")
    flat = jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[len(batch) :]), inst)
    problem = _first_problem(flat)
    if problem is not None:
        element, message = problem
        if batch:
            idx = tuple(int(i) for i in np.unravel_index(element, batch))
            message = f"batch element {idx}: {message}"
        raise ValueError(message)
    return inst


def _check_shapes(inst: SOPInstance, batch: tuple[int, ...]) -> None:
    """Shapes and dtypes of every leaf, per instance after the leading ``batch`` axes."""
    nb = len(batch)

    def shape(name: str) -> tuple[int, ...]:
        got = np.shape(getattr(inst, name))
        if got[:nb] != batch:
            raise ValueError(f"{name} must have the batch shape {batch}, got shape {got}")
        return got[nb:]

    set_id = inst.set_id
    if set_id.ndim - nb != 1:
        raise ValueError(f"set_id must be [N], got shape {set_id.shape}")
    n = set_id.shape[-1]
    if n < 1:
        raise ValueError("an instance needs at least one node (the start)")
    if shape("cost") != (n, n):
        raise ValueError(f"cost must be [N, N] = [{n}, {n}], got shape {shape('cost')}")
    reward = shape("set_reward")
    if len(reward) != 1 or reward[0] < 1:
        raise ValueError(f"set_reward must be [K] with K >= 1, got shape {reward}")
    if shape("coords") != (n, 2):
        raise ValueError(f"coords must be [N, 2] = [{n}, 2], got shape {shape('coords')}")
    for name in ("start", "end", "budget"):
        if shape(name) != ():
            raise ValueError(f"{name} must be a scalar, got shape {shape(name)}")
    if set_id.dtype.kind not in "iu":
        raise ValueError(f"set_id must hold integers, got dtype {set_id.dtype}")


def _first_problem(inst: SOPInstance) -> tuple[int, str] | None:
    """First bad element of a flat batch [B] and its first problem, or None (vectorised)."""
    cost, set_id, reward = inst.cost, inst.set_id, inst.set_reward
    b, n = set_id.shape
    k = reward.shape[1]
    rows = np.arange(b)
    budget = inst.budget.astype(np.float64)
    start, end = inst.start.astype(np.int64), inst.end.astype(np.int64)

    in_range = (set_id >= 0) & (set_id < k)
    flat_ids = (set_id + k * rows[:, None])[in_range]
    counts = np.bincount(flat_ids, minlength=b * k).reshape(b, k)  # nodes per set
    start_ok = (start >= 0) & (start < n)
    s0 = set_id[rows, np.clip(start, 0, n - 1)]
    s0c = np.clip(s0, 0, k - 1)
    special_end = (end != -1) & (end != start)
    end_ok = (end >= 0) & (end < n)
    se = set_id[rows, np.clip(end, 0, n - 1)]
    sec = np.clip(se, 0, k - 1)

    def negative_cost(e: int) -> str:
        i, j = np.argwhere(cost[e] < 0)[0]
        return f"negative cost {cost[e, i, j]} from node {i} to node {j}"

    def bad_set_id(e: int) -> str:
        i = int(np.argmax(~in_range[e] & (set_id[e] != -1)))
        return f"set id {int(set_id[e, i])} of node {i} is outside [-1, {k})"

    def empty_set(e: int) -> str:
        s = int(np.argmax((counts[e] == 0) & (reward[e] > 0)))
        return f"set {s} has reward {reward[e, s]} but no node (a masked set must have reward 0)"

    # (bad [B], message of element e) in the order they are reported
    checks: list[tuple[np.ndarray, Any]] = [
        (np.isnan(cost).any(axis=(1, 2)), lambda e: "cost contains NaN"),
        ((cost < 0).any(axis=(1, 2)), negative_cost),
        (~np.isfinite(reward).all(axis=1), lambda e: "set_reward contains NaN or inf"),
        (
            (reward < 0).any(axis=1),
            lambda e: f"negative set reward in set {int(np.argmax(reward[e] < 0))}",
        ),
        (~np.isfinite(inst.coords).all(axis=(1, 2)), lambda e: "coords contain NaN or inf"),
        (np.isnan(budget), lambda e: "budget is NaN"),
        (budget < 0, lambda e: f"negative budget {float(budget[e])}"),
        ((~in_range & (set_id != -1)).any(axis=1), bad_set_id),
        (((counts == 0) & (reward > 0)).any(axis=1), empty_set),
        (~start_ok, lambda e: f"start node {int(start[e])} is outside [0, {n})"),
        (s0 < 0, lambda e: f"start node {int(start[e])} is a padding node (set_id -1)"),
        (
            counts[rows, s0c] != 1,
            lambda e: f"the start node must be alone in its set; set {int(s0[e])} has "
            f"{counts[e, s0c[e]]}",
        ),
        (
            reward[rows, s0c] != 0,
            lambda e: f"the start set {int(s0[e])} must have reward 0, got {reward[e, s0c[e]]}",
        ),
        (
            special_end & ~end_ok,
            lambda e: f"end node {int(end[e])} is outside [0, {n}) (use -1 for an open path)",
        ),
        (special_end & (se < 0), lambda e: f"end node {int(end[e])} is a padding node (set_id -1)"),
        (
            special_end & ((counts[rows, sec] != 1) | (reward[rows, sec] != 0) | (se == s0)),
            lambda e: f"the end node {int(end[e])} must be alone in its own zero-reward set "
            f"(set {int(se[e])})",
        ),
    ]
    bad = np.stack([flags for flags, _ in checks])  # [C, B]
    failing = bad.any(axis=0)
    if not failing.any():
        return None
    e = int(np.argmax(failing))
    return e, checks[int(np.argmax(bad[:, e]))][1](e)


def evaluate(instance: SOPInstance, nodes: Any) -> tuple[float, float, bool]:
    """Reference evaluator (NumPy): ``(reward, cost, feasible)`` of a plan.

    ``nodes``: visited node ids in order (start first; closed tour / fixed goal: end last),
    optionally padded with -1 at the end. ``feasible`` means: starts at the start node,
    ends at the end node when there is one, no padding node, every intermediate node in a
    rewarding-capable set (not the start / end set), no set twice, finite cost within the
    budget (up to :func:`budget_tolerance`). Cost is summed in float64 along the plan.
    """
    inst = jax.tree_util.tree_map(np.asarray, instance)
    seq = [int(v) for v in np.asarray(nodes).reshape(-1)]
    while seq and seq[-1] == -1:
        seq.pop()
    start, end = int(inst.start), int(inst.end)
    n = inst.set_id.shape[0]
    if not seq or any(not 0 <= v < n for v in seq):
        return 0.0, float("inf"), False
    feasible = seq[0] == start
    middle = seq[1:]
    if end >= 0:
        if len(seq) < 2 or seq[-1] != end:
            feasible = False
        else:
            middle = seq[1:-1]
    cost = 0.0
    for a, b in zip(seq[:-1], seq[1:], strict=False):
        cost += float(inst.cost[a, b])
    fixed_sets = {int(inst.set_id[start])}
    if end >= 0:
        fixed_sets.add(int(inst.set_id[end]))
    seen: set[int] = set()
    reward = 0.0
    for v in middle:
        s = int(inst.set_id[v])
        if s < 0 or s in fixed_sets or s in seen:
            feasible = False
            continue
        seen.add(s)
        reward += float(inst.set_reward[s])
    if not np.isfinite(cost) or cost > float(inst.budget) + budget_tolerance(inst.budget):
        feasible = False
    return reward, cost, bool(feasible)
