"""StrategicPolicy: loading (and its errors), feasible plans, padding, options, no retracing."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

import bfsop_jax.policy as policy_module
from bfsop_jax.checkpoint import CheckpointStore, save_model, write_config
from bfsop_jax.model import ModelConfig, StrategicTransformer
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.sop import SOPInstance, evaluate, plan_length
from bfsop_jax.sop.io import random_instance
from bfsop_jax.training import RunConfig, TrainConfig
from bfsop_jax.training.bc import init_states

CONFIG = ModelConfig(d_model=32, n_layers=1, n_heads=2, d_ff=64)
NODES, SETS = 25, 9  # model capacity; test instances have 19 nodes and 7 sets


def run_config(model_config: ModelConfig = CONFIG) -> dict:
    return {
        "run": RunConfig(model=model_config, train=TrainConfig(epochs=2)).to_dict(),
        "replicas": [{"seed": 0, "lr": 1e-3}, {"seed": 1, "lr": 1e-3}],
        "dataset": {"num_nodes": NODES, "num_sets": SETS},
    }


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run directory with a (random-weight) model, as training leaves it."""
    path = tmp_path_factory.mktemp("run")
    model = StrategicTransformer(CONFIG, rngs=nnx.Rngs(0))
    kernel = model.decoder.project_glimpse.kernel  # zero at init: make the scores non-uniform
    kernel[...] = jax.random.normal(jax.random.key(1), kernel.shape) / np.sqrt(kernel.shape[0])
    write_config(path, run_config())
    save_model(path, nnx.split(model, nnx.Param)[1])
    return path


@pytest.fixture(scope="module")
def policy(run_dir) -> StrategicPolicy:
    return StrategicPolicy.load(run_dir)


def instances(seeds) -> list[SOPInstance]:
    return [random_instance(s, num_sets=6, viewpoints=3, masked_sets=s % 3) for s in seeds]


def stack(insts: list[SOPInstance]) -> SOPInstance:
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *insts)


def assert_matches_evaluate(inst: SOPInstance, sol) -> None:
    reward, cost, feasible = evaluate(inst, np.asarray(sol.nodes))
    assert feasible, np.asarray(sol.nodes)
    assert np.isclose(float(sol.reward), reward, rtol=1e-5, atol=1e-5)
    assert np.isclose(float(sol.cost), cost, rtol=1e-5, atol=1e-4)


