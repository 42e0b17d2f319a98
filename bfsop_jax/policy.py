"""The Strategic Transformer as an SOP planner: ``StrategicPolicy.load(dir).plan(instance)``.

Inference (docs/design.md §8.4): one jitted program runs the encoder, greedy decoding, the bounded
SOP 2-opt (:func:`bfsop_jax.sop.two_opt`, at most 100 reversals) and the budget gate
(:func:`bfsop_jax.sop.budget_gate`), for one instance or a batch. Instances smaller than
the model's capacity (N nodes, K sets, from the run's ``config.json``) are padded with
padding nodes (``set_id`` -1, unreachable) and empty zero-reward sets, so ``.sop`` files
and hand-made instances work too; larger ones are refused.

Options, each measurable on its own:

* ``two_opt=False`` (or :meth:`StrategicPolicy.plan_without_two_opt`): decoding plus the
  budget gate only;
* ``augment=True``: decode the 8 symmetries of the normalised coordinates (flips and quarter
  turns; costs unchanged) and keep the best plan after 2-opt and the gate;
* ``best_of=k`` (k > 1): add k plans sampled from the decoder to the greedy one;
* ``multi_start=True`` (POMO-style): add one greedy rollout per set, each forced to make
  its first move into that set (:func:`bfsop_jax.model.decode.decode`'s ``first_set``);
  ``multi_start=M`` (an int): only the M sets the decoder scores highest for its first
  move besides the greedy one's (:func:`bfsop_jax.model.decode.first_sets`);
* ``fill=True``: spend the budget a plan leaves unused by cheapest insertion.

"Best" means the largest reward, then the smallest cost. Each (batch size, options)
combination compiles once; later calls with the same shapes reuse the program.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from bfsop_jax import checkpoint as ckpt
from bfsop_jax import ops
from bfsop_jax.model.decode import DecodeTrace, decode, first_sets
from bfsop_jax.model.features import NUM_SYMMETRIES, node_features, symmetric_features
from bfsop_jax.model.transformer import ModelConfig, StrategicTransformer
from bfsop_jax.sop.two_opt import budget_gate, insertion_fill
from bfsop_jax.sop.two_opt import two_opt as sop_two_opt
from bfsop_jax.sop.types import Solution, SOPInstance, plan_length, validate

__all__ = [
    "DEMO_POLICY_DIR",
    "MULTI_START_REFINE",
    "SHIPPED_POLICIES",
    "TWO_OPT_ITERS",
    "StrategicPolicy",
    "check_decoding",
]

# The pretrained models shipped with the package (config.json + model/), by preset name.
ASSETS_DIR = Path(__file__).resolve().parent / "assets"
DEMO_POLICY_DIR = ASSETS_DIR / "policy_demo"
SHIPPED_POLICIES = ("demo", "paper")
TWO_OPT_ITERS = 100  # bounded 2-opt (docs/design.md §7.5)
MULTI_START_REFINE = 4  # multi-start: plans per instance refined (greedy + 3 best others)


def model_fingerprint(config: ModelConfig, num_nodes: int, num_sets: int, params: Any) -> str:
    """16 hex digits: a hash of a model's configuration, capacity (N nodes, K sets) and
    every parameter's bytes; the same on any device, another for any other weights."""
    digest = hashlib.sha256(repr((config, int(num_nodes), int(num_sets))).encode())
    for path, leaf in jax.tree_util.tree_leaves_with_path(params):
        value = np.asarray(leaf)
        digest.update(f"{jax.tree_util.keystr(path)}{value.dtype}{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    return digest.hexdigest()[:16]


class StrategicPolicy:
    """A trained Strategic Transformer with its decoding, 2-opt and budget gate."""

    def __init__(self, model: StrategicTransformer, num_nodes: int, num_sets: int):
        """Wrap ``model`` for instances of at most ``num_nodes`` nodes and ``num_sets`` sets."""
        if num_nodes < 1 or num_sets < 1:
            raise ValueError(f"capacity must be positive, got N={num_nodes}, K={num_sets}")
        self.config: ModelConfig = model.config
        self.num_nodes = int(num_nodes)
        self.num_sets = int(num_sets)
        self._graphdef, params = nnx.split(model, nnx.Param)
        self._static_graph = _HashedOnce(self._graphdef)  # the jitted programs' static key
        self._params = jax.device_put(params, jax.devices()[0])

    # -- loading -------------------------------------------------------------------------
    @classmethod
    def load(
        cls, run_dir: str | os.PathLike | None = None, checkpoint: str = "auto"
    ) -> StrategicPolicy:
        """Rebuild the model of a run directory (or the shipped demo model).

        Args:
            run_dir: a training run directory (``config.json`` plus ``model/`` and/or
                ``checkpoints/``), or the name of a shipped model (``"demo"``,
                ``"paper"``: ``bfsop_jax/assets/policy_<name>``, used when no directory of
                that name exists); None loads :data:`DEMO_POLICY_DIR`.
            checkpoint: ``"model"`` (the replica chosen at the end of training),
                ``"latest"`` (the last epoch checkpoint, its best replica so far) or
                ``"auto"`` (``model`` if present, else ``latest``).

        Raises:
            ValueError: missing directory, config or checkpoint, or unreadable files.
        """
        if run_dir is None:
            run_dir = "demo"
        if isinstance(run_dir, str) and run_dir in SHIPPED_POLICIES and not Path(run_dir).is_dir():
            name = run_dir
            run_dir = ASSETS_DIR / f"policy_{name}"
            if not (run_dir / ckpt.CONFIG_FILE).is_file():
                raise ValueError(
                    f"the pretrained {name} policy is not installed (bfsop_jax/assets/"
                    f"policy_{name} has no config.json); train one with "
                    f"`python -m experiments.distill --preset {name}` and pass its run "
                    "directory"
                )
        run_dir = Path(run_dir)
        if checkpoint not in ("auto", "model", "latest"):
            raise ValueError(f"checkpoint must be 'auto', 'model' or 'latest', got {checkpoint!r}")
        config = ckpt.read_config(run_dir)
        try:
            model_config = ModelConfig.from_dict(config["run"]["model"])
            num_nodes = int(config["dataset"]["num_nodes"])
            num_sets = int(config["dataset"]["num_sets"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(
                f"{run_dir / ckpt.CONFIG_FILE} lacks the model description: {err}"
            ) from None
        abstract = nnx.eval_shape(lambda: StrategicTransformer(model_config, rngs=nnx.Rngs(0)))
        graphdef, target = nnx.split(abstract, nnx.Param)
        if checkpoint == "auto":
            checkpoint = "model" if (run_dir / ckpt.MODEL_DIR).is_dir() else "latest"
        if checkpoint == "model":
            params = ckpt.load_model(run_dir, target)
        else:
            # an unfinished training run: read its last epoch checkpoint (the one place
            # inference needs the training state's layout)
            from bfsop_jax.training.bc import latest_best_params

            params = latest_best_params(run_dir, config, model_config)
        return cls(nnx.merge(graphdef, params), num_nodes, num_sets)

    @property
    def params(self) -> Any:
        """The model's ``nnx.Param`` state (e.g. ``train(..., init_params=)`` to fine-tune)."""
        return self._params

    @functools.cached_property
    def fingerprint(self) -> str:
        """16 hex digits that name this model (:func:`model_fingerprint`). Evaluations and
        resumed runs record it to tell models apart."""
        return model_fingerprint(self.config, self.num_nodes, self.num_sets, self._params)

    @property
    def model(self) -> StrategicTransformer:
        """The wrapped model (a fresh module sharing this policy's parameters)."""
        return nnx.merge(self._graphdef, self._params)

    # -- planning ------------------------------------------------------------------------
    def plan(
        self,
        instance: SOPInstance,
        two_opt: bool = True,
        augment: bool = False,
        best_of: int = 1,
        key: jax.Array | None = None,
        temperature: float = 1.0,
        fill: bool = False,
        multi_start: bool | int = False,
        check: bool = True,
    ) -> Solution:
        """Plan one instance (``set_id`` [n]) or a batch (``set_id`` [B, n]).

        Args:
            instance: n <= N nodes and k <= K sets (padded up to the model's N, K).
            two_opt: refine with the bounded SOP 2-opt before the budget gate.
            augment: also decode the 8 coordinate symmetries, keep the best.
            best_of: k > 1 adds k sampled plans to the greedy one, keeps the best.
            key: PRNG key for sampling (default ``jax.random.key(0)``: deterministic).
            temperature: softmax temperature of the sampled plans.
            fill: after the budget gate, spend the unused budget by greedy cheapest
                insertion of unvisited sets (:func:`bfsop_jax.sop.insertion_fill`).
            multi_start: ``True``: also decode one greedy rollout per set of the model's
                K, each starting with a move into its set, and keep the best (K more
                rollouts); an int M: M more rollouts, starting in the M sets the decoder
                scores highest for its first move after the greedy rollout's set.
            check: validate the instance's values on the host first
                (:func:`bfsop_jax.sop.validate`; a bad instance raises ``ValueError``).
                ``False`` is the hot path for instances known to be valid (e.g. posed by
                :mod:`bfsop_jax.sop.builder`): only shapes are checked, from metadata,
                and padding runs inside the compiled program, so JAX arrays already on
                the device never travel to the host. Same plans either way.

        Returns:
            A feasible :class:`Solution` (``nodes`` [T] or [B, T] with T = plan_length(k),
            -1 padded; reward and cost exact in float32 for the given instance).
        """
        check_decoding(best_of, multi_start)
        if not temperature > 0:
            raise ValueError(f"temperature must be positive, got {temperature}")
        starts = _starts(multi_start, self.num_sets)
        if check:
            padded, single, k = self._prepare(instance)
        else:
            padded, single, k = self._check_shapes(instance)
        # the default key is made once and the batch axis of one instance is dropped in
        # the program: on a CPU every eager op costs tens of microseconds
        sol = _plan_jit(
            self._params,
            padded,
            _default_key() if key is None else key,
            np.float32(temperature),
            graphdef=self._static_graph,
            use_two_opt=bool(two_opt),
            augment=bool(augment),
            best_of=best_of,
            fill=bool(fill),
            multi_start=starts,
            single=single,
            pad_to=None if check else (self.num_nodes, self.num_sets),
        )
        if k == self.num_sets:
            return sol
        return sol.replace(nodes=sol.nodes[..., : plan_length(k)])

    def plan_without_two_opt(self, instance: SOPInstance, **options: Any) -> Solution:
        """:meth:`plan` with ``two_opt=False`` (decoding and budget gate only; Table III)."""
        return self.plan(instance, two_opt=False, **options)

    def plan_traced(
        self,
        instance: SOPInstance,
        key: jax.Array | None = None,
        two_opt: bool = True,
        augment: bool = False,
        best_of: int = 1,
        temperature: float | jax.Array = 1.0,
        fill: bool = False,
        multi_start: bool | int = False,
    ) -> Solution:
        """:meth:`plan` as a pure JAX function, to call inside the caller's ``jit``/``scan``.

        No host-side checks: ``instance`` must be valid (JAX or NumPy leaves, single or
        batched, at most N nodes and K sets; smaller ones are padded with ``jnp``).
        """
        single = instance.set_id.ndim == 1
        inst = jax.tree_util.tree_map(jnp.asarray, instance)
        if single:
            inst = jax.tree_util.tree_map(lambda x: x[None], inst)
        n, k = inst.set_id.shape[1], inst.set_reward.shape[1]
        self._require_fits(n, k)
        inst = _pad(inst, self.num_nodes, self.num_sets, jnp)
        key = jax.random.key(0) if key is None else key
        sol = _plan_program(
            self._graphdef,
            self._params,
            inst,
            key,
            jnp.asarray(temperature, jnp.float32),
            bool(two_opt),
            bool(augment),
            int(best_of),
            bool(fill),
            _starts(multi_start, self.num_sets),
        )
        return _unpad(sol, k, single)

    def trace(self, instance: SOPInstance) -> DecodeTrace:
        """Greedy decoding with the per-step distributions (before 2-opt and the gate).

        ``probs`` and ``allowed`` are over the model's N padded nodes plus END (index N).
        """
        padded, single, k = self._prepare(instance)
        out = _trace_jit(self._params, padded, graphdef=self._static_graph)
        out = out.replace(solution=_unpad(out.solution, k, False))
        return jax.tree_util.tree_map(lambda x: x[0], out) if single else out

    # -- internals -----------------------------------------------------------------------
    def _require_fits(self, n: int, k: int) -> None:
        """ValueError when an instance of n nodes and k sets exceeds the model's N, K."""
        if n > self.num_nodes or k > self.num_sets:
            raise ValueError(
                f"instance has {n} nodes and {k} sets; this model plans at most "
                f"{self.num_nodes} nodes and {self.num_sets} sets"
            )

    def _check_shapes(self, instance: SOPInstance) -> tuple[SOPInstance, bool, int]:
        """``plan(check=False)``: ranks and sizes from metadata only (nothing is copied)."""
        if not isinstance(instance, SOPInstance):
            raise ValueError(f"expected an SOPInstance, got {type(instance).__name__}")
        shape = np.shape(instance.set_id)
        if len(shape) not in (1, 2):
            raise ValueError(f"set_id must be [N] or [B, N], got shape {shape}")
        n, k = shape[-1], np.shape(instance.set_reward)[-1]
        self._require_fits(n, k)
        return instance, len(shape) == 1, k

    def _prepare(self, instance: SOPInstance) -> tuple[SOPInstance, bool, int]:
        inst = validate(instance, max_batch_dims=1)  # NumPy leaves
        single = inst.set_id.ndim == 1
        if single:
            inst = jax.tree_util.tree_map(lambda x: x[None], inst)
        n, k = inst.set_id.shape[1], inst.set_reward.shape[1]
        self._require_fits(n, k)
        padded = _pad(inst, self.num_nodes, self.num_sets)
        return jax.device_put(padded, jax.devices()[0]), single, k


class _HashedOnce:
    """A static argument of ``jax.jit`` whose hash is computed once: hashing an NNX graph
    definition walks the whole graph, 0.3 ms (demo model) to 0.5 ms (paper model) of every
    single-instance plan on a 2-core CPU (``python -m benchmarks.bench_policy``)."""

    def __init__(self, value: Any):
        self.value = value
        self._hash = hash(value)

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return self is other or (isinstance(other, _HashedOnce) and self.value == other.value)


@functools.partial(jax.jit, static_argnames=("graphdef",))
def _trace_jit(params: Any, inst: SOPInstance, *, graphdef: _HashedOnce) -> DecodeTrace:
    return decode(nnx.merge(graphdef.value, params), inst)


@functools.cache
def _default_key() -> jax.Array:
    return jax.random.key(0)


@functools.partial(
    jax.jit,
    static_argnames=(
        "graphdef", "use_two_opt", "augment", "best_of", "fill", "multi_start", "single",
        "pad_to",
    ),
)  # fmt: skip
def _plan_jit(
    params, inst, key, temperature, *, graphdef, use_two_opt, augment, best_of, fill,
    multi_start, single, pad_to=None,
):  # fmt: skip
    # compiled once per (model graph, batch size, options); the body is looked up at trace
    # time, which lets tests count traces. ``single``: the instance has (``pad_to``: will
    # have) one batch axis of one, dropped at the end. ``pad_to`` (N, K): the instance is
    # the caller's, unpadded, single or batched; pad it here.
    if pad_to is not None:
        inst = jax.tree_util.tree_map(jnp.asarray, inst)
        if single:
            inst = jax.tree_util.tree_map(lambda x: x[None], inst)
        inst = _pad(inst, *pad_to, jnp)
    sol = _plan_program(
        graphdef.value, params, inst, key, temperature, use_two_opt, augment, best_of, fill,
        multi_start,
    )  # fmt: skip
    return jax.tree_util.tree_map(lambda x: x[0], sol) if single else sol


def _plan_program(
    graphdef: nnx.GraphDef,
    params: Any,
    inst: SOPInstance,
    key: jax.Array,
    temperature: jax.Array,
    use_two_opt: bool,
    augment: bool,
    best_of: int,
    fill: bool = False,
    multi_start: int = 0,
) -> Solution:
    """Encode, decode (greedy, symmetries, samples, starts), 2-opt, gate, keep the best.

    Candidates are laid out draw-major over ``views * B`` rows: the greedy plan, then the
    ``best_of`` samples, then the ``multi_start`` rollouts (all greedy; one per set when it
    is K, else the top-scored first sets).
    """
    model = nnx.merge(graphdef, params)
    b = inst.set_id.shape[0]
    k = inst.set_reward.shape[1]
    features = node_features(inst)
    views = 1
    if augment:  # [8, B, ...] -> [8B, ...], symmetry-major
        views = NUM_SYMMETRIES
        features = jax.tree_util.tree_map(_flatten2, symmetric_features(features))
    cache = model.prepare(features, _tile(inst.start, views))
    samples = best_of if best_of > 1 else 0
    starts = multi_start
    draws = 1 + samples + starts
    rows = views * b
    features_once, cache_once = features, cache
    cache = jax.tree_util.tree_map(lambda x: _tile(x, draws), cache)
    features = jax.tree_util.tree_map(lambda x: _tile(x, draws), features)
    every = jax.tree_util.tree_map(lambda x: _tile(x, views * draws), inst)
    draw = jnp.arange(draws * rows) // rows
    greedy = (draw == 0) | (draw > samples)
    first_set = None
    if starts == k:
        first_set = jnp.where(draw > samples, draw - samples - 1, -1).astype(jnp.int32)
    elif starts:  # [views * B, M] -> draw-major rows after the greedy plan and samples
        viewed = jax.tree_util.tree_map(lambda x: _tile(x, views), inst)
        top = first_sets(model, viewed, starts, features_once, cache_once)
        first_set = jnp.concatenate(
            [jnp.full(((1 + samples) * rows,), -1, jnp.int32), top.T.reshape(-1)]
        )
    trace = decode(
        model, every, key, temperature, greedy, features=features, cache=cache,
        first_set=first_set,
    )  # fmt: skip
    sol = trace.solution
    candidates = draws * views
    if starts and candidates > MULTI_START_REFINE:
        # refine only the greedy plan and the most promising other rollouts (ranked after
        # the budget gate): refining all K + 1 would cost ~K times the 2-opt of one plan
        ranked = budget_gate(every, sol)
        rows = _top_candidates(ranked, candidates, b, MULTI_START_REFINE)
        sol, every = (jax.tree_util.tree_map(lambda x: x[rows], t) for t in (sol, every))
        candidates = MULTI_START_REFINE
    if use_two_opt:
        sol = sop_two_opt(every, sol, max_iters=TWO_OPT_ITERS)
    sol = budget_gate(every, sol)
    if fill:
        sol = insertion_fill(every, sol)
    return _best(sol, candidates, b)


def check_decoding(best_of: int, multi_start: bool | int) -> None:
    """Raise ``ValueError`` unless ``best_of`` is a positive int and ``multi_start`` a
    bool or a non-negative int (the options of :meth:`StrategicPolicy.plan`)."""
    if not isinstance(best_of, int) or best_of < 1:
        raise ValueError(f"best_of must be a positive int, got {best_of!r}")
    if isinstance(multi_start, bool | np.bool_):
        return
    if not isinstance(multi_start, int | np.integer) or multi_start < 0:
        raise ValueError(f"multi_start must be a bool or a non-negative int, got {multi_start!r}")


def _starts(multi_start: bool | int, num_sets: int) -> int:
    """Multi-start rollouts per instance: K for ``True``, M for an int M (K at most)."""
    check_decoding(1, multi_start)
    if isinstance(multi_start, bool | np.bool_):
        return num_sets if multi_start else 0
    return min(int(multi_start), num_sets)


def _top_candidates(sol: Solution, candidates: int, b: int, keep: int) -> jax.Array:
    """Rows of candidate 0 (the greedy plan) and, per instance, the ``keep - 1`` other
    candidates with the largest reward, then the smallest cost.

    ``sol`` leaves are [C * B, ...] candidate-major; returns [keep * B] row indices,
    candidate-major too.
    """
    reward = sol.reward.reshape(candidates, b)[1:]
    cost = sol.cost.reshape(candidates, b)[1:]
    order = jnp.lexsort((cost, -reward), axis=0)[: keep - 1] + 1  # [keep - 1, B]
    order = jnp.concatenate([jnp.zeros((1, b), order.dtype), order])
    return (order * b + jnp.arange(b)[None]).reshape(-1)


def _pad(inst: SOPInstance, num_nodes: int, num_sets: int, xp: Any = np) -> SOPInstance:
    """Pad a batch to N nodes (padding: set -1, unreachable) and K zero-reward sets.

    ``xp``: ``numpy`` on the host, ``jax.numpy`` inside a traced program.
    """
    b, n = inst.set_id.shape
    k = inst.set_reward.shape[1]
    extra_n, extra_k = num_nodes - n, num_sets - k
    cost = xp.pad(
        xp.asarray(inst.cost, xp.float32),
        ((0, 0), (0, extra_n), (0, extra_n)),
        constant_values=np.inf,
    )
    return SOPInstance(
        cost=cost,
        set_id=xp.pad(
            xp.asarray(inst.set_id, xp.int32), ((0, 0), (0, extra_n)), constant_values=-1
        ),
        set_reward=xp.pad(xp.asarray(inst.set_reward, xp.float32), ((0, 0), (0, extra_k))),
        start=xp.asarray(inst.start, xp.int32),
        end=xp.asarray(inst.end, xp.int32),
        budget=xp.asarray(inst.budget, xp.float32),
        coords=xp.pad(xp.asarray(inst.coords, xp.float32), ((0, 0), (0, extra_n), (0, 0))),
    )


def _unpad(sol: Solution, num_sets: int, single: bool) -> Solution:
    """Cut the plan slots to the caller's T = plan_length(k) (padding sets are never used)."""
    sol = sol.replace(nodes=sol.nodes[:, : plan_length(num_sets)])
    return jax.tree_util.tree_map(lambda x: x[0], sol) if single else sol


def _tile(x: jax.Array, times: int) -> jax.Array:
    """[B, ...] -> [times * B, ...] (copy-major)."""
    return jnp.broadcast_to(x, (times,) + x.shape).reshape((times * x.shape[0],) + x.shape[1:])


def _flatten2(x: jax.Array) -> jax.Array:
    return x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:])


def _best(sol: Solution, candidates: int, b: int) -> Solution:
    """Per instance, the candidate with the largest reward, then the smallest cost.

    ``sol`` leaves are [C * B, ...] candidate-major; rewards within a relative 1e-6 of the
    best count as equal (float32 sums in different orders).
    """
    reward = sol.reward.reshape(candidates, b)
    cost = sol.cost.reshape(candidates, b)
    top = jnp.max(reward, axis=0)
    tie = reward >= top - 1e-6 * jnp.maximum(1.0, jnp.abs(top))
    pick = ops.argmin(jnp.where(tie, cost, jnp.inf), axis=0)
    rows = pick * b + jnp.arange(b)
    return jax.tree_util.tree_map(lambda x: x[rows], sol)
