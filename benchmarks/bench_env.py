"""Environment throughput: both action interfaces under AutoReset, beside FBE's rollout.

Usage::

    python -m benchmarks.bench_env --preset demo --batches 1,32,1024
    python -m benchmarks.bench_env --preset demo --batches 1024,4096   # on an accelerator

For each batch size, on the same batch of episodes (reset from the default params: a
training house seed, a category it contains, a start), one jitted ``lax.scan`` of
``--steps`` macro steps (fewer at large batches, so a call stays short on a CPU) of:

* ``fbe``: the FBE strategy's own rollout (``continue_rollout``), the reference;
* ``candidates/nearest``: ``AutoReset(make(preset, "candidates"))`` driven by the
  nearest-frontier candidate policy (FBE's decisions, posed through the interface);
* ``candidates/random``: the same environment, a uniformly random available candidate;
* ``native/random``: ``AutoReset(make(preset))`` with random goal and look points.

Prints environment (macro) steps per second and motion steps per second, compilation
timed apart (the first call), and where a candidate step's time goes: posing the
candidates vs the simulator's step, each timed alone on the same batch. Record results
with the machine and date in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json

import jax
import jax.numpy as jnp

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import machine, time_calls
from bfsop_jax.agents import FBE, continue_rollout
from bfsop_jax.agents.candidate import nearest_frontier
from bfsop_jax.config import PRESET_NAMES
from bfsop_jax.env import make, observe, step
from bfsop_jax.env.candidates import STOP, pose_candidates
from bfsop_jax.env.wrappers import AutoReset

WORK = 2048  # environment steps per timed call at most (batch x scan length)


def _random_candidate(key, obs):
    go = obs.action_mask & (jnp.arange(obs.action_mask.shape[0]) != STOP)
    pick = jax.random.categorical(key, jnp.where(go, 0.0, -jnp.inf))
    return jnp.where(jnp.any(go), pick, STOP).astype(jnp.int32)


def _env_scan(env, params, policy, n: int):
    """A jitted scan of ``n`` auto-reset steps of a vmapped batch; returns its motion
    steps (int32 [])."""
    auto = AutoReset(env)
    step_b = jax.vmap(auto.step, in_axes=(0, 0, 0, None))

    @jax.jit
    def run(obs, state, key):
        def body(carry, k):
            obs, state = carry
            b = obs.pose.shape[0]
            ka, ks = jax.random.split(k)
            act = jax.vmap(policy)(jax.random.split(ka, b), obs)
            obs, state, _, _, _, info = step_b(jax.random.split(ks, b), state, act, params)
            return (obs, state), info["motion_steps"].sum()

        _, moved = jax.lax.scan(body, (obs, state), jax.random.split(key, n))
        return moved.sum()

    return run


def _fbe_rollout(states, preset, n: int):
    """FBE's own jitted rollout of ``n`` macro steps (returns its motion steps, int32 [])
    and its initial memory for ``states``."""
    fbe = FBE()
    memory = jax.jit(jax.vmap(lambda s: fbe.init(observe(s), preset)))(states)
    roll = jax.vmap(lambda s, m: continue_rollout(s, m, fbe, preset, n))
    return jax.jit(lambda s, m: roll(s, m)[2].moved.sum()), memory


def run(preset_name: str, batches: list[int], steps: int, repeats: int) -> dict:
    env_c, params = make(preset_name, "candidates")
    env_n, _ = make(preset_name)
    preset = env_c.preset
    rows = []
    for b in batches:
        n = max(2, min(steps, WORK // b))
        keys = jax.random.split(jax.random.key(0), b)
        obs_c, state_c = jax.jit(jax.vmap(env_c.reset, in_axes=(0, None)))(keys, params)
        obs_n, state_n = jax.jit(jax.vmap(env_n.reset, in_axes=(0, None)))(keys, params)
        key = jax.random.key(1)

        fbe_moves, memory = _fbe_rollout(state_c.env, preset, n)
        cases = {
            "fbe": (fbe_moves, (state_c.env, memory)),
            "candidates/nearest": (
                _env_scan(env_c, params, lambda k, o: nearest_frontier(o), n),
                (obs_c, state_c, key),
            ),
            "candidates/random": (
                _env_scan(env_c, params, _random_candidate, n), (obs_c, state_c, key)
            ),
            "native/random": (
                _env_scan(env_n, params, lambda k, o: env_n.action_space(params).sample(k), n),
                (obs_n, state_n, key),
            ),
        }
        for name, (fn, args) in cases.items():
            t = time_calls(fn, *args, repeats=repeats if b < 256 else 1)
            moves = int(fn(*args))
            rows.append({
                "batch": b, "case": name, "scan": n, "compile_s": t.first_s - t.median,
                "s_per_call": t.median, "env_steps_per_s": b * n / t.median,
                "motion_steps_per_s": moves / t.median,
            })  # fmt: skip
            print(f"  batch {b:5d} {name:20s} {rows[-1]['env_steps_per_s']:9.1f} env steps/s "
                  f"{rows[-1]['motion_steps_per_s']:10.1f} motion steps/s  (compile "
                  f"{rows[-1]['compile_s']:.1f} s, {n} steps per call)", flush=True)  # fmt: skip
        # where a candidate step's time goes: posing vs the simulator, on the same batch
        pose = jax.jit(jax.vmap(lambda m, s: pose_candidates(m, observe(s), preset,
                                                             env_c.candidate_config)))  # fmt: skip
        sim = jax.jit(jax.vmap(lambda s, a: step(s, a, preset)))
        action = jax.vmap(lambda c: jax.tree_util.tree_map(lambda x: x[1], c))(
            state_c.candidates.candidates)  # fmt: skip
        from bfsop_jax.env.types import Action

        native = Action(goal_xy=action.goal_xy, look_xy=action.look_xy, look=action.look)
        t_pose = time_calls(pose, state_c.candidates, state_c.env, repeats=repeats)
        t_sim = time_calls(sim, state_c.env, native, repeats=repeats)
        rows.append({"batch": b, "case": "split", "pose_ms": 1e3 * t_pose.median,
                     "sim_step_ms": 1e3 * t_sim.median})  # fmt: skip
        print(f"  batch {b:5d} per macro step: posing candidates {1e3 * t_pose.median:.1f} ms, "
              f"simulator step {1e3 * t_sim.median:.1f} ms", flush=True)
    by = {(r["batch"], r["case"]): r for r in rows}
    rate = lambda b, case: by[(b, case)]["motion_steps_per_s"]
    ratios = {b: rate(b, "candidates/nearest") / rate(b, "fbe") for b in batches}
    for b, r in ratios.items():
        print(f"  batch {b:5d}: candidate interface at {r:.0%} of FBE's motion steps/s")
    return {"preset": preset.name, "machine": machine(), "date": dt.date.today().isoformat(),
            "rows": rows, "candidates_vs_fbe": ratios}  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_env`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    ap.add_argument("--batches", default="1,32,1024",
                    help="comma-separated batch sizes (default 1,32,1024)")
    ap.add_argument("--steps", type=positive_int, default=16,
                    help="macro steps per timed call (fewer at large batches)")
    ap.add_argument("--repeats", type=positive_int, default=2)
    ap.add_argument("--json", default=None, help="also write the results here")
    return ap


def main(argv: list[str] | None = None) -> dict:
    args = build_parser().parse_args(argv)
    try:
        batches = [int(x) for x in args.batches.split(",")]
    except ValueError:
        raise ValueError(
            f"--batches must be comma-separated integers, got {args.batches!r}"
        ) from None
    if not batches or min(batches) < 1:
        raise ValueError(f"--batches must be positive, got {args.batches!r}")
    print(f"bench_env: preset {args.preset}, {machine()}", flush=True)
    out = run(args.preset, batches, args.steps, args.repeats)
    if args.json:
        from bfsop_jax import files

        files.write_text(args.json, json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    run_main(main)