# -- loading ---------------------------------------------------------------------------------
# Orbax leaves a failed asynchronous read behind; the error we check is raised all the same
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_load_errors(tmp_path, run_dir, monkeypatch):
    with pytest.raises(ValueError, match="does not exist"):
        StrategicPolicy.load(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="missing config.json"):
        StrategicPolicy.load(tmp_path)
    write_config(tmp_path, run_config())
    with pytest.raises(ValueError, match="no checkpoint"):
        StrategicPolicy.load(tmp_path)
    with pytest.raises(ValueError, match="no saved model"):
        StrategicPolicy.load(tmp_path, checkpoint="model")
    (tmp_path / "config.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        StrategicPolicy.load(tmp_path)
    monkeypatch.setattr(policy_module, "ASSETS_DIR", tmp_path / "not_shipped")
    with pytest.raises(ValueError, match="pretrained demo policy"):
        StrategicPolicy.load()
    with pytest.raises(ValueError, match="pretrained paper policy"):
        StrategicPolicy.load("paper")
    other = tmp_path / "other"
    other.mkdir()
    # a model saved for another architecture does not fit the config
    write_config(other, run_config())
    save_model(
        other,
        nnx.split(
            StrategicTransformer(
                ModelConfig(d_model=16, n_layers=1, n_heads=2, d_ff=8), rngs=nnx.Rngs(0)
            ),
            nnx.Param,
        )[1],
    )
    with pytest.raises(ValueError, match="cannot read model checkpoint"):
        StrategicPolicy.load(other)


# Orbax leaves a failed asynchronous read behind; the error we check is raised all the same
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
@pytest.mark.parametrize("damage", ["truncate", "garble"])
def test_corrupt_checkpoint(tmp_path, run_dir, damage):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    files = sorted(p for p in (copy / "model").rglob("*") if p.is_file() and p.stat().st_size)
    assert files
    for path in files:
        data = path.read_bytes()
        if damage == "truncate":
            path.write_bytes(data[: len(data) // 2])
        else:
            path.write_bytes(bytes(b ^ 0x5A for b in data))
    with pytest.raises(ValueError, match="cannot read model checkpoint"):
        StrategicPolicy.load(copy)


def test_load_latest_epoch_checkpoint(tmp_path):
    """An unfinished run (no model/ yet) loads the best replica of its last checkpoint."""
    write_config(tmp_path, run_config())
    recipe = TrainConfig(epochs=2)
    graphdef, states = init_states(CONFIG, recipe, seeds=[0, 1], lrs=[1e-3, 1e-3])
    with CheckpointStore(tmp_path) as store:
        store.save(1, states, {"epoch": 1, "best_replica": 1, "selection_loss": [2.0, 1.0]})
    policy = StrategicPolicy.load(tmp_path)
    want = jax.tree_util.tree_leaves(jax.tree_util.tree_map(lambda x: x[1], states.params))
    got = jax.tree_util.tree_leaves(policy._params)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


# -- planning --------------------------------------------------------------------------------
def test_fingerprint_names_the_weights(run_dir, policy):
    """The same weights loaded again give the same fingerprint; one changed weight, or
    another capacity, another."""
    again = StrategicPolicy.load(run_dir)
    assert again.fingerprint == policy.fingerprint and len(policy.fingerprint) == 16
    model = StrategicTransformer(CONFIG, rngs=nnx.Rngs(0))
    nnx.update(model, jax.tree_util.tree_map(np.array, policy.params))
    assert StrategicPolicy(model, NODES, SETS).fingerprint == policy.fingerprint
    assert StrategicPolicy(model, NODES + 1, SETS).fingerprint != policy.fingerprint
    kernel = model.decoder.project_glimpse.kernel
    kernel[...] = jnp.asarray(kernel[...]).at[0, 0].add(1e-3)
    assert StrategicPolicy(model, NODES, SETS).fingerprint != policy.fingerprint


def test_instance_larger_than_the_model(policy):
    big = random_instance(0, num_sets=8, viewpoints=4)  # 33 nodes, 9 sets
    with pytest.raises(ValueError, match="at most 25 nodes and 9 sets"):
        policy.plan(big)
    bad = instances([0])[0]
    with pytest.raises(ValueError, match="NaN"):
        policy.plan(bad.replace(cost=np.where(np.eye(19) > 0, np.nan, bad.cost)))


def test_batch_plans_are_feasible(policy):
    insts = instances(range(8))
    batch = stack(insts)
    with_2opt = policy.plan(batch)
    without = policy.plan_without_two_opt(batch)
    assert with_2opt.nodes.shape == (8, plan_length(7))
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, with_2opt[i])
        assert_matches_evaluate(inst, without[i])
    assert float(with_2opt.reward.sum()) > 0  # not the empty plan everywhere


def test_single_instances_compile_once(policy, monkeypatch):
    """Single instances of any size up to the capacity share one compiled program."""
    counted = chex.assert_max_traces(policy_module._plan_program, n=1)
    monkeypatch.setattr(policy_module, "_plan_program", counted)
    chex.clear_trace_counter()
    compiled = policy_module._plan_jit._cache_size()
    small = random_instance(3, num_sets=4, viewpoints=2)  # 9 nodes, 5 sets: padded
    plans = []
    for inst in instances(range(20, 23)) + [small]:
        sol = policy.plan(inst)
        assert sol.nodes.shape == (plan_length(inst.num_sets),)
        assert_matches_evaluate(inst, sol)
        plans.append(sol)
    assert policy_module._plan_jit._cache_size() <= compiled + 1
    monkeypatch.undo()
    # a single instance gets the plan it gets in a batch
    batch_plan = policy.plan(stack(instances(range(20, 23)) + instances([20]) * 5))
    np.testing.assert_array_equal(batch_plan.nodes[0], plans[0].nodes)


def test_augment_and_best_of(policy):
    insts = instances(range(30, 38))
    batch = stack(insts)
    plain = policy.plan(batch)  # same batch size as above: no new compile
    extra = policy.plan(batch, augment=True, best_of=3, key=jax.random.key(4))
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, extra[i])
    # the greedy identity view is one of the candidates, the best is kept
    assert (np.asarray(extra.reward) >= np.asarray(plain.reward) - 1e-5).all()
    again = policy.plan(batch, augment=True, best_of=3, key=jax.random.key(4))
    np.testing.assert_array_equal(again.nodes, extra.nodes)
    with pytest.raises(ValueError, match="best_of"):
        policy.plan(batch, best_of=0)


def test_multi_start_is_at_least_the_greedy_plan(policy):
    """One greedy rollout per first set, the greedy plan among the refined candidates:
    never worse than plain greedy decoding, feasible, deterministic."""
    insts = instances(range(30, 38))
    batch = stack(insts)
    plain = policy.plan(batch)
    multi = policy.plan(batch, multi_start=True)
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, jax.tree_util.tree_map(lambda x, i=i: x[i], multi))
    assert (np.asarray(multi.reward) >= np.asarray(plain.reward) - 1e-5).all()
    assert float(np.sum(multi.reward)) > float(np.sum(plain.reward))  # the extra starts help
    np.testing.assert_array_equal(policy.plan(batch, multi_start=True).nodes, multi.nodes)


