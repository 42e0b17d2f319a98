"""Model inputs computed from an :class:`~bfsop_jax.sop.SOPInstance` (pure JAX, batched).

Every normalisation uses the instance alone (no preset constant), so the planner also
works on ``.sop`` files and hand-made instances of any scale:

* coordinates: shifted by the lower corner of the bounding box of the valid (non-padding)
  nodes and divided by the box's *larger* side, so they lie in ``[0, 1]`` and keep the
  aspect ratio (a corridor stays a corridor);
* reward: the node's set reward divided by the largest set reward (0 if all are 0);
* geometric bias (docs/design.md §8.1): ``b_ij = log(c^_ij + 1e-9)`` with
  ``c^ = c / max(max finite valid c, 1e-9)``; unreachable pairs (``inf``) get ``c^ = 1``,
  pairs with a padding node get ``c^ = 1`` too (they are masked in attention anyway);
* remaining budget: divided by the same largest finite cost, clipped to
  ``[0, BUDGET_CLIP]`` (an infinite budget stays finite);
* step features (:func:`step_features`, for a decoder with ``step_features``): what a
  move from the current node to each candidate costs, against what it is worth and what
  budget is left, in the same cost units.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from bfsop_jax.sop.types import SOPInstance

__all__ = [
    "BUDGET_CLIP",
    "COST_EPS",
    "NUM_FEATURES",
    "NUM_SYMMETRIES",
    "NUM_STEP_FEATURES",
    "NodeFeatures",
    "node_features",
    "normalised_budget",
    "insertion_step_features",
    "random_symmetry",
    "step_features",
    "symmetric_features",
]

COST_EPS = 1e-9  # eps of the geometric bias (paper value)
BUDGET_CLIP = 10.0  # remaining budget, in units of the largest cost, is clipped to this
NUM_FEATURES = 4  # [x~, y~, r~, is_start]
NUM_SYMMETRIES = 8  # flips and quarter turns of the unit square
NUM_STEP_FEATURES = 7  # see step_features
FAR = 2.0  # normalised cost given to unreachable pairs in the step features (>= every real one)


@struct.dataclass
class NodeFeatures:
    """Encoder inputs of one instance (or a batch, leading axis on every leaf)."""

    nodes: Any  # [N, 4] float32: x~, y~ in [0, 1], reward r~ in [0, 1], is_start in {0, 1}
    bias: Any  # [N, N] float32: log(c^ + 1e-9), c^ = normalised cost in [0, 1]
    valid: Any  # [N] bool: node is not padding
    cost_scale: Any  # [] float32: largest finite cost between valid nodes (metres), >= 1e-9


def _single(instance: SOPInstance) -> NodeFeatures:
    set_id = instance.set_id
    valid = set_id >= 0
    n = set_id.shape[0]

    coords = instance.coords.astype(jnp.float32)
    lo = jnp.min(jnp.where(valid[:, None], coords, jnp.inf), axis=0)
    hi = jnp.max(jnp.where(valid[:, None], coords, -jnp.inf), axis=0)
    side = jnp.maximum(jnp.max(hi - lo), COST_EPS)
    xy = jnp.where(valid[:, None], (coords - lo) / side, 0.0)

    reward = instance.set_reward.astype(jnp.float32)
    top = jnp.max(reward)
    node_reward = jnp.where(valid, reward[jnp.clip(set_id, 0)], 0.0)
    r = jnp.where(top > 0, node_reward / jnp.where(top > 0, top, 1.0), 0.0)
    is_start = (jnp.arange(n) == instance.start).astype(jnp.float32)

    cost = instance.cost.astype(jnp.float32)
    pair = valid[:, None] & valid[None, :]
    finite = pair & jnp.isfinite(cost)
    scale = jnp.maximum(jnp.max(jnp.where(finite, cost, 0.0)), COST_EPS)
    c_hat = jnp.where(finite, cost / scale, 1.0)
    bias = jnp.log(c_hat + COST_EPS)
    return NodeFeatures(
        nodes=jnp.concatenate([xy, r[:, None], is_start[:, None]], axis=-1),
        bias=bias,
        valid=valid,
        cost_scale=scale,
    )


def node_features(instance: SOPInstance) -> NodeFeatures:
    """Features of one instance (``set_id`` [N]) or a batch (``set_id`` [B, N])."""
    if instance.set_id.ndim == 2:
        return jax.vmap(_single)(instance)
    if instance.set_id.ndim != 1:
        raise ValueError(f"set_id must be [N] or [B, N], got shape {instance.set_id.shape}")
    return _single(instance)


def normalised_budget(budget_left: jax.Array, cost_scale: jax.Array) -> jax.Array:
    """Remaining budget (metres) in units of the largest cost, clipped to [0, BUDGET_CLIP]."""
    return jnp.clip(budget_left / cost_scale, 0.0, BUDGET_CLIP)


def step_features(
    instance: SOPInstance, features: NodeFeatures, last: jax.Array, travelled: jax.Array
) -> jax.Array:
    """Per-candidate features of S decoding states per instance (batched, pure).

    For the state (last node ``l``, cost so far ``t``) and each node ``j``, in units of
    the instance's largest finite cost ``s`` (``features.cost_scale``):

    0. ``d = c(l, j) / s``, the move's cost (unreachable: :data:`FAR`);
    1. ``e = c(j, end) / s``, from ``j`` on to the end node (0 for an open path);
    2. ``left = (budget - t) / s``, clipped to ``[0, BUDGET_CLIP]``;
    3. ``slack = left - d - e``, clipped to ``[-1, BUDGET_CLIP]`` (>= 0: ``j`` still fits);
    4. ``(d + e) / left``, the share of what is left that the move commits, clipped to
       ``[0, 2]``;
    5. ``r~_j``, the node's normalised set reward;
    6. ``log(r~_j + 1e-3) - log(d + 1e-2)``, reward per distance on a log scale.

    Args:
        instance: batch of B instances (N nodes).
        features: their :func:`node_features` (any coordinate symmetry: costs are the same).
        last: [B, S] int32 last node of each state.
        travelled: [B, S] float32 cost of each state's plan so far (cost units).

    Returns:
        [B, S, N, NUM_STEP_FEATURES] float32 (zeros for padding nodes).
    """
    scale = features.cost_scale[:, None, None]  # [B, 1, 1]
    cost = jnp.take_along_axis(instance.cost, last[..., None], axis=1)  # [B, S, N]
    end = jnp.clip(instance.end, 0)
    to_end = jax.vmap(lambda c, e: c[:, e])(instance.cost, end)  # [B, N]
    to_end = jnp.where(jnp.isfinite(to_end), jnp.minimum(to_end / scale[:, 0], FAR), FAR)
    e = jnp.where(instance.end[:, None] >= 0, to_end, 0.0)[:, None]
    return _move_features(instance, features, cost, e, travelled)


def insertion_step_features(
    instance: SOPInstance, features: NodeFeatures, delta: jax.Array, travelled: jax.Array
) -> jax.Array:
    """:func:`step_features` of an insertion decoder's states (batched, pure).

    The move is the cheapest insertion of ``j`` into the plan so far, so feature 0 is its
    added cost ``delta_j / s`` and feature 1 (``e``) is 0: the plan's cost ``t`` already
    includes the way to a closed tour's end node.

    Args:
        instance: batch of B instances (N nodes).
        features: their :func:`node_features`.
        delta: [B, S, N] float32 added cost of each node's cheapest insertion (cost units,
            inf where it has none).
        travelled: [B, S] float32 cost of each state's plan (cost units).

    Returns:
        [B, S, N, NUM_STEP_FEATURES] float32 (zeros for padding nodes).
    """
    return _move_features(instance, features, delta, jnp.zeros((1, 1, 1), jnp.float32), travelled)


def _move_features(
    instance: SOPInstance, features: NodeFeatures, move: jax.Array, e: jax.Array, travelled
) -> jax.Array:
    """The 7 step features from the move costs [B, S, N] (cost units) and ``e`` (normalised,
    broadcast to [B, S, N])."""
    scale = features.cost_scale[:, None, None]  # [B, 1, 1]
    d = jnp.where(jnp.isfinite(move), jnp.clip(move / scale, 0.0, FAR), FAR)
    e = jnp.broadcast_to(e, d.shape)
    left = normalised_budget(instance.budget[:, None] - travelled, scale[..., 0])
    left = jnp.broadcast_to(left[..., None], d.shape)
    slack = jnp.clip(left - d - e, -1.0, BUDGET_CLIP)
    share = jnp.clip((d + e) / jnp.maximum(left, 1e-3), 0.0, 2.0)
    r = jnp.broadcast_to(features.nodes[:, None, :, 2], d.shape)
    ratio = jnp.log(r + 1e-3) - jnp.log(d + 1e-2)
    out = jnp.stack([d, e, left, slack, share, r, ratio], axis=-1)
    return jnp.where(features.valid[:, None, :, None], out, 0.0).astype(jnp.float32)


def _transform_xy(xy: jax.Array, index: int) -> jax.Array:
    """Symmetry ``index`` (0..7) of the unit square applied to [..., 2] points.

    0: identity; 1-3: quarter turns; 4-7: the same after a mirror (x <-> y). Points of
    ``[0, 1]^2`` stay in ``[0, 1]^2``; costs do not change (they are distances).
    """
    x, y = xy[..., 0], xy[..., 1]
    if index >= 4:
        x, y = y, x
    for _ in range(index % 4):
        x, y = 1.0 - y, x  # quarter turn about the square's centre
    return jnp.stack([x, y], axis=-1)


def symmetric_features(features: NodeFeatures) -> NodeFeatures:
    """The 8 coordinate symmetries: every leaf gets a new leading axis of size 8.

    Only ``x~, y~`` of valid nodes change; padding nodes keep zeros.
    """
    xy = features.nodes[..., :2]
    rest = features.nodes[..., 2:]
    valid = features.valid[..., None]
    variants = [
        jnp.concatenate([jnp.where(valid, _transform_xy(xy, s), 0.0), rest], axis=-1)
        for s in range(NUM_SYMMETRIES)
    ]
    stacked = jax.tree_util.tree_map(
        lambda leaf: jnp.broadcast_to(leaf, (NUM_SYMMETRIES,) + leaf.shape), features
    )
    return stacked.replace(nodes=jnp.stack(variants))


def random_symmetry(features: NodeFeatures, key: jax.Array, apply: Any = True) -> NodeFeatures:
    """Each row's node features under a random one of the 8 coordinate symmetries.

    ``apply``: a (traced) bool; false keeps every row as it is (symmetry 0, the identity).
    """
    variants = symmetric_features(features).nodes  # [8, B, N, F]
    pick = jax.random.randint(key, (variants.shape[1],), 0, NUM_SYMMETRIES)
    pick = jnp.where(apply, pick, 0)
    return features.replace(nodes=variants[pick, jnp.arange(variants.shape[1])])
