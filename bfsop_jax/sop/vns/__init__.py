"""VNS teacher for the Set Orienteering Problem (NumPy).

Follows the published VNS-SOP (Penicka, Faigl & Saska 2019):

* a solution is a permutation of all rewarding sets; its first ``m`` entries are visited in
  order. The node inside each visited set is never searched: for a fixed set order a
  layered min-plus DP (forward table from the start, backward table to the end) picks the
  best node of every set exactly;
* initial solution: greedy insertion by the smallest added length per unit reward;
* basic VNS over two neighbourhoods. Shake 1 moves a random segment of the permutation,
  shake 2 swaps two random segments; then sets are dropped from the end while the tour is
  over budget and the next permutation entries appended while they fit. Local search 1
  relocates a visited set or inserts an unvisited one; local search 2 swaps two visited
  sets or replaces a visited set by an unvisited one. A move is accepted when the reward
  rises, or stays equal with a shorter tour; the VNS accepts a shaken-and-searched solution
  under the same rule;
* stops after ``max_iters`` iterations, ``max_no_improve`` iterations without improvement
  or ``time_limit`` seconds. Deterministic for a seed.

Additions for tight budgets (docs/sop.md): segment reversals in local search 2, and two
intensifications run when the stop rule fires (a success counts as an improvement):
insertion of a set that overshoots the budget followed by an order-only repair
(:func:`_squeeze`), then ruin and recreate of one or two visited sets (:func:`_recreate`).

Vectorisation (why it is not a line-by-line port): instead of drawing n^2 random trials and
evaluating each with a Python-level DP, every move of a neighbourhood is evaluated exactly
in one batched min-plus pass from the DP tables (forward / backward tables, tables of the
tour with one set removed, and a propagation through the unchanged middle of a swap).
The random-trial first-improvement search is then emulated: a uniformly random improving
move is taken (what the first improving random trial would be), and the number of trials
it would have cost is drawn from the matching geometric law and charged to the n^2 trial
budget. With exact costs of all moves at hand, the published lower-bound test that skips
trials which cannot fit is unnecessary: infeasible moves are simply masked.

Internal layout: the rewarding sets of an instance are compacted to ``M`` sets with at most
``Q`` (reachable) nodes each; set ``M`` is the start and set ``M + 1`` the end ("END" is a
zero-cost sink for an open path). ``block[s, t]`` is the ``[Q, Q]`` cost matrix between the
node slots of sets ``s`` and ``t`` (inf for padding slots).

Options: one frozen :class:`VNSConfig` (reference configuration :data:`REFERENCE`, dataset
labelling :meth:`VNSConfig.labelling`, :data:`DEMO_LABELLING`).

Modules (by concern):

* :mod:`~bfsop_jax.sop.vns.config`: :class:`VNSConfig` and the named configurations;
* :mod:`~bfsop_jax.sop.vns.setview`: :class:`SetView`, :func:`set_view`;
* :mod:`~bfsop_jax.sop.vns.dp`: the layered min-plus DP tables and scores;
* :mod:`~bfsop_jax.sop.vns.moves`: neighbourhood costs, applying moves, shakes, budget fit;
* :mod:`~bfsop_jax.sop.vns.search`: local search and the intensifications;
* :mod:`~bfsop_jax.sop.vns.greedy`: the greedy start (:func:`greedy_solution`,
  :func:`solve_greedy`, :func:`empty_solution`);
* :mod:`~bfsop_jax.sop.vns.driver`: :func:`solve_vns`.
"""

# Besides the public names, the private helpers that tests reach as ``vns._name`` (the
# package replaces a single module) stay importable from here (``as`` marks re-exports).
from bfsop_jax.sop.vns.config import DEMO_LABELLING, REFERENCE, VNSConfig
from bfsop_jax.sop.vns.dp import _gap_tables as _gap_tables
from bfsop_jax.sop.vns.dp import _lowest as _lowest
from bfsop_jax.sop.vns.dp import _score as _score
from bfsop_jax.sop.vns.dp import _tables as _tables
from bfsop_jax.sop.vns.dp import _visited_mask as _visited_mask
from bfsop_jax.sop.vns.driver import solve_vns
from bfsop_jax.sop.vns.greedy import empty_solution, greedy_solution, solve_greedy
from bfsop_jax.sop.vns.moves import _apply as _apply
from bfsop_jax.sop.vns.moves import _fit as _fit
from bfsop_jax.sop.vns.moves import _neighbourhood as _neighbourhood
from bfsop_jax.sop.vns.search import RESTART_MAX_SETS
from bfsop_jax.sop.vns.search import _fill as _fill
from bfsop_jax.sop.vns.search import _local_search as _local_search
from bfsop_jax.sop.vns.search import _recreate as _recreate
from bfsop_jax.sop.vns.setview import SetView, set_view

__all__ = [
    "DEMO_LABELLING",
    "REFERENCE",
    "RESTART_MAX_SETS",
    "SetView",
    "VNSConfig",
    "empty_solution",
    "greedy_solution",
    "set_view",
    "solve_greedy",
    "solve_vns",
]