def test_top_first_sets_follow_the_first_step_scores(policy):
    """``first_sets``: the sets whose best allowed node the decoder scores highest for its
    first move, best first, the greedy move's own set left out, -1 past the open sets."""
    from bfsop_jax.model.decode import first_sets  # noqa: PLC0415

    for inst in instances(range(60, 64)):
        probs = np.asarray(policy.trace(inst).probs[0])[:19]  # first step, real nodes
        set_id = np.asarray(inst.set_id)
        padded = policy._prepare(inst)[0]
        top = np.asarray(first_sets(policy.model, padded, SETS))[0]
        per_set = {s: probs[set_id == s].max() for s in set(set_id[set_id >= 0].tolist())}
        greedy_set = set_id[int(np.argmax(probs))]
        ranked = sorted(
            (s for s, p in per_set.items() if p > 0 and s != greedy_set), key=lambda s: -per_set[s]
        )
        np.testing.assert_array_equal(top[: len(ranked)], ranked)
        assert (top[len(ranked) :] == -1).all()


def test_multi_start_over_the_top_first_sets(policy):
    """``multi_start=M``: M more rollouts from the top-scored first sets; feasible, never
    worse than greedy, deterministic; M >= K is the full multi-start, 0 none."""
    insts = instances(range(30, 38))
    batch = stack(insts)
    plain = policy.plan(batch)
    top = policy.plan(batch, multi_start=2)
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, jax.tree_util.tree_map(lambda x, i=i: x[i], top))
    assert (np.asarray(top.reward) >= np.asarray(plain.reward) - 1e-5).all()
    np.testing.assert_array_equal(policy.plan(batch, multi_start=2).nodes, top.nodes)
    every = policy.plan(batch, multi_start=True)
    np.testing.assert_array_equal(policy.plan(batch, multi_start=SETS + 3).nodes, every.nodes)
    np.testing.assert_array_equal(policy.plan(batch, multi_start=0).nodes, plain.nodes)
    # with the coordinate symmetries each view ranks its own first sets
    both = policy.plan(batch, multi_start=2, augment=True)
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, jax.tree_util.tree_map(lambda x, i=i: x[i], both))
    for bad in (-1, 1.5, "4"):
        with pytest.raises(ValueError, match="multi_start"):
            policy.plan(batch, multi_start=bad)


def test_closed_tour_ends_at_the_depot(policy):
    inst = random_instance(5, num_sets=6, viewpoints=3, closed=True)
    sol = policy.plan(inst)
    nodes = [n for n in np.asarray(sol.nodes) if n >= 0]
    assert nodes[0] == 0 and nodes[-1] == 0
    assert_matches_evaluate(inst, sol)


