"""Solver evaluation (Tables II/III, decoder distance mass) and the distill pipeline."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from flax import nnx

from bfsop_jax.config import EVAL_SEED_START, get_preset
from bfsop_jax.data.generate import SOURCE_STUDENT, DataConfig, pose_tasks
from bfsop_jax.data.shards import ShardStore
from bfsop_jax.eval import solvers as solver_eval
from bfsop_jax.model import ModelConfig, StrategicTransformer
from bfsop_jax.policy import StrategicPolicy
from bfsop_jax.sop import evaluate, solve_vns
from bfsop_jax.sop.io import random_instance
from bfsop_jax.viz import plot_distance_mass, plot_model_comparison, plot_tour_comparison


@pytest.fixture(scope="module")
def policy() -> StrategicPolicy:
    model = StrategicTransformer(
        ModelConfig(d_model=32, n_layers=1, n_heads=2, d_ff=64), rngs=nnx.Rngs(0)
    )
    kernel = model.decoder.project_glimpse.kernel  # zero at init: make the scores non-uniform
    kernel[...] = jax.random.normal(jax.random.key(1), kernel.shape) / np.sqrt(kernel.shape[0])
    return StrategicPolicy(model, num_nodes=31, num_sets=11)


@pytest.fixture(scope="module")
def batch():
    insts = [random_instance(s, num_sets=8, viewpoints=3, masked_sets=s % 2) for s in range(6)]
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *insts)


def test_evaluate_solvers_reports_every_planner(policy, batch, tmp_path):
    planners = {"transformer": {"two_opt": False}, "transformer+2opt": {"two_opt": True}}
    evaluation = solver_eval.evaluate_solvers(
        policy, batch, vns_kwargs={"max_iters": 100, "max_no_improve": 50},
        planners=planners, batch_size=4, repeats=1, progress=False,
    )  # fmt: skip
    result = evaluation.summary
    assert result["instances"] == 6
    p = result["planners"]
    assert set(p) == {"vns", "greedy_insertion", *planners}
    vns = [solve_vns(solver_eval.take(batch, i), max_iters=100, max_no_improve=50)
           for i in range(6)]  # fmt: skip
    assert p["vns"]["mean_reward"] == pytest.approx(np.mean([float(s.reward) for s in vns]))
    for name in planners:
        row = p[name]
        assert row["reward_ratio"] == pytest.approx(row["mean_reward"] / p["vns"]["mean_reward"])
        assert row["latency_ms_single"] > 0 and row["plans_per_s_batched"] > 0
        assert row["batch_size"] == 4
        # the recorded plans are feasible and give the reported means
        rewards = []
        for i, nodes in enumerate(evaluation.plans[name]):
            r, c, ok = evaluate(solver_eval.take(batch, i), nodes[nodes >= 0])
            assert ok
            rewards.append(r)
        assert np.mean(rewards) == pytest.approx(row["mean_reward"], rel=1e-5)
    two = result["two_opt"]
    assert two["cost_change_pct"] == pytest.approx(
        100 * (p["transformer+2opt"]["mean_cost"] / p["transformer"]["mean_cost"] - 1)
    )

    solver_eval.write_json(result, tmp_path / "solver_eval.json")
    saved = json.loads((tmp_path / "solver_eval.json").read_text())
    assert saved == json.loads(json.dumps(result)) and saved["planners"]["vns"]["mean_reward"] > 0
    assert len(evaluation.teacher[0]) == 6  # the VNS plans, reusable by other models
    text = solver_eval.write_tables(result, tmp_path / "tables.md")
    assert "Table II" in text and "Table III" in text and "VNS teacher" in text
    assert (tmp_path / "tables.md").read_text() == text

    # per-instance rewards: paired differences against greedy insertion, and the
    # side-by-side table of several models
    row = p["transformer+2opt"]
    assert len(row["rewards"]) == 6 and np.mean(row["rewards"]) == pytest.approx(
        row["mean_reward"], rel=1e-5
    )
    d, lo, hi = solver_eval.paired_vs(result, "transformer+2opt")
    expect = (np.asarray(row["rewards"]) - np.asarray(p["greedy_insertion"]["rewards"])).mean()
    assert d == pytest.approx(expect / p["vns"]["mean_reward"], abs=1e-6)
    assert lo <= d <= hi
    table = solver_eval.compare_table({"a": p, "b": p}, planners)
    assert table.count("| a | transformer") == 2 and table.count("| b | transformer") == 2
    assert f"{row['reward_ratio']:.3f} | {d:+.3f} [{lo:+.3f}, {hi:+.3f}]" in table
    fig = plot_model_comparison({"a": p, "b": p}, tmp_path / "compare.png", latency_budget_ms=5.0)
    ax = fig.axes[0]
    drawn = [line for line in ax.get_lines() if line.get_label() in ("a", "b")]
    n_shown = len([k for k in p if k not in ("vns", "greedy_insertion")])
    assert [len(line.get_xdata()) for line in drawn] == [n_shown, n_shown]
    np.testing.assert_allclose(  # ratios to the VNS, in order of latency
        sorted(zip(drawn[0].get_xdata(), drawn[0].get_ydata(), strict=True))[0][1],
        min((r["latency_ms_single"], r["reward_ratio"]) for k, r in p.items()
            if k not in ("vns", "greedy_insertion"))[1], rtol=1e-6)  # fmt: skip
    assert (tmp_path / "compare.png").stat().st_size > 0


def test_pooled_evaluations_equal_one_evaluation_of_all_houses(
    policy, batch, tmp_path, monkeypatch
):
    """Two runs on disjoint house ranges pool into the summary one run of both would give
    (means, ratios, paired intervals over instances and over houses); the houses of a run
    that did not record them are recovered by re-posing its tasks, and checked; mismatched
    runs are refused."""
    from experiments import distill, pool_eval

    planners = {"transformer+2opt": {"two_opt": True}}
    kw = dict(vns_kwargs={"max_iters": 50, "max_no_improve": 20}, planners=planners,
              batch_size=2, repeats=1, progress=False)  # fmt: skip
    houses = [10, 10, 11, 12, 13, 13]  # two instances in houses 10 and 13 (the runs' 0..3, 4..5)
    whole = {**solver_eval.evaluate_solvers(policy, batch, **kw).summary, "instance_houses": houses}
    parts = []
    for i, (lo, hi) in enumerate([(0, 4), (4, 6)]):
        part = solver_eval.evaluate_solvers(policy, solver_eval.take(batch, slice(lo, hi)), **kw)
        summary = {**part.summary, "house_seeds": [lo, hi], "checkpoint": "m", "preset": "demo"}
        if i == 0:
            summary["instance_houses"] = houses[lo:hi]
        (tmp_path / f"run{i}").mkdir()
        solver_eval.write_json(summary, tmp_path / f"run{i}" / "solver_eval.json")
        parts.append(summary)
    args = [str(tmp_path / "run0"), str(tmp_path / "run1"), "--out", str(tmp_path / "pooled")]
    pooled = pool_eval.main(args)  # run1 has no houses: intervals over instances only
    assert (
        "instance_houses" not in pooled
        and "CI over houses" not in (tmp_path / "pooled" / "tables.md").read_text()
    )

    def repose(preset, lo, hi, tasks, progress=True):  # stands in for the exploration runs
        assert (preset, lo, hi, tasks) == (distill.PRESETS["demo"], 4, 6, 24)
        return solver_eval.take(batch, slice(4, 6)), np.asarray(houses[4:6])

    monkeypatch.setattr(distill, "eval_instances", repose)
    pooled = pool_eval.main([*args, "--recover-houses", "--no-progress"])
    saved = json.loads((tmp_path / "run1" / "solver_eval.json").read_text())
    assert saved["instance_houses"] == houses[4:6]  # recorded in the run for next time
    assert pooled["instance_houses"] == houses
    by_house = solver_eval.paired_vs(pooled, "transformer+2opt", by_house=True)
    assert by_house == pytest.approx(
        solver_eval.paired_vs(whole, "transformer+2opt", by_house=True), abs=1e-6
    )
    assert "CI over houses" in (tmp_path / "pooled" / "tables.md").read_text()
    other_tasks = (solver_eval.take(batch, slice(0, 2)), np.zeros(2))  # greedy differs there
    monkeypatch.setattr(distill, "eval_instances", lambda *a, **k: other_tasks)
    with pytest.raises(ValueError, match="greedy insertion differs"):
        pool_eval.recover_houses(parts[1], progress=False)
    with pytest.raises(ValueError, match="cannot resample houses"):
        solver_eval.paired_vs(parts[1], "transformer+2opt", by_house=True)
    assert pooled["instances"] == 6 and pooled["house_seeds"] == [[0, 4], [4, 6]]
    for name in ("vns", "greedy_insertion", "transformer+2opt"):
        a, b = pooled["planners"][name], whole["planners"][name]
        assert a["rewards"] == pytest.approx(b["rewards"], abs=1e-6)
        assert a["mean_cost"] == pytest.approx(b["mean_cost"], rel=1e-5)
    assert pooled["planners"]["transformer+2opt"]["reward_ratio"] == pytest.approx(
        whole["planners"]["transformer+2opt"]["reward_ratio"], rel=1e-5
    )
    d, lo, hi = solver_eval.paired_vs(pooled, "transformer+2opt")
    assert (d, lo, hi) == pytest.approx(solver_eval.paired_vs(whole, "transformer+2opt"), abs=1e-6)
    text = (tmp_path / "pooled" / "tables.md").read_text()
    assert "6 held-out instances of houses 0..3, 4..5" in text and f"{d:+.3f}" in text
    assert (tmp_path / "pooled" / "paired.png").stat().st_size > 0  # runs and pool, drawn
    # a pool pools again: the pooled summary of run0 + run1 with a third range
    third = {**parts[1], "house_seeds": [6, 8], "instance_houses": houses[4:6]}
    again = solver_eval.pool_summaries([pooled, third])
    assert again["house_seeds"] == [[0, 4], [4, 6], [6, 8]] and again["instances"] == 8
    other_options = {"options": {"two_opt": False}}
    for bad, match in [
        ([parts[0], parts[0]], "overlapping house ranges"),
        ([pooled, parts[1]], "overlapping house ranges"),
        ([parts[0], {**parts[1], "checkpoint": "other"}], "different checkpoints"),
        ([parts[0], {**parts[1], "preset": "paper"}], "different presets"),
        ([{**parts[0], "tasks_per_house": 24}, {**parts[1], "tasks_per_house": 2}],
         "different tasks_per_houses"),
        ([parts[0], {**parts[1], "planners": {**parts[1]["planners"], "transformer+2opt": {
            **parts[1]["planners"]["transformer+2opt"], **other_options}}}],
         "'transformer\\+2opt' ran with different options"),
        ([parts[0], {**parts[1], "house_seeds": "4:6"}], "house_seeds must be"),
    ]:  # fmt: skip
        with pytest.raises(ValueError, match=match):
            solver_eval.pool_summaries(bad)
    for broken, match in [
        ({**parts[1], "preset": "huge"}, "unknown preset 'huge'"),
        ({k: v for k, v in parts[1].items() if k != "house_seeds"}, "house_seeds must be one"),
        ({**parts[1], "planners": {}}, "no per-instance greedy insertion rewards"),
    ]:
        with pytest.raises(ValueError, match=match):
            pool_eval.recover_houses(broken, progress=False)
    one = solver_eval.take(batch, slice(0, 1))
    with pytest.raises(ValueError, match="the teacher has 1 plans and 1 latencies for 2"):
        solver_eval.evaluate_solvers(policy, solver_eval.take(batch, slice(0, 2)),
                                     teacher=solver_eval.evaluate_teacher(one, progress=False,
                                     vns_kwargs=kw["vns_kwargs"]), **kw)  # fmt: skip
    with pytest.raises(SystemExit):
        pool_eval.main([str(tmp_path), "--out", str(tmp_path / "x")])  # no solver_eval.json


def test_extra_data_never_trains_on_validation_houses():
    """An extra dataset of the same preset whose training houses are the main data's
    validation houses (or whose validation houses the main data trains on) is refused."""
    from experiments.distill import _refuse_shared_houses

    rows = lambda *seeds: {"house_seed": np.asarray(seeds)}
    train, val = [rows(0, 0, 1)], [rows(2, 2)]
    _refuse_shared_houses("d", train, val, rows(0, 1), rows(3))  # the same split: fine
    with pytest.raises(ValueError, match=r"--extra-data d: houses \[2\] train on one side"):
        _refuse_shared_houses("d", train, val, rows(0, 2), rows(3))
    with pytest.raises(ValueError, match=r"houses \[1\]"):
        _refuse_shared_houses("d", train, val, rows(0), rows(1))
    _refuse_shared_houses("d", train, [None], rows(2), rows(3))  # no validation split


def test_decoder_distance_mass_is_a_distribution(policy, batch, tmp_path):
    mass = solver_eval.decoder_distance_mass(policy, batch, batch=4)
    assert mass.shape == (2, 5)
    # the current node is the node chosen at the step before; for this (append) decoder
    # that is the plan's previous node
    trace = jax.device_get(policy.trace(batch))
    nodes, choices = np.asarray(trace.solution.nodes), np.asarray(trace.choices)
    t = min(nodes.shape[1] - 1, choices.shape[1])
    real = nodes[:, 1 : t + 1] >= 0
    np.testing.assert_array_equal(nodes[:, 1 : t + 1][real], choices[:, :t][real])
    np.testing.assert_allclose(mass.sum(axis=1), 1.0, atol=1e-5)
    assert (mass >= 0).all()
    plot_distance_mass(mass, tmp_path / "mass.png")
    assert (tmp_path / "mass.png").stat().st_size > 0


@pytest.fixture(scope="module")
def held_out():
    """Tasks posed on two held-out smoke houses, with the maps they were posed on."""
    cfg = DataConfig(preset="smoke", houses=1, tasks_per_house=5)
    seeds = [EVAL_SEED_START, EVAL_SEED_START + 1]
    return cfg, seeds, pose_tasks(seeds, cfg, progress=False, maps=True)


def test_pose_tasks_on_held_out_houses(held_out):
    cfg, seeds, (insts, owners, maps) = held_out
    assert insts.set_id.shape[0] == owners.shape[0] > 0
    assert set(owners.tolist()) <= set(seeds)
    assert (np.asarray(insts.set_reward) > 0).any(axis=1).all()  # nothing trivial kept
    # the map of each house: int8 cell states of the run's final belief, partly explored
    assert sorted(maps) == seeds
    for house_map in maps.values():
        assert house_map.dtype == np.int8 and house_map.shape == get_preset("smoke").grid_shape
        assert set(np.unique(house_map).tolist()) == {-1, 0, 1}
    with pytest.raises(ValueError, match="at least one house"):
        pose_tasks([], cfg)


def test_tour_figure_draws_the_tours_over_their_map(held_out, tmp_path):
    """``tour_figure`` (the distill evaluation's tour comparison): both plans over the map
    their instance was posed on, along shortest paths on it; a PNG with the same rewards
    and costs as ``evaluate``."""
    from PIL import Image

    from bfsop_jax.eval.distill import tour_figure
    from bfsop_jax.sop import solve_greedy

    _, _, (insts, owners, maps) = held_out
    i = int(np.argmax((np.asarray(insts.set_id) >= 0).sum(axis=1)))
    inst = solver_eval.take(insts, i)
    greedy = solve_greedy(inst).node_list()
    plans = {"greedy": greedy, "first set only": greedy[:2]}
    assert len(greedy) > 1
    path = tmp_path / "tours.png"
    scored = tour_figure(inst, plans, maps[int(owners[i])], "smoke", path)
    for name, nodes in plans.items():
        reward, cost, _ = evaluate(inst, nodes)
        assert scored[name] == (nodes, pytest.approx(float(reward)), pytest.approx(float(cost)))
    with Image.open(path) as img:
        assert img.format == "PNG" and img.size[0] > img.size[1] > 200
    # without a map: straight legs on white, still a figure
    tour_figure(inst, plans, None, "smoke", tmp_path / "plain.png")
    assert (tmp_path / "plain.png").stat().st_size > 0
    with pytest.raises(ValueError, match="cell_size"):
        plot_tour_comparison(inst, {"greedy": scored["greedy"]}, tmp_path / "x.png",
                             belief=maps[int(owners[i])])  # fmt: skip


@pytest.mark.slow
def test_distill_end_to_end_and_eval_rerun(tmp_path, smoke_data_dir):
    """The smoke preset: data (the session's cached dataset) -> train -> eval, then the eval
    stage alone on other seeds."""
    from experiments import distill

    run, data = tmp_path / "run", smoke_data_dir
    summary = distill.main(
        ["--preset", "smoke", "--out", str(run), "--data-dir", str(data), "--no-progress"]
    )
    for name in ("tables.md", "solver_eval.json", "tour_comparison.png",
                 "decoder_distance_mass.png", "training_curve.png", "metrics.csv"):  # fmt: skip
        assert (run / name).is_file(), name
    ev = json.loads((run / "solver_eval.json").read_text())
    assert ev["instances"] > 0 and ev["planners"]["transformer+2opt"]["speedup"] > 0
    assert len(ev["instance_houses"]) == ev["instances"]  # intervals over houses possible
    assert set(ev["instance_houses"]) <= set(range(*ev["house_seeds"]))
    assert summary["solver_eval"]["instances"] == ev["instances"]
    # the run ends with the navigation evaluation (reduced Table I protocol)
    assert (run / "navigation" / "results.json").is_file()
    assert "Table I: navigation, reduced protocol" in (run / "tables.md").read_text()
    assert set(summary["solver_eval"]["navigation"]["methods"]) == {"fbe"}
    assert set(ev["navigation"]["methods"]) == {"fbe"}  # solver_eval.json records it too
    # the trained model is kept only for the same training: another rate is refused
    with pytest.raises(ValueError, match="trained otherwise .its seeds or learning rates"):
        distill.main(["--preset", "smoke", "--stage", "train", "--out", str(run), "--data-dir",
                      str(data), "--lr", "0.5", "--no-progress"])  # fmt: skip
    # cached data: a second data stage generates nothing new
    meta = (data / "meta.json").read_text()
    distill.main(["--preset", "smoke", "--stage", "data", "--data-dir", str(data), "--no-progress"])
    assert (data / "meta.json").read_text() == meta
    # the evaluation alone, on other held-out houses, into another directory, with another
    # model on the same instances against the same teacher plans
    other = tmp_path / "eval2"
    seeds = f"{EVAL_SEED_START + 5}:{EVAL_SEED_START + 6}"
    distill.main(["--preset", "smoke", "--stage", "eval", "--checkpoint", str(run),
                  "--eval-seeds", seeds, "--out", str(other), "--no-progress",
                  "--no-navigation", "--compare", "demo"])  # fmt: skip
    ev3 = json.loads((other / "solver_eval.json").read_text())
    assert ev3["house_seeds"] == [EVAL_SEED_START + 5, EVAL_SEED_START + 6]
    assert (other / "tables.md").is_file()
    assert list(ev3["compare"]) == [str(run), "demo"]
    assert ev3["compare"]["demo"]["vns"] == ev3["planners"]["vns"]  # one teacher run
    assert set(ev3["compare"]["demo"]) >= set(distill.PRESETS["smoke"].compare_planners)
    assert "| demo | transformer+2opt |" in (other / "tables.md").read_text()
    assert (other / "compare.png").stat().st_size > 0  # reward against latency, both models

    # DAgger: one round in which the trained student drives and the teacher labels
    dagger = ["--preset", "smoke", "--stage", "dagger", "--out", str(run), "--data-dir",
              str(data), "--rounds", "1", "--dagger-epochs", "1", "--dagger-categories", "1",
              "--eval-tasks", "2", "--no-navigation", "--no-progress"]  # fmt: skip
    history = distill.main(dagger)["dagger"]
    assert [row["round"] for row in history] == [0, 1]
    rows = ShardStore.open(run / "dagger" / "round-01" / "data").load()
    assert len(rows["source"]) == history[1]["rows"] > 0
    assert (rows["source"] == SOURCE_STUDENT).all()
    assert (rows["house_seed"] < EVAL_SEED_START).all()  # training houses only
    assert history[1]["aggregate"] == history[0]["aggregate"] + history[1]["rows"]
    for name in ("dagger.json", "dagger.md", "dagger.png"):
        assert (run / "dagger" / name).is_file(), name
    model_dir = run / "dagger" / "round-01" / "run" / "model"
    stamp = max(f.stat().st_mtime_ns for f in model_dir.rglob("*") if f.is_file())
    again = distill.main(dagger)["dagger"]  # resumed: nothing relabelled or retrained
    assert again[1]["rows"] == history[1]["rows"]
    assert max(f.stat().st_mtime_ns for f in model_dir.rglob("*") if f.is_file()) == stamp
    longer = list(dagger)
    longer[longer.index("--dagger-epochs") + 1] = "2"
    with pytest.raises(ValueError, match="DAgger round trained otherwise .its recipe or epochs"):
        distill.main(longer)  # a finished round of 1 epoch is not reused as a 2-epoch one

    # reward fine-tuning of the trained run into run/rl, selected on the validation houses
    rows = distill.main(["--preset", "smoke", "--stage", "rl", "--out", str(run), "--data-dir",
                         str(data), "--rl-epochs", "1", "--rl-samples", "2",
                         "--no-progress"])["rl"]  # fmt: skip
    assert [r["epoch"] for r in rows] == [0, 1] and sum(r["selected"] for r in rows) == 1
    for name in ("rl.md", "rl.png", "rl_metrics.jsonl", "config.json"):
        assert (run / "rl" / name).is_file(), name
    assert StrategicPolicy.load(run / "rl").num_sets == StrategicPolicy.load(run).num_sets


def test_distill_trains_the_insertion_decoder(tmp_path, smoke_data_dir):
    """The insertion decoder trains (recorded in config.json; the demo and paper presets'
    default, with the route improvement), its policy plans
    feasible plans and it fine-tunes on reward. The run also takes ``--extra-data`` (here
    the same dataset again: twice the training instances). The CLI's ``--on-policy``,
    ``--decoder append`` and ``--init`` set the run's config (on-policy training itself:
    tests/test_insertion_decoder.py)."""
    from experiments import distill

    run = tmp_path / "ins"
    distill.main(["--preset", "smoke", "--stage", "train", "--out", str(run), "--data-dir",
                  str(smoke_data_dir), "--epochs", "1", "--extra-data", str(smoke_data_dir),
                  "--decoder", "insertion", "--no-progress"])  # fmt: skip
    config = json.loads((run / "config.json").read_text())
    assert config["run"]["model"]["decoder"] == "insertion" and config["run"]["model"]["refine"]
    store = ShardStore.open(smoke_data_dir)
    cfg = DataConfig(**store.config)
    single = distill._split(store, cfg, distill.PRESETS["smoke"].val_houses)[0]
    assert config["dataset"]["train"]["instances"] == 2 * len(single["budget"])
    assert config["dataset"]["meta"]["extra_data"][0]["data_dir"] == str(smoke_data_dir)
    with pytest.raises(ValueError, match="extra-data"):
        distill.main(["--preset", "smoke", "--stage", "train", "--extra-data", " , "])
    policy = StrategicPolicy.load(run)
    assert policy.model.config.decoder == "insertion"
    inst = random_instance(3, num_sets=4, viewpoints=2)
    sol = policy.plan(inst)
    assert evaluate(inst, np.asarray(sol.nodes))[2]
    # reward fine-tuning scores the sampled plans along the insertion decoder's choices
    rows = distill.main(["--preset", "smoke", "--stage", "rl", "--out", str(run), "--data-dir",
                         str(smoke_data_dir), "--rl-epochs", "1", "--rl-samples", "2",
                         "--no-progress"])["rl"]  # fmt: skip
    assert [r["epoch"] for r in rows] == [0, 1] and np.isfinite(rows[1]["train_bc_loss"])
    with pytest.raises(SystemExit):
        distill.main(["--preset", "smoke", "--stage", "train", "--decoder", "prepend"])
    # --on-policy sets the recipe's weight; --decoder append drops the route improvement;
    # --init refuses a model of another config before any training
    args = distill._parse(["--preset", "smoke", "--on-policy", "0.5"])
    preset, cfg = distill.PRESETS["smoke"], distill.PRESETS["smoke"].data
    assert distill._train_run_config(args, preset, cfg, {}).train.on_policy == 0.5
    for name in ("demo", "paper"):  # the real presets default to the insertion decoder
        real = distill._train_run_config(args, distill.PRESETS[name], cfg, {})
        assert real.model.decoder == "insertion" and real.model.refine
    append = distill._train_run_config(args, preset, cfg, {"decoder": "append", "refine": False})
    assert append.model.decoder == "append" and not append.model.refine
    with pytest.raises(ValueError, match="--on-policy"):
        distill.main(["--preset", "smoke", "--stage", "train", "--on-policy", "-1"])
    with pytest.raises(ValueError, match="--init"):
        distill.main(["--preset", "smoke", "--stage", "train", "--data-dir", str(smoke_data_dir),
                      "--out", str(tmp_path / "append"), "--init", str(run), "--decoder",
                      "append", "--no-progress"])  # fmt: skip


def test_distill_rejects_bad_arguments(tmp_path, capsys):
    from experiments import distill

    with pytest.raises(SystemExit):
        distill.main(["--preset", "huge"])
    with pytest.raises(ValueError, match="START:END"):
        distill.main(["--preset", "smoke", "--stage", "eval", "--checkpoint", str(tmp_path),
                      "--eval-seeds", "nonsense", "--out", str(tmp_path)])  # fmt: skip
    for flag, value in (("--epochs", "0"), ("--rl-samples", "0"), ("--dagger-houses", "-2"),
                        ("--rl-lr", "0")):  # fmt: skip
        with pytest.raises(ValueError, match=flag):
            distill.main(["--preset", "smoke", "--out", str(tmp_path / "never"), flag, value])
    assert not (tmp_path / "never").exists()
