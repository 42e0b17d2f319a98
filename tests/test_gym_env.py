"""The gymnax-style environment: contract, spaces, wrappers, the candidate interface, and
its scripted policies against the navigation benchmark's own runs and scoring."""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.agents.candidate import nearest_frontier
from bfsop_jax.env import make, observe
from bfsop_jax.env.candidates import STOP, pose_candidates
from bfsop_jax.env.spaces import Box, Dict, Discrete
from bfsop_jax.env.wrappers import AutoReset, LogWrapper, episode_ppl
from bfsop_jax.eval import navigation as nav
from bfsop_jax.world.generator import generate_house

B = 4  # environments per batch
STEPS = 24  # macro steps per batched run (smoke episodes end in 5-40)


@functools.cache
def smoke_params(actions: str = "candidates", budget: float = 30.0):
    """The environment with a stacked set of four smoke houses as its house source (a
    reset then only gathers one: the tests compile no house generator into their
    programs), and a short budget: several episodes per run."""
    env, params = make("smoke", actions)
    gen = jax.jit(jax.vmap(generate_house, in_axes=(0, None)), static_argnums=1)
    houses = gen(jax.vmap(jax.random.key)(jnp.arange(4)), env.preset)
    return env, params.replace(houses=houses, budget=jnp.float32(budget))


def random_candidate(key, obs):
    """Uniform over the available candidates, stop only when nothing else is left."""
    go = obs.action_mask & (jnp.arange(obs.action_mask.shape[0]) != STOP)
    logits = jnp.where(go, 0.0, -jnp.inf)
    return jnp.where(jnp.any(go), jax.random.categorical(key, logits), STOP).astype(jnp.int32)


@functools.cache
def setup(actions: str):
    env, params = smoke_params(actions)
    wrapped = LogWrapper(AutoReset(env))
    reset_b = jax.jit(jax.vmap(wrapped.reset, in_axes=(0, None)))

    def policy(key, obs):
        if actions == "candidates":
            return random_candidate(key, obs)
        return env.action_space(params).sample(key)

    @jax.jit
    def run(state, obs, key):
        def body(carry, k):
            state, obs = carry
            ka, ks = jax.random.split(k)
            act = jax.vmap(policy)(jax.random.split(ka, B), obs)
            obs, state, r, term, trunc, info = jax.vmap(
                wrapped.step, in_axes=(0, 0, 0, None)
            )(jax.random.split(ks, B), state, act, params)
            return (state, obs), (r, term, trunc, info)

        return jax.lax.scan(body, (state, obs), jax.random.split(key, STEPS))

    obs, state = reset_b(jax.random.split(jax.random.key(0), B), params)
    (state, obs), out = run(state, obs, jax.random.key(1))
    return env, params, state, obs, out


def test_make_and_bad_input():
    for name in ("smoke", "demo", "paper"):
        env, params = make(name)
        assert env.preset.name == name and float(params.budget) == env.preset.budget_m
    with pytest.raises(ValueError, match="actions must be one of"):
        make("smoke", "pixels")
    with pytest.raises(ValueError, match="unknown preset"):
        make("tiny")
    with pytest.raises(ValueError, match="prior must have shape"):
        make("smoke", prior=np.ones((3, 3)))
    env, _ = make("smoke", "candidates")
    assert env.num_actions == 1 + env.preset.max_frontier_clusters + env.preset.n_loi


@pytest.mark.parametrize("actions", ["native", "candidates"])
def test_random_episodes_keep_the_contract(actions):
    env, params, state, obs, (reward, term, trunc, info) = setup(actions)
    # every leaf finite, observations inside the space
    for leaf in jax.tree_util.tree_leaves((state, obs)):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert bool(jnp.all(jnp.isfinite(leaf)))
    space = env.observation_space(params)
    for b in range(B):
        assert bool(space.contains(jax.tree_util.tree_map(lambda x, b=b: x[b], obs)))
    reward, term, trunc = map(np.asarray, (reward, term, trunc))
    done = np.asarray(info["returned_episode"])
    assert (reward >= 0).all() and (reward <= 1).all()
    assert np.array_equal(done, term | trunc) and done.sum() >= B
    # an episode's return is its progress P_T; terminated means the gate, all found,
    # or (candidates) nothing left / stop; truncation only past the macro-step limit
    ret, prog = np.asarray(info["episode_return"]), np.asarray(info["episode_progress"])
    np.testing.assert_allclose(ret[done], prog[done], atol=1e-6)
    length = np.asarray(info["episode_path_length"])[done]
    found = np.asarray(info["episode_found"])[done]
    total = np.asarray(info["episode_n_targets"])[done]
    ended = (length >= float(params.budget) - 1e-4) | (found >= total)
    if actions == "native":
        assert ended[term[done]].all()
    assert (np.asarray(info["episode_macro_steps"])[trunc] >= int(params.max_steps)).all()
    assert (np.asarray(info["episode_last_find_length"])[done] <= length + 1e-5).all()