def test_trace_has_distributions(policy):
    inst = instances([40])[0]
    trace = policy.trace(inst)
    probs = np.asarray(trace.probs)
    assert probs.shape == (plan_length(SETS) - 1, NODES + 1)
    first = probs[0]
    assert np.isclose(first.sum(), 1.0, atol=1e-5) and first[0] == 0.0  # start masked
    assert (first[19:NODES] == 0).all()  # padding nodes masked
    assert jnp.asarray(trace.solution.nodes).shape == (plan_length(7),)


def test_plan_traced_inside_jit(policy):
    """The pure variant runs inside a caller's jit (here with a smaller instance, padded
    with jnp) and gives the same plan as ``plan``."""
    insts = instances(range(50, 58))
    batch = stack(insts)
    traced = jax.jit(lambda inst: policy.plan_traced(inst))(batch)
    np.testing.assert_array_equal(traced.nodes, policy.plan(batch).nodes)
    np.testing.assert_allclose(traced.cost, policy.plan(batch).cost, rtol=1e-6)


def test_nothing_to_visit_gives_the_empty_plan(policy):
    """No landmark left (every set masked) or no budget: the start-only plan, no crash."""
    empty = random_instance(60, num_sets=6, viewpoints=3, masked_sets=6)
    broke = instances([61])[0].replace(budget=np.float32(0.0))
    for inst in (empty, broke):
        sol = policy.plan(inst)
        assert [n for n in np.asarray(sol.nodes) if n >= 0] == [0]
        assert float(sol.reward) == 0.0 and float(sol.cost) == 0.0


def test_fill_option_adds_reward_within_budget(policy):
    batch = stack(instances(range(30, 36)))
    plain = policy.plan(batch)
    filled = policy.plan(batch, fill=True)
    for i in range(6):
        inst = jax.tree_util.tree_map(lambda x, i=i: x[i], batch)
        assert_matches_evaluate(inst, jax.tree_util.tree_map(lambda x, i=i: x[i], filled))
        assert float(filled.reward[i]) >= float(plain.reward[i]) - 1e-5


@pytest.mark.parametrize("name", ["demo", "paper"])
def test_shipped_policies_plan_map_instances(name):
    """The pretrained models in the package (``StrategicPolicy.load()`` with no argument is
    the demo one; ``load("paper")`` the paper-size one) plan navigation-sized instances
    (N = 76, K = 16) feasibly and beat an empty plan."""
    shipped = StrategicPolicy.load(name)
    assert (shipped.num_nodes, shipped.num_sets) == (76, 16)
    assert shipped.config.decoder == "insertion" and shipped.config.refine
    if name == "demo":
        assert StrategicPolicy.load().config == shipped.config  # the default model
    else:  # the paper model: 6 encoder layers, 8 heads, d = 128, ff 512, insertion decoder
        m = shipped.config
        assert (m.n_layers, m.n_heads, m.d_model, m.d_ff) == (6, 8, 128, 512)
    insts = [random_instance(s, num_sets=15, viewpoints=5, masked_sets=s % 3) for s in range(4)]
    sol = shipped.plan(stack(insts))
    for i, inst in enumerate(insts):
        assert_matches_evaluate(inst, jax.tree_util.tree_map(lambda x, i=i: x[i], sol))
    assert float(np.mean(np.asarray(sol.reward))) > 0


def test_unchecked_plan_equals_checked_plan(policy):
    """``check=False`` (shapes from metadata, padding in the program) plans the same as the
    checked path, for one instance (NumPy or device arrays) and for a batch; it still
    refuses instances larger than the model."""
    insts = instances(range(3))
    for inst in insts:
        want = policy.plan(inst, fill=True)
        on_device = jax.tree_util.tree_map(jnp.asarray, inst)
        for x in (inst, on_device):
            got = policy.plan(x, fill=True, check=False)
            chex.assert_trees_all_equal(got, want)
    batch = stack(insts)
    chex.assert_trees_all_equal(policy.plan(batch, check=False), policy.plan(batch))
    big = random_instance(0, num_sets=SETS + 1, viewpoints=2)
    with pytest.raises(ValueError, match="at most"):
        policy.plan(big, check=False)
