"""Where a single-instance plan of the Strategic Transformer spends its time.

``python -m benchmarks.bench_policy --model demo --houses 2`` poses held-out navigation
tasks (exploration runs in held-out houses, as the distillation's evaluation does), then
times one instance at a time, side by side in one run:

* ``StrategicPolicy.plan`` as users call it (greedy decoding + 2-opt + budget gate);
* its parts: the host-side checks and padding (``validate``, pad, ``device_put``), and
  the jitted program alone on an already padded instance;
* the hot path without host checks: ``plan(check=False)`` on an instance already on the
  device (shapes checked from metadata, padding inside the program);
* the program with the jit cache keyed the way it was before 2026-12-03 (the model's graph
  definition hashed on every call);
* the same model without the route improvement after each insertion (``refine``), and
  without the 2-opt;
* the inference options that plan several candidates (best of 4 + fill, multi-start over
  the top 8 first sets + fill, multi-start over every first set + fill);
* every row again with ``jnp.argmin``/``jnp.argmax`` in place of :mod:`bfsop_jax.ops`'
  (what the planner used before 2026-12-03; XLA:CPU's variadic arg-reductions are slow).

Prints a Markdown table (medians over instances, milliseconds) and the reward of each
variant, so a speed-up that changed the plans would show; then batched planning:
instances/s of one ``plan`` call on ``--batch`` instances (the posed ones, cycled), with
and without the host checks.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import machine, time_calls
from bfsop_jax import ops
from bfsop_jax import policy as policy_module
from bfsop_jax.config import EVAL_SEED_START, PRESET_NAMES
from bfsop_jax.data.generate import DataConfig, pose_tasks
from bfsop_jax.policy import StrategicPolicy

# the multi-candidate options timed (StrategicPolicy.plan keyword arguments)
MULTI = {
    "best of 4 + fill": {"best_of": 4, "fill": True},
    "multi-start (top 8) + fill": {"multi_start": 8, "fill": True},
    "multi-start (all) + fill": {"multi_start": True, "fill": True},
}


def _median_ms(fn, items) -> float:
    jax.block_until_ready(fn(items[0]))  # compile
    times = []
    for item in items:
        t0 = time.perf_counter()
        jax.block_until_ready(fn(item))
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _program(policy: StrategicPolicy, static_graph, two_opt: bool = True):
    """The jitted plan program alone, on a padded instance (``static_graph``: its cache key)."""

    def run(padded):
        return policy_module._plan_jit(
            policy._params, padded, policy_module._default_key(), np.float32(1.0),
            graphdef=static_graph(), use_two_opt=two_opt, augment=False, best_of=1,
            fill=False, multi_start=0, single=True,
        ).reward  # fmt: skip

    return run


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_policy`` (options: docs/cli.md)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="demo", help="shipped model name or run directory")
    ap.add_argument(
        "--preset", default="demo", choices=PRESET_NAMES, help="preset of the posed tasks"
    )
    ap.add_argument(
        "--houses", type=positive_int, default=2, help="held-out houses to pose tasks in"
    )
    ap.add_argument("--tasks", type=positive_int, default=24, help="tasks per house")
    ap.add_argument(
        "--batch", type=positive_int, default=1024, help="instances of the batched plan"
    )
    return ap


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)

    cfg = DataConfig(preset=args.preset, tasks_per_house=args.tasks)
    seeds = np.arange(EVAL_SEED_START, EVAL_SEED_START + args.houses)
    instances, _ = pose_tasks(seeds, cfg, progress=False)
    items = [
        jax.tree_util.tree_map(lambda x, i=i: np.asarray(x)[i], instances)
        for i in range(int(instances.set_id.shape[0]))
    ]
    policy = StrategicPolicy.load(args.model)
    model = StrategicPolicy.load(args.model).model  # a copy whose config drops refine
    model.config = dataclasses.replace(model.config, refine=False)
    unrefined = StrategicPolicy(model, policy.num_nodes, policy.num_sets)

    padded = {id(x): policy._prepare(x)[0] for x in items}
    on_device = {id(x): jax.device_put(x) for x in items}
    once = policy._static_graph
    program = _program(policy, lambda: once)
    program_rehashed = _program(policy, lambda: policy_module._HashedOnce(policy._graphdef))
    rows = [
        ("plan (as called)", lambda x: policy.plan(x).reward),
        ("  host: validate, pad, device_put", lambda x: policy._prepare(x)[0]),
        ("  jitted program", lambda x: program(padded[id(x)])),
        ("  jitted program, graph hashed per call (before)",
         lambda x: program_rehashed(padded[id(x)])),
        ("plan(check=False), instance on the device",
         lambda x: policy.plan(on_device[id(x)], check=False).reward),
        ("plan without the 2-opt", lambda x: policy.plan(x, two_opt=False).reward),
        ("plan without refine", lambda x: unrefined.plan(x).reward),
    ] + [
        (f"plan + {name}", lambda x, o=options: policy.plan(x, **o).reward)
        for name, options in MULTI.items()
    ]  # fmt: skip
    now = [_median_ms(fn, items) for _, fn in rows]
    rewards = {name: sum(float(policy.plan(x, **o).reward) for x in items)
               for name, o in MULTI.items()}  # fmt: skip
    reward = sum(float(policy.plan(x).reward) for x in items)
    reward_plain = sum(float(unrefined.plan(x).reward) for x in items)
    # the same rows traced again with jnp's arg-reductions (new programs: caches cleared)
    fast = ops.argmin, ops.argmax
    ops.argmin, ops.argmax = jnp.argmin, jnp.argmax
    jax.clear_caches()
    try:
        before = [_median_ms(fn, items) for _, fn in rows]
        same = sum(float(policy.plan(x).reward) for x in items) == reward
    finally:
        ops.argmin, ops.argmax = fast
        jax.clear_caches()
    batched = _batched(policy, items, args.batch)
    config = policy.config
    print(f"{len(items)} instances from held-out {args.preset} houses {seeds[0]}..{seeds[-1]}; "
          f"model {args.model} ({config.decoder} decoder, refine={config.refine})")  # fmt: skip
    print(f"{machine()}, {time.strftime('%Y-%m-%d')}")
    print("\n| step | median ms / instance | with jnp.argmin/argmax | ratio |\n|---|---|---|---|")
    for (name, _), ms, old in zip(rows, now, before, strict=True):
        print(f"| {name} | {ms:.2f} | {old:.2f} | {old / ms:.2f}x |")
    print(f"\nsummed reward: with refine {reward:.2f}, without {reward_plain:.2f}; "
          + ", ".join(f"{name} {r:.2f}" for name, r in rewards.items())
          + f"; same plans with jnp's arg-reductions: {same}")  # fmt: skip
    print(f"\nbatched plan (greedy + 2-opt), {args.batch} instances in one call: "
          + ", ".join(f"{name} {ms:.1f} ms = {args.batch / ms * 1e3:,.0f} instances/s"
                      for name, ms in batched.items()))  # fmt: skip


def _batched(policy: StrategicPolicy, items: list, size: int) -> dict[str, float]:
    """Median ms of one ``plan`` call on ``size`` instances (``items`` cycled), checked
    on the host and unchecked on the device."""
    rows = [items[i % len(items)] for i in range(size)]
    batch = jax.tree_util.tree_map(lambda *x: np.stack(x), *rows)
    device = jax.device_put(batch)
    timed = {
        "checked (NumPy batch)": lambda: policy.plan(batch).reward,
        "check=False (batch on the device)": lambda: policy.plan(device, check=False).reward,
    }
    return {name: 1e3 * time_calls(fn, repeats=3).median for name, fn in timed.items()}


if __name__ == "__main__":
    run_main(main)
