"""Ray-cast occupancy map updates per second (batched, jitted).

Usage: ``python -m benchmarks.bench_mapping --preset demo --batch 64 --repeats 20``

Maps are random rectangles (the figure does not depend on the layout much: every ray samples
its full length, the hit only changes which samples count as free). Reported figures:

- ``updates_per_s``: one jitted ``vmap(update_belief)`` call per batch, belief not donated
  (the call writes a fresh copy of every belief, a full-map memory pass);
- ``updates_per_s_donated``: the same with the belief buffer donated (updated in place);
- ``updates_per_s_in_scan``: ``preset.micro_steps`` consecutive scans per call inside a
  ``lax.scan``, the way an environment step senses after every motion step (beliefs are
  updated in place);
- ``stage_ms``: cumulative cost of the stages of one batched update, to show where the time
  goes (ray samples -> first hit -> scatter of the scan window -> belief window update).
"""

from __future__ import annotations

import argparse
import functools

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.cli import positive_int, run_main
from benchmarks.timing import time_calls
from bfsop_jax.config import PRESET_NAMES, Preset, get_preset
from bfsop_jax.sensing import mapping


def random_batch(preset: Preset, batch: int, seed: int = 0):
    """Random rectangle maps [B, H, W], zero beliefs and free-cell poses [B, 3]."""
    rng = np.random.default_rng(seed)
    h, w = preset.grid_shape
    occ = np.zeros((batch, h, w), bool)
    for b in range(batch):
        occ[b, :2], occ[b, -2:], occ[b, :, :2], occ[b, :, -2:] = True, True, True, True
        for _ in range(h * w // 2000):
            rh, rw = rng.integers(2, 20, 2)
            r, c = rng.integers(0, h - rh), rng.integers(0, w - rw)
            occ[b, r : r + rh, c : c + rw] = True
    poses = np.zeros((batch, 3), np.float32)
    for b in range(batch):
        i, j = np.argwhere(~occ[b])[rng.integers((~occ[b]).sum())]
        poses[b] = ((j + 0.5) * preset.cell_size, (i + 0.5) * preset.cell_size, rng.uniform(-3, 3))
    return jnp.asarray(occ), jnp.zeros((batch, h, w), jnp.float32), jnp.asarray(poses)


def _time(fn, args, repeats: int) -> tuple[float, float]:
    """(compile + first call seconds, best seconds per call over ``repeats`` rounds of 5)."""
    t = time_calls(fn, *args, repeats=repeats, inner=5)
    return t.first_s, t.best


def run(preset_name: str = "demo", batch: int = 64, repeats: int = 10) -> dict:
    """Time batched map updates; returns a dict of figures (seconds, updates per second)."""
    preset = get_preset(preset_name)
    occ, belief, poses = random_batch(preset, batch)
    update = jax.vmap(functools.partial(mapping.update_belief, preset=preset))

    single = jax.jit(update)
    compile_s, per_call = _time(single, (belief, occ, poses), repeats)

    donated = jax.jit(update, donate_argnums=0)
    state = {"belief": belief + 0.0}

    def donated_call(o, p):
        state["belief"] = donated(state["belief"], o, p)
        return state["belief"]

    _, per_donated = _time(donated_call, (occ, poses), repeats)

    steps = preset.micro_steps
    rng = np.random.default_rng(1)
    jitter = rng.normal(0, 0.05, (steps, batch, 3)).astype(np.float32)
    trajectory = poses[None] + jnp.asarray(jitter)

    @jax.jit
    def rollout(b, o, traj):
        return jax.lax.scan(lambda bb, p: (update(bb, o, p), None), b, traj)[0]

    _, per_rollout = _time(rollout, (belief, occ, trajectory), repeats)

    # Cumulative stages: each jitted function runs the previous stages plus one more.
    def samples(o, p):
        return mapping._sample_cells(p, preset)[:2]

    def first_hit(o, p):
        return mapping._scan_samples(o, p, preset)[3]

    def window(o, p):
        return mapping._scan_window(o, p, preset)[0]

    stage_ms = {}
    for name, fn in (("ray_samples", samples), ("first_hit", first_hit), ("scatter", window)):
        stage_ms[name] = 1e3 * _time(jax.jit(jax.vmap(fn)), (occ, poses), repeats)[1]
    stage_ms["belief_update"] = 1e3 * per_call
    stage_ms["belief_update_donated"] = 1e3 * per_donated
    stage_ms["belief_update_in_scan"] = 1e3 * per_rollout / steps
    return {
        "preset": preset.name,
        "batch": batch,
        "grid": preset.grid_shape,
        "rays_x_samples": (preset.n_rays, mapping._n_steps(preset) + 1),
        "compile_s": compile_s,
        "updates_per_s": batch / per_call,
        "updates_per_s_donated": batch / per_donated,
        "updates_per_s_in_scan": batch * steps / per_rollout,
        "stage_ms": stage_ms,
        "device": str(jax.devices()[0]),
    }


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.bench_mapping`` (options: docs/cli.md)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="demo", choices=PRESET_NAMES)
    parser.add_argument("--batch", type=positive_int, default=64)
    parser.add_argument("--repeats", type=positive_int, default=10)
    return parser


def main() -> None:
    args = build_parser().parse_args()
    res = run(args.preset, args.batch, args.repeats)
    print(
        f"{res['preset']} grid {res['grid']} batch {res['batch']} on {res['device']}: "
        f"compile {res['compile_s']:.2f} s"
    )
    print(f"  map updates/s, one call per batch : {res['updates_per_s']:10.0f}")
    print(f"  map updates/s, belief donated     : {res['updates_per_s_donated']:10.0f}")
    print(f"  map updates/s, lax.scan rollout   : {res['updates_per_s_in_scan']:10.0f}")
    print("  cumulative stage time per batch (ms):")
    for name, ms in res["stage_ms"].items():
        print(f"    {name:24s} {ms:8.3f}")


if __name__ == "__main__":
    run_main(main)
