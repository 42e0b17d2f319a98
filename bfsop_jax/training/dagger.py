"""DAgger (docs/design.md §8.3): the student plans its own episodes, the teacher labels them.

Behaviour cloning trains on the states the *teacher's* behaviour visits; once the student
plans the tours itself, its episodes reach maps, positions and remaining budgets the data
never showed. A DAgger round closes that gap:

1. the current student plans the tours of BF-SOP episodes in training houses
   (:func:`bfsop_jax.data.generate.student_records`: several target categories per house,
   new start poses every round);
2. the VNS teacher labels every instance the student planned on its own online map;
3. training continues, from the student's weights, on the aggregate: the behaviour-cloning
   data plus the rows of every round so far.

Layout of ``out_dir``::

    round-01/data/   the round's labelled rows (a ShardStore: resumable, cache-checked)
    round-01/run/    the round's training run (StrategicPolicy.load-able)
    ...
    dagger.json      per-round figures (rows, seconds, the caller's evaluation)

Every step is resumable: a round whose data is complete is not relabelled, a round whose
model exists is not retrained.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from bfsop_jax import checkpoint as ckpt
from bfsop_jax.config import get_preset
from bfsop_jax.data.generate import DataConfig, prior_digest, student_records
from bfsop_jax.data.shards import ShardStore
from bfsop_jax.files import write_json
from bfsop_jax.training.config import RunConfig

__all__ = ["DaggerConfig", "run_dagger"]


@dataclasses.dataclass(frozen=True)
class DaggerConfig:
    """How many DAgger rounds, and how much the student drives in each."""

    rounds: int = 3
    houses_per_round: int = 20  # training houses driven in per round (a rotating window)
    categories_per_house: int = 3  # episodes per training house and round
    epochs: int = 10  # training epochs per round, from the previous round's weights
    lr: float | None = None  # learning rate of the rounds (None: the base run's last one)

    def __post_init__(self) -> None:
        for name in ("rounds", "houses_per_round", "categories_per_house", "epochs"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"DaggerConfig.{name} must be a positive int, got {value!r}")
        if self.lr is not None and not self.lr > 0:
            raise ValueError(f"DaggerConfig.lr must be positive, got {self.lr}")


def _concat(parts: list[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    keys = parts[0].keys()
    return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in keys}


def _last_lr(run_dir: Path, config: dict[str, Any]) -> float:
    """The learning rate the run ended with (its last metrics row), else its base rate."""
    best = config.get("result", {}).get("best_replica", 0)
    path = run_dir / "metrics.jsonl"
    if path.is_file():
        rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
        rows = [r for r in rows if r.get("replica", 0) == best and "lr" in r]
        if rows:
            return float(rows[-1]["lr"])
    return float(config.get("result", {}).get("lr", config["replicas"][0]["lr"]))


def _check_round(
    run_dir: Path, run_config: RunConfig, lr: float, warm: dict[str, Any], rows: int
) -> None:
    """ValueError unless the finished round in ``run_dir`` was trained as this call would
    train it (recipe and epochs, learning rate, warm start, training rows)."""
    old = ckpt.read_config(run_dir)
    dataset = old.get("dataset", {})
    differ = ckpt.differing({
        "recipe or epochs": (old.get("run"), run_config.to_dict()),
        "learning rate": ([r.get("lr") for r in old.get("replicas", [])], [float(lr)]),
        "warm start": (dataset.get("meta"), warm),
        "training rows": (dataset.get("train", {}).get("instances"), rows),
    })  # fmt: skip
    if differ:
        raise ValueError(
            f"{run_dir} holds a DAgger round trained otherwise (its {', '.join(differ)} "
            "differ); pass another --out"
        )


def run_dagger(
    base_run: str | Path,
    train_ds: Mapping[str, np.ndarray],
    val_ds: Mapping[str, np.ndarray] | None,
    house_seeds: np.ndarray,
    data_config: DataConfig,
    out_dir: str | Path,
    dagger: DaggerConfig = DaggerConfig(),
    evaluate: Callable[[Any, int], dict[str, Any]] | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Run (or resume) DAgger rounds from the trained run ``base_run``.

    Args:
        base_run: the behaviour-cloning run directory (round 0's student).
        train_ds, val_ds: its training and validation records; the DAgger rows are added
            to the training side only (validation stays the teacher's distribution).
        house_seeds: [H] training house seeds the student may drive in (never evaluation
            houses; the validation houses are best left out too). Round r takes the next
            ``dagger.houses_per_round`` of them (wrapping around), so rounds see new houses.
        data_config: labels the rows (``vns_config``) and names the preset.
        out_dir: where rounds and ``dagger.json`` go.
        dagger: rounds, episodes and epochs.
        evaluate: ``evaluate(policy, round) -> dict`` of figures to record per round (round
            0 is the base model), e.g. reward ratio on held-out instances and PPL.
        progress: progress bars while training.

    Returns:
        One dict per round 0..R: ``round``, ``rows`` (DAgger rows added that round),
        ``aggregate`` (training rows), ``seconds`` per stage and the evaluation's figures.
    """
    from bfsop_jax.agents import TransformerPlanner
    from bfsop_jax.policy import StrategicPolicy
    from bfsop_jax.training.bc import train
    from bfsop_jax.world.prior import default_prior

    seeds = np.asarray(house_seeds, np.int64).ravel()
    if seeds.size == 0:
        raise ValueError("run_dagger needs at least one training house seed")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    preset = get_preset(data_config.preset)
    prior = jnp.asarray(default_prior())
    base_config = ckpt.read_config(Path(base_run))
    run_config = RunConfig.from_dict(base_config["run"])
    lr = dagger.lr if dagger.lr is not None else _last_lr(Path(base_run), base_config)
    run_config = dataclasses.replace(
        run_config, train=dataclasses.replace(run_config.train, epochs=dagger.epochs)
    )
    history_path = out / "dagger.json"
    history: list[dict[str, Any]] = []

    policy = StrategicPolicy.load(base_run)
    row0: dict[str, Any] = {"round": 0, "run_dir": str(base_run), "rows": 0,
                            "aggregate": int(len(train_ds["set_id"]))}  # fmt: skip
    if evaluate is not None:
        row0.update(evaluate(policy, 0))
    history.append(row0)
    write_json(history_path, history)

    parts = [dict(train_ds)]
    previous = Path(base_run)
    for r in range(1, dagger.rounds + 1):
        round_dir = out / f"round-{r:02d}"
        row: dict[str, Any] = {"round": r}
        h = min(dagger.houses_per_round, seeds.size)
        mine = seeds[(np.arange(h) + (r - 1) * h) % seeds.size]
        store = ShardStore(
            round_dir / "data",
            {"dagger_round": r, "student": str(previous), "student_model": policy.fingerprint,
             "prior": prior_digest(prior), "house_seeds": mine.tolist(),
             "categories_per_house": dagger.categories_per_house,
             "data_config": dataclasses.asdict(data_config)},
        )  # fmt: skip
        timings: dict[str, float] = {}
        if not store.is_complete(0):
            planner = TransformerPlanner(policy)
            records = student_records(
                mine, planner, preset, data_config, prior, episode_salt=r,
                categories_per_house=dagger.categories_per_house, timings=timings,
            )  # fmt: skip
            store.write(0, records, {"house_seeds": mine.tolist()})
        rows = store.load()
        parts.append(rows)
        aggregate = _concat(parts)
        row.update(rows=int(len(rows["set_id"])), aggregate=int(len(aggregate["set_id"])))
        run_dir = round_dir / "run"
        t0 = time.perf_counter()
        warm = {"dagger_round": r, "warm_start": str(previous), "warm_model": policy.fingerprint}
        if not (run_dir / ckpt.MODEL_DIR).is_dir():
            resume = (run_dir / "checkpoints").exists()
            train(
                run_config, aggregate, val_ds, run_dir, seeds=(0,), lrs=(lr,), resume=resume,
                progress=progress, init_params=policy.params, dataset_meta=warm,
            )  # fmt: skip
        else:
            _check_round(run_dir, run_config, lr, warm, int(len(aggregate["set_id"])))
        timings["training"] = time.perf_counter() - t0
        row["seconds"] = {k: round(v, 1) for k, v in timings.items()}
        row["run_dir"] = str(run_dir)
        policy = StrategicPolicy.load(run_dir)
        previous = run_dir
        if evaluate is not None:
            row.update(evaluate(policy, r))
        history.append(row)
        write_json(history_path, history)
        print(json.dumps(row))
    return history
