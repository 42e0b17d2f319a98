"""Set Orienteering Problem data: the instance, a solution, validation and a reference evaluator.

One format serves the NumPy solvers (VNS teacher, exact DP) and the JAX code (2-opt,
budget gate, model): the leaves of :class:`SOPInstance` and :class:`Solution` are plain
arrays, NumPy or JAX, and a batch simply carries a leading batch axis on every leaf.

Conventions (SPEC 8.1):

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


def validate(instance: SOPInstance) -> None:
    """Check an instance (single or batched); raise ``ValueError`` naming the problem.

    Checked: shapes, dtypes, NaN in costs / rewards / budget / coords, negative costs,
    rewards or budget, set ids outside ``[-1, K)``, a rewarding set without nodes, a start
    node that is padding or shares its set, a start set with reward, and an ``end`` that is
    neither -1, the start, nor a node alone in its own zero-reward set. Infinite costs are
    allowed (unreachable pairs); a set with no node is allowed only with reward 0.
    """
    inst = jax.tree_util.tree_map(np.asarray, instance)
    if inst.set_id.ndim == 0:
        raise ValueError("set_id must be a [N] array, got a scalar")
    batch = inst.set_id.shape[:-1]
    if batch:
        for idx in np.ndindex(*batch):
            try:
                validate(inst[idx])
            except ValueError as err:
                raise ValueError(f"batch element {idx}: {err}") from None
        return
    _validate_single(inst)


def _validate_single(inst: SOPInstance) -> None:
    cost, set_id, reward = inst.cost, inst.set_id, inst.set_reward
    if set_id.ndim != 1:
        raise ValueError(f"set_id must be [N], got shape {set_id.shape}")
    n = set_id.shape[0]
    if n < 1:
        raise ValueError("an instance needs at least one node (the start)")
    if cost.shape != (n, n):
        raise ValueError(f"cost must be [N, N] = [{n}, {n}], got shape {cost.shape}")
    if reward.ndim != 1 or reward.shape[0] < 1:
        raise ValueError(f"set_reward must be [K] with K >= 1, got shape {reward.shape}")
    if np.shape(inst.coords) != (n, 2):
        raise ValueError(f"coords must be [N, 2] = [{n}, 2], got shape {np.shape(inst.coords)}")
    for name in ("start", "end", "budget"):
        if np.ndim(getattr(inst, name)) != 0:
            raise ValueError(f"{name} must be a scalar, got shape {np.shape(getattr(inst, name))}")
    if set_id.dtype.kind not in "iu":
        raise ValueError(f"set_id must hold integers, got dtype {set_id.dtype}")
    if np.isnan(cost).any():
        raise ValueError("cost contains NaN")
    if (cost < 0).any():
        i, j = np.argwhere(cost < 0)[0]
        raise ValueError(f"negative cost {cost[i, j]} from node {i} to node {j}")
    if np.isnan(reward).any() or np.isinf(reward).any():
        raise ValueError("set_reward contains NaN or inf")
    if (reward < 0).any():
        raise ValueError(f"negative set reward in set {int(np.argmax(reward < 0))}")
    if not np.isfinite(inst.coords).all():
        raise ValueError("coords contain NaN or inf")
    budget = float(inst.budget)
    if np.isnan(budget):
        raise ValueError("budget is NaN")
    if budget < 0:
        raise ValueError(f"negative budget {budget}")
    k = reward.shape[0]
    bad = (set_id < -1) | (set_id >= k)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"set id {int(set_id[i])} of node {i} is outside [-1, {k})")
    counts = np.bincount(set_id[set_id >= 0], minlength=k)
    empty_rewarding = (counts == 0) & (reward > 0)
    if empty_rewarding.any():
        s = int(np.argmax(empty_rewarding))
        raise ValueError(
            f"set {s} has reward {reward[s]} but no node (a masked set must have reward 0)"
        )
    start, end = int(inst.start), int(inst.end)
    if not 0 <= start < n:
        raise ValueError(f"start node {start} is outside [0, {n})")
    if set_id[start] < 0:
        raise ValueError(f"start node {start} is a padding node (set_id -1)")
    s0 = int(set_id[start])
    if counts[s0] != 1:
        raise ValueError(f"the start node must be alone in its set; set {s0} has {counts[s0]}")
    if reward[s0] != 0:
        raise ValueError(f"the start set {s0} must have reward 0, got {reward[s0]}")
    if end != -1 and end != start:
        if not 0 <= end < n:
            raise ValueError(f"end node {end} is outside [0, {n}) (use -1 for an open path)")
        if set_id[end] < 0:
            raise ValueError(f"end node {end} is a padding node (set_id -1)")
        se = int(set_id[end])
        if counts[se] != 1 or reward[se] != 0 or se == s0:
            raise ValueError(
                f"the end node {end} must be alone in its own zero-reward set (set {se})"
            )


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
