"""The Strategic Transformer (Flax NNX): a geometric-bias encoder and a pointer decoder.

Encoder (docs/design.md §8.1): node features ``[x~, y~, r~, is_start]`` are projected to ``d``, then
``n_layers`` pre-LayerNorm blocks (``h += MHA(LN(h)); h += FF(LN(h))``, a final LN).
Pre-LN keeps the residual path an identity at initialisation, which trains stably without
a warm-up. Every head's attention logits get ``scale_h * b_ij`` added, ``b`` the log-cost
bias of :mod:`bfsop_jax.model.features` and ``scale_h`` a learned per-head scalar
(initially ``bias_scale_init``): ``b`` is largest for the *farthest* pairs, and the
learned scale lets each head turn that into a preference for near or far nodes. Keys of
padding nodes get ``-inf``. There is no positional encoding, so the encoder is
permutation-equivariant over the nodes.

Decoder (Kool et al. style pointer): a learned END embedding is appended to the node
embeddings (index ``N``), so END takes part in the glimpse and is scored like a node.
Keys are computed once per instance (:meth:`PointerDecoder.precompute`). At each step the
query is ``W_g mean(h_valid) + W_s [h_last, h_start, (budget~)]``; a multi-head glimpse
over the allowed nodes refines it, and the scores are ``clip * tanh(q . k_j / sqrt(d))``;
entries not allowed get ``-inf``. With ``step_features`` a small MLP over the per-candidate
step features (:func:`bfsop_jax.model.features.step_features`: the move's cost, what is
left of the budget, reward per distance) adds a score to every node; its output layer
starts at zero, so such a decoder starts as the plain pointer. *Which* nodes are allowed
is decided by the caller (:mod:`bfsop_jax.model.decode`): the network only applies the
mask it is given.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
from flax import nnx, struct

from bfsop_jax.model.features import NUM_FEATURES, NUM_STEP_FEATURES, NodeFeatures

__all__ = [
    "DECODERS",
    "DecoderCache",
    "ModelConfig",
    "PointerDecoder",
    "StrategicTransformer",
    "config_from_dict",
]

DECODERS = ("append", "insertion")  # how a chosen node enters the plan (ModelConfig.decoder)


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Shape and variant of the Strategic Transformer (static, hashable).

    Defaults are the paper's values (d = 128, 6 layers, 8 heads, feed-forward 512).
    """

    d_model: int = 128  # embedding width d
    n_layers: int = 6  # encoder layers
    n_heads: int = 8  # attention heads (encoder and decoder glimpse)
    d_ff: int = 512  # hidden width of the feed-forward blocks
    clip: float = 10.0  # pointer scores are clip * tanh(q . k / sqrt(d))
    geometric_bias: bool = True  # add the learned-scale log-cost bias to attention logits
    budget_aware: bool = False  # feed the remaining budget to the decoder query
    budget_mask: bool = False  # mask nodes that no longer fit; END only when none does
    bias_scale_init: float = 1.0  # initial per-head scale of the geometric bias
    step_features: bool = False  # score candidates by their step features too (an MLP)
    step_hidden: int = 64  # hidden width of that MLP
    # "append": each step appends a node to the path (the paper's pointer decoding);
    # "insertion": each step puts the chosen node where it adds the least cost
    decoder: str = "append"
    # insertion decoder: after every insertion the route is improved (two 2-opt reversals,
    # then each set's cheapest node between its neighbours; bfsop_jax.sop.refine_route),
    # so the next choices see the budget that frees (the append decoder ignores it)
    refine: bool = False

    def __post_init__(self) -> None:
        for name in ("d_model", "n_layers", "n_heads", "d_ff", "step_hidden"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ModelConfig.{name} must be a positive int, got {value!r}")
        if self.d_model % self.n_heads:
            raise ValueError(
                f"ModelConfig.d_model ({self.d_model}) must be divisible by n_heads "
                f"({self.n_heads})"
            )
        if self.decoder not in DECODERS:
            raise ValueError(
                f"ModelConfig.decoder must be one of {', '.join(DECODERS)}, got {self.decoder!r}"
            )
        if not self.clip > 0:
            raise ValueError(f"ModelConfig.clip must be positive, got {self.clip}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        return config_from_dict(cls, data)


def config_from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Build the frozen dataclass ``cls`` from a dict, naming unknown keys in the error."""
    if not isinstance(data, dict):
        raise ValueError(f"{cls.__name__} needs a dict, got {type(data).__name__}")
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - fields
    if unknown:
        raise ValueError(f"unknown {cls.__name__} keys: {sorted(unknown)}")
    return cls(**data)


def _split_heads(x: jax.Array, heads: int) -> jax.Array:
    """[..., L, d] -> [..., H, L, d / H]."""
    *lead, length, d = x.shape
    x = x.reshape(*lead, length, heads, d // heads)
    return jnp.moveaxis(x, -2, -3)


def _merge_heads(x: jax.Array) -> jax.Array:
    """[..., H, L, dh] -> [..., L, H * dh]."""
    x = jnp.moveaxis(x, -3, -2)
    return x.reshape(*x.shape[:-2], -1)


class GeometricAttention(nnx.Module):
    """Multi-head self-attention with an additive, per-head-scaled geometric bias."""

    def __init__(self, config: ModelConfig, *, rngs: nnx.Rngs):
        d = config.d_model
        self.n_heads = config.n_heads
        self.qkv = nnx.Linear(d, 3 * d, use_bias=False, rngs=rngs)
        self.out = nnx.Linear(d, d, rngs=rngs)
        if config.geometric_bias:
            self.bias_scale = nnx.Param(
                jnp.full((config.n_heads,), config.bias_scale_init, jnp.float32)
            )
        else:
            self.bias_scale = None

    def __call__(self, h: jax.Array, bias: jax.Array, valid: jax.Array) -> jax.Array:
        """h [B, N, d], bias [B, N, N], valid [B, N] -> [B, N, d]."""
        q, k, v = (_split_heads(x, self.n_heads) for x in jnp.split(self.qkv(h), 3, axis=-1))
        logits = jnp.einsum("bhid,bhjd->bhij", q, k) / math.sqrt(q.shape[-1])
        if self.bias_scale is not None:
            logits = logits + self.bias_scale[...][None, :, None, None] * bias[:, None]
        logits = jnp.where(valid[:, None, None, :], logits, -jnp.inf)
        weights = jax.nn.softmax(logits, axis=-1)  # the start node is always a valid key
        return self.out(_merge_heads(jnp.einsum("bhij,bhjd->bhid", weights, v)))


class EncoderLayer(nnx.Module):
    """Pre-LN block: biased multi-head attention, then a ReLU feed-forward."""

    def __init__(self, config: ModelConfig, *, rngs: nnx.Rngs):
        d = config.d_model
        self.norm_attention = nnx.LayerNorm(d, rngs=rngs)
        self.attention = GeometricAttention(config, rngs=rngs)
        self.norm_ff = nnx.LayerNorm(d, rngs=rngs)
        self.ff_in = nnx.Linear(d, config.d_ff, rngs=rngs)
        self.ff_out = nnx.Linear(config.d_ff, d, rngs=rngs)

    def __call__(self, h: jax.Array, bias: jax.Array, valid: jax.Array) -> jax.Array:
        h = h + self.attention(self.norm_attention(h), bias, valid)
        return h + self.ff_out(jax.nn.relu(self.ff_in(self.norm_ff(h))))


@struct.dataclass
class DecoderCache:
    """Per-instance decoder tensors, computed once before the decoding steps.

    ``N + 1`` entries: the N nodes, then END.
    """

    nodes: Any  # [B, N, d] float32: node embeddings (zeros for padding)
    glimpse_key: Any  # [B, H, N+1, d/H] float32
    glimpse_value: Any  # [B, H, N+1, d/H] float32
    logit_key: Any  # [B, N+1, d] float32
    context: Any  # [B, d] float32: projected graph embedding (mean of valid nodes)
    start: Any  # [B, d] float32: embedding of the start node
    cost_scale: Any  # [B] float32: largest finite cost (metres), normalises the budget


class PointerDecoder(nnx.Module):
    """Pointer head: step query -> masked glimpse -> clipped scores over nodes and END."""

    def __init__(self, config: ModelConfig, *, rngs: nnx.Rngs):
        d = config.d_model
        self.n_heads = config.n_heads
        self.clip = config.clip
        self.budget_aware = config.budget_aware
        # unit-variance entries, like the layer-normed node embeddings it is scored against
        self.end_embedding = nnx.Param(jax.random.normal(rngs.params(), (d,)))
        self.project_nodes = nnx.Linear(d, 3 * d, use_bias=False, rngs=rngs)
        self.project_graph = nnx.Linear(d, d, use_bias=False, rngs=rngs)
        step_in = 2 * d + (1 if config.budget_aware else 0)
        self.project_step = nnx.Linear(step_in, d, use_bias=False, rngs=rngs)
        # zero-initialised: scores start at 0 (uniform over the allowed entries, tanh in its
        # linear range); node embeddings share a large common component at initialisation,
        # which would otherwise give saturated scores of either sign and a vanishing gradient
        self.project_glimpse = nnx.Linear(
            d, d, use_bias=False, kernel_init=nnx.initializers.zeros_init(), rngs=rngs
        )
        self.uses_step_features = config.step_features
        if config.step_features:
            self.step_in = nnx.Linear(NUM_STEP_FEATURES, config.step_hidden, rngs=rngs)
            self.step_out = nnx.Linear(
                config.step_hidden, 1, kernel_init=nnx.initializers.zeros_init(), rngs=rngs
            )

    def precompute(
        self, nodes: jax.Array, features: NodeFeatures, start: jax.Array
    ) -> DecoderCache:
        """nodes [B, N, d] embeddings, start [B] start node ids -> :class:`DecoderCache`."""
        b, _, d = nodes.shape
        valid = features.valid
        count = jnp.maximum(jnp.sum(valid, axis=-1, keepdims=True), 1)
        graph = jnp.sum(jnp.where(valid[..., None], nodes, 0.0), axis=1) / count
        end = jnp.broadcast_to(self.end_embedding[...], (b, 1, d))
        g_key, g_value, l_key = jnp.split(
            self.project_nodes(jnp.concatenate([nodes, end], axis=1)), 3, axis=-1
        )
        return DecoderCache(
            nodes=nodes,
            glimpse_key=_split_heads(g_key, self.n_heads),
            glimpse_value=_split_heads(g_value, self.n_heads),
            logit_key=l_key,
            context=self.project_graph(graph),
            start=jnp.take_along_axis(nodes, start[:, None, None], axis=1)[:, 0],
            cost_scale=features.cost_scale,
        )

    def __call__(
        self,
        cache: DecoderCache,
        last: jax.Array,
        allowed: jax.Array,
        budget_left: jax.Array | None = None,
        step: jax.Array | None = None,
    ) -> jax.Array:
        """Scores of S decoding states per instance.

        Args:
            cache: from :meth:`precompute`, batch B.
            last: [B, S] int32, the last visited node of each state.
            allowed: [B, S, N+1] bool, which nodes (and END, index N) may come next.
            budget_left: [B, S] float32 remaining budget normalised by the largest cost
                (:func:`~bfsop_jax.model.features.normalised_budget`); used only when the
                model is budget-aware.
            step: [B, S, N, NUM_STEP_FEATURES] float32 step features; used (and needed)
                only when the model has ``step_features``.

        Returns:
            [B, S, N+1] float32 scores in ``[-clip, clip]``; ``-inf`` where not allowed.
        """
        d = cache.logit_key.shape[-1]
        h_last = jnp.take_along_axis(cache.nodes, last[..., None], axis=1)  # [B, S, d]
        h_start = jnp.broadcast_to(cache.start[:, None], h_last.shape)
        parts = [h_last, h_start]
        if self.budget_aware:
            if budget_left is None:
                raise ValueError("a budget-aware decoder needs budget_left")
            parts.append(budget_left[..., None].astype(h_last.dtype))
        query = cache.context[:, None] + self.project_step(jnp.concatenate(parts, axis=-1))

        # glimpse: multi-head attention of the query over the allowed entries
        q = query.reshape(*query.shape[:-1], self.n_heads, -1)  # [B, S, H, dh]
        compat = jnp.einsum("bshd,bhnd->bshn", q, cache.glimpse_key) / math.sqrt(q.shape[-1])
        compat = jnp.where(allowed[:, :, None, :], compat, -jnp.inf)
        heads = jnp.einsum("bshn,bhnd->bshd", jax.nn.softmax(compat, axis=-1), cache.glimpse_value)
        glimpse = self.project_glimpse(heads.reshape(query.shape))

        scores = jnp.einsum("bsd,bnd->bsn", glimpse, cache.logit_key) / math.sqrt(d)
        scores = self.clip * jnp.tanh(scores)
        if self.uses_step_features:
            if step is None:
                raise ValueError("a decoder with step_features needs the step features")
            extra = self.step_out(jax.nn.relu(self.step_in(step)))[..., 0]  # [B, S, N]
            scores = scores + jnp.pad(extra, ((0, 0), (0, 0), (0, 1)))  # END: no term
        return jnp.where(allowed, scores, -jnp.inf)


class StrategicTransformer(nnx.Module):
    """Encoder with geometric attention bias plus the pointer decoder (docs/design.md §8.1)."""

    def __init__(self, config: ModelConfig, *, rngs: nnx.Rngs):
        self.config = config
        self.embed = nnx.Linear(NUM_FEATURES, config.d_model, rngs=rngs)
        self.layers = nnx.List([EncoderLayer(config, rngs=rngs) for _ in range(config.n_layers)])
        self.norm = nnx.LayerNorm(config.d_model, rngs=rngs)
        self.decoder = PointerDecoder(config, rngs=rngs)

    def encode(self, features: NodeFeatures) -> jax.Array:
        """Node embeddings [B, N, d] from batched features; padding rows are zero."""
        h = self.embed(features.nodes)
        for layer in self.layers:
            h = layer(h, features.bias, features.valid)
        return jnp.where(features.valid[..., None], self.norm(h), 0.0)

    def prepare(self, features: NodeFeatures, start: jax.Array) -> DecoderCache:
        """Encode a batch and precompute the decoder keys; start [B] start node ids."""
        return self.decoder.precompute(self.encode(features), features, start)