def test_spaces_sample_and_contain():
    key = jax.random.key(3)
    for actions in ("native", "candidates"):
        env, params = make("smoke", actions)
        space = env.action_space(params)
        a = space.sample(key)
        assert bool(space.contains(a))
        obs_space = env.observation_space(params)
        assert bool(obs_space.contains(obs_space.sample(key)))
    assert isinstance(make("smoke", "candidates")[0].action_space(), Discrete)
    box = Box(0.0, 1.0, (2,))
    assert not bool(box.contains(jnp.array([0.5, 2.0])))
    assert not bool(box.contains(jnp.zeros(3)))
    assert not bool(Discrete(3).contains(jnp.int32(3)))
    assert not bool(Dict({"a": box}).contains({"b": jnp.zeros(2)}))


def test_one_trace_and_the_same_episode_alone_or_in_a_batch():
    env, params = smoke_params()

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(key, state, action):
        return env.step(key, state, action, params)

    keys = jax.random.split(jax.random.key(7), 3)
    obs_b, state_b = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
    step_b = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    single = jax.jit(env.reset)(keys[1], params)
    for _ in range(4):
        act_b = jax.vmap(nearest_frontier)(obs_b)
        obs_b, state_b, *_ = step_b(jax.random.split(keys[0], 3), state_b, act_b, params)
        obs, state = single
        single = step(keys[0], state, nearest_frontier(obs))[:2]
    row = jax.tree_util.tree_map(lambda x: x[1], (obs_b, state_b))
    chex.assert_trees_all_equal(row, single)


def test_auto_reset_runs_only_finished_rows_and_reports_the_final_observation():
    env, params = smoke_params()
    params = params.replace(max_steps=jnp.int32(1))  # every episode truncated at once
    keys = jax.random.split(jax.random.key(11), 3)
    reset_b = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    obs, state = reset_b(keys, params)
    act = jax.vmap(nearest_frontier)(obs)
    step_keys = jax.random.split(jax.random.key(1), 3)
    results = []
    for sparse in (True, False):
        auto = AutoReset(env, sparse=sparse)
        results.append(jax.jit(jax.vmap(auto.step, in_axes=(0, 0, 0, None)))(
            step_keys, state, act, params))  # fmt: skip
    chex.assert_trees_all_equal(results[0], results[1])  # dense: gymnax's way, same result
    o, s, _, term, trunc, info = results[0]
    assert bool(jnp.all(trunc | term))
    assert bool(jnp.all(s.env.steps == 0))  # fresh episodes
    # the new episodes are the ones reset with the wrapper's reset key
    fresh = reset_b(jax.vmap(lambda k: jax.random.split(k)[1])(step_keys), params)
    chex.assert_trees_all_equal((o, s), fresh)
    # the finished step's own last observation is in the info
    plain = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))(
        jax.vmap(lambda k: jax.random.split(k)[0])(step_keys), state, act, params)  # fmt: skip
    chex.assert_trees_all_equal(info["final_observation"], plain[0])


