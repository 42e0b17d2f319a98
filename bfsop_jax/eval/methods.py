"""The navigation benchmark's methods: their names, groups and labels.

:data:`METHODS` are Table I's five strategies, :data:`BASELINES` the ones a "best
baseline" is chosen from, :data:`ABLATIONS` the extra rows run on request only (among
them :data:`CANDIDATE_METHODS`, the scripted policies of the environment's candidate
interface), and :data:`LABELS` every method's name in tables and figures. Importable from
:mod:`bfsop_jax.eval.navigation` too.
"""

from __future__ import annotations

__all__ = ["ABLATIONS", "BASELINES", "CANDIDATE_METHODS", "LABELS", "METHODS"]

METHODS: tuple[str, ...] = ("fbe", "bfs_global", "tfl_reactive", "bfsop_vns", "bfsop_st")
BASELINES: tuple[str, ...] = ("fbe", "bfs_global", "tfl_reactive")
# Rows run on request only (``--methods``), never a "best baseline": TFL-Reactive with
# BF-SOP's explorer shows how much of BF-SOP's margin is its exploration mode's.
# The scripted policies of the environment's candidate interface (bfsop_jax.env) run as
# extra rows too: what choosing among the posed candidates gives without learning.
CANDIDATE_METHODS: tuple[str, ...] = ("cand_nearest_frontier", "cand_nearest_landmark")
ABLATIONS: tuple[str, ...] = ("tfl_reactive_gain", *CANDIDATE_METHODS)
LABELS: dict[str, str] = {
    "fbe": "FBE",
    "bfs_global": "BFS-Global",
    "tfl_reactive": "TFL-Reactive",
    "bfsop_vns": "BF-SOP (VNS)",
    "bfsop_st": "BF-SOP (Transformer)",
    "tfl_reactive_gain": "TFL-Reactive + gain explorer",
    "cand_nearest_frontier": "Candidates: nearest frontier",
    "cand_nearest_landmark": "Candidates: nearest landmark, else frontier",
}
