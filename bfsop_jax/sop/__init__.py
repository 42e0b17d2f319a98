"""Set Orienteering Problem: instances, ``.sop`` files, the VNS teacher, the exact solver,
the bounded 2-opt with the budget gate, and the batched host callback."""

from bfsop_jax.sop.callback import solve_vns_batch, vns_callback
from bfsop_jax.sop.exact import solve_exact
from bfsop_jax.sop.io import random_instance, read_sop
from bfsop_jax.sop.two_opt import budget_gate, insertion_fill, refine_route, two_opt
from bfsop_jax.sop.types import Solution, SOPInstance, evaluate, plan_length, validate
from bfsop_jax.sop.vns import VNSConfig, solve_greedy, solve_vns

__all__ = [
    "SOPInstance",
    "Solution",
    "VNSConfig",
    "budget_gate",
    "evaluate",
    "insertion_fill",
    "refine_route",
    "plan_length",
    "random_instance",
    "read_sop",
    "solve_exact",
    "solve_greedy",
    "solve_vns",
    "solve_vns_batch",
    "two_opt",
    "validate",
    "vns_callback",
]