def test_houses_from_the_source_and_categories_by_weight():
    env, params = smoke_params("native")
    houses = params.houses
    weights = jnp.zeros(9).at[2].set(1.0)  # Cup only, where there is one
    reset_b = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    obs, state = reset_b(jax.random.split(jax.random.key(5), 8),
                         params.replace(category_weights=weights))  # fmt: skip
    ids = np.asarray(state.house_id)
    assert set(ids) <= {0, 1, 2, 3} and len(set(ids)) > 1
    for i, h in enumerate(ids):
        np.testing.assert_array_equal(np.asarray(state.env.house.occupied[i]),
                                      np.asarray(houses.occupied[h]))  # fmt: skip
        cats = np.asarray(houses.object_category[h])
        counts = np.bincount(cats[(cats >= 0) & (cats < 9)], minlength=9)
        if counts[2] > 0:
            assert int(state.env.category[i]) == 2
        assert int(state.n_targets[i]) == counts[int(state.env.category[i])] >= 1
    # procedural houses: the seed is drawn from the range, and it is the seed's house
    _, procedural = make("smoke", "native")
    procedural = procedural.replace(seed_low=jnp.int32(1000000), seed_high=jnp.int32(1000002))
    _, state = jax.jit(env.reset)(jax.random.key(0), procedural)
    seed = int(state.house_id)
    assert seed in (1000000, 1000001)
    house = jax.jit(generate_house, static_argnums=1)(jax.random.key(seed), env.preset)
    np.testing.assert_array_equal(np.asarray(state.env.house.occupied),
                                  np.asarray(house.occupied))  # fmt: skip


def test_candidates_never_read_the_true_house():
    env, params = smoke_params()
    obs, state = jax.jit(env.reset)(jax.random.key(2), params)
    sim = state.env
    unseen = ~np.asarray(sim.receptacles_seen | sim.landmarks_seen | sim.found)
    unseen &= np.asarray(sim.house.object_category) >= 0
    moved = sim.house.replace(
        object_xy=jnp.where(jnp.asarray(unseen)[:, None], 1.0, sim.house.object_xy),
        object_category=jnp.where(jnp.asarray(unseen), 0, sim.house.object_category),
    )
    pose = jax.jit(lambda m, o: pose_candidates(m, o, env.preset, env.candidate_config))
    a = pose(state.candidates, observe(sim))
    b = pose(state.candidates, observe(sim.replace(house=moved)))
    chex.assert_trees_all_equal(a, b)


def test_nearest_frontier_is_fbe_and_the_log_scores_as_the_benchmark(tmp_path):
    """The candidate interface's nearest-frontier policy walks FBE's episodes, and the PPL
    scored on the host from what LogWrapper records equals the benchmark's for them."""
    houses = nav.HouseSet(get_smoke())
    episodes = nav.protocol_episodes(houses, [1000000], [0, 8])
    result = nav.evaluate_navigation(["fbe"], episodes, houses, tmp_path, batch=2,
                                     progress=False)  # fmt: skip
    env, params = make("smoke", "candidates")
    logged = LogWrapper(AutoReset(env))
    n = int(params.max_steps)

    @jax.jit
    def play(obs, state, params):
        def body(carry, _):
            obs, state = carry
            obs, state, _, _, _, info = logged.step(jax.random.key(0), state, nearest_frontier(obs),
                                                    params)  # fmt: skip
            return (obs, state), info

        return jax.lax.scan(body, (obs, state), None, length=n)[1]

    for ep, record in zip(episodes, result["episodes"], strict=True):
        house = houses[ep.house]
        # the auto-reset after the episode draws from this house too (no generator compiled)
        params = params.replace(houses=jax.tree_util.tree_map(lambda a: a[None], house))
        obs, state = jax.jit(logged.reset_to)(ep.key, params, house, ep.category, ep.house)
        info = jax.device_get(play(obs, state, params))
        first = int(np.argmax(info["returned_episode"]))
        assert info["returned_episode"][first]
        row = {k: v[first] for k, v in info.items() if k.startswith("episode_")}
        scored = episode_ppl(row, env.preset, houses)
        assert row["episode_found"] == record["found"]
        assert row["episode_n_targets"] == record["total"]
        assert scored["path_length"] == pytest.approx(record["path_length"], abs=1e-5)
        assert scored["l_opt"] == pytest.approx(record["l_opt"], abs=1e-5)
        assert scored["ppl"] == pytest.approx(record["ppl"], abs=1e-6)
        if record["found"] < record["total"]:  # FBE goes on once all are found
            assert row["episode_path_length"] == pytest.approx(record["path_length_end"])


def get_smoke():
    from bfsop_jax.config import get_preset

    return get_preset("smoke")
