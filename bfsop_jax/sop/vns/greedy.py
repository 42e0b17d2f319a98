"""The greedy insertion start of the VNS, and plans decoded into :class:`Solution` s."""

from __future__ import annotations

import numpy as np

from bfsop_jax.sop.types import Solution, SOPInstance, evaluate
from bfsop_jax.sop.vns.dp import _plan
from bfsop_jax.sop.vns.search import _fill
from bfsop_jax.sop.vns.setview import SetView, set_view

__all__ = ["empty_solution", "greedy_solution", "solve_greedy"]


def greedy_solution(view: SetView) -> tuple[np.ndarray, int]:
    """Greedy insertion by the smallest added length per unit reward: (permutation, m)."""
    msets = view.num_sets
    perm, m = _fill(view, np.arange(msets)[None], np.zeros(1, int), np.zeros((1, msets), bool))
    return perm[0], int(m[0])


def _solution(instance: SOPInstance, nodes: list[int]) -> Solution:
    reward, cost, _ = evaluate(instance, nodes)
    return Solution(
        nodes=np.asarray(nodes, np.int32), reward=np.float32(reward), cost=np.float32(cost)
    )


def empty_solution(instance: SOPInstance) -> Solution:
    """The plan that visits nothing: [start] (open path) or [start, end]."""
    inst = instance.to_numpy()
    nodes = [int(inst.start)] + ([int(inst.end)] if int(inst.end) >= 0 else [])
    return _solution(inst, nodes)


def solve_greedy(instance: SOPInstance) -> Solution:
    """Greedy insertion plan (the VNS start): cheapest added length per unit reward.

    Deterministic and fast (one batched insertion evaluation per added set); unpadded nodes.
    """
    inst = instance.to_numpy()
    view = set_view(inst)
    if view.num_sets == 0:
        return empty_solution(inst)
    perm, m = greedy_solution(view)
    return _solution(inst, _plan(view, perm, m))
