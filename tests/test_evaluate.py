"""`python -m experiments.evaluate`: Table I end to end on a tiny protocol, resume, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bfsop_jax import metrics
from bfsop_jax.config import get_preset
from bfsop_jax.eval import navigation as nav
from bfsop_jax.world.constants import TARGET_NAMES
from experiments import evaluate

ARGS = ["--preset", "smoke", "--house-seeds", "1000000:1000002", "--categories", "Apple,HousePlant",
        "--methods", "fbe,bfsop_st", "--batch", "3", "--no-progress"]  # fmt: skip


@pytest.fixture(scope="module")
def table1(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    result = evaluate.main(ARGS + ["--out", str(out)])
    return out, result


def test_protocol_replaces_absent_categories():
    houses = nav.HouseSet(get_preset("smoke"))
    ids = range(1000000, 1000004)
    episodes = nav.protocol_episodes(houses, ids, list(range(9)))
    for c in range(9):
        mine = [e for e in episodes if e.category == c]
        assert len(mine) == len(ids)  # every category keeps its number of episodes
        assert len({e.house for e in mine}) == len(mine)
        for e in mine:
            assert houses.counts(e.house)[c] > 0
            assert e.house in ids or e.house >= max(ids) + 1


def test_table1_outputs(table1):
    out, result = table1
    for name in ("results.json", "table1.md", "ppl.png", "ppl_per_category.png",
                 "trajectories.png", "protocol.json"):  # fmt: skip
        assert (out / name).is_file(), name
    saved = json.loads((out / "results.json").read_text())
    assert set(saved["methods"]) == {"fbe", "bfsop_st"}
    for m, s in saved["methods"].items():
        assert s["episodes"] == 4
        lo, hi = s["ppl_ci95"]
        assert lo <= s["ppl_mean"] <= hi
        for key in ("progress_mean", "path_length_mean", "switches_mean", "revisit_mean"):
            assert key in s, (m, key)
    keys = {(r["house_seed"], r["category"]) for r in saved["episodes"] if r["method"] == "fbe"}
    for m in saved["methods"]:
        assert keys == {(r["house_seed"], r["category"]) for r in saved["episodes"]
                        if r["method"] == m}  # fmt: skip
    for r in saved["episodes"]:
        assert 0 <= r["found"] <= r["total"] and r["total"] >= 1
        assert r["path_length"] <= r["path_length_end"] <= r["budget"] + 1e-4
        assert r["ppl"] == pytest.approx(
            metrics.ppl(r["found"], r["total"], r["path_length"], r["l_opt"])
        )
        assert r["ppl"] <= r["progress"] + 1e-9 and r["ppl_end"] <= r["ppl"] + 1e-9
        assert 0.0 <= r["revisit"] <= 1.0
        assert (r["l_opt"] > 0) == (r["found"] > 0) or r["path_length"] == 0.0
        missed = r["missed_seen"] + r["missed_unseen"] + r["missed_floor"]
        assert missed == r["total"] - r["found"] and min(
            r["missed_seen"], r["missed_unseen"], r["missed_floor"]) >= 0  # fmt: skip
        assert 0.0 <= r["touring_share"] <= 1.0 and 0 <= r["found_touring"] <= r["found"]
        assert 0 <= r["missed_unentered"] <= missed
        if r["method"] == "fbe":
            assert r["switches"] == 0 and r["planner_calls"] == 0 and r["touring_share"] == 0
            assert r["found_touring"] == 0
    text = (out / "table1.md").read_text()
    assert "BF-SOP (Transformer) - " in text and "[95% CI]" in text
    _, hlo, hhi = nav.paired(saved["episodes"], "bfsop_st", "fbe", by_house=True)  # 2+ houses
    assert "over houses [95% CI]" in text and f"| [{hlo:+.3f}, {hhi:+.3f}] |" in text


def test_ablation_row_is_compared_but_never_the_best_baseline(table1, tmp_path):
    """TFL-Reactive with BF-SOP's explorer gets its own paired row, not "best baseline"."""
    out, _ = table1
    saved = json.loads((out / "results.json").read_text())
    records = [r for r in saved["episodes"] if r["method"] == "bfsop_st"]
    for r in saved["episodes"]:
        if r["method"] == "fbe":  # stand-ins: the ablation scores above the baseline
            records += [dict(r, method="tfl_reactive"), dict(r, method="tfl_reactive_gain",
                                                             ppl=r["ppl"] + 0.5)]  # fmt: skip
    names = ["tfl_reactive", "bfsop_st", "tfl_reactive_gain"]
    result = dict(saved, episodes=records, methods=nav.summarise(records, names))
    text = nav.write_table1(result, tmp_path / "table1.md")
    assert "| TFL-Reactive + gain explorer | " in text
    assert "BF-SOP (Transformer) - TFL-Reactive (best baseline)" in text
    d, lo, hi = nav.paired(records, "bfsop_st", "tfl_reactive_gain")
    row = f"| BF-SOP (Transformer) - TFL-Reactive + gain explorer (the same explorer) | {d:+.3f}"
    assert row in text and "gain explorer (best baseline)" not in text


def test_resume_reuses_finished_chunks(table1):
    out, result = table1
    chunks = sorted((out / "episodes").glob("*.json"))
    stamps = [p.stat().st_mtime_ns for p in chunks]
    again = evaluate.main(ARGS + ["--out", str(out)])
    assert [p.stat().st_mtime_ns for p in chunks] == stamps
    assert again["methods"] == result["methods"]


def test_resume_rescores_chunks_of_an_older_scoring(table1, tmp_path, monkeypatch):
    """Finished chunks scored another way (no ``scoring``, no stored found slots, another
    L_opt) are re-scored from their saved paths when the run resumes; nothing runs again."""
    import shutil

    out, result = table1
    old = tmp_path / "old"
    shutil.copytree(out, old)
    chunks = sorted((old / "episodes").glob("*_[0-9][0-9][0-9].json"))
    assert chunks and all(json.loads(p.read_text())["scoring"] == nav.SCORING for p in chunks)
    for done in chunks:
        saved = json.loads(done.read_text())
        del saved["scoring"]
        for r in saved["episodes"]:
            r.update(l_opt=1.5 * r["l_opt"] + 1.0, ppl=-1.0, ppl_end=-1.0)
        done.write_text(json.dumps(saved))
        with np.load(done.with_suffix(".npz")) as z:
            kept = {k: z[k] for k in z.files if not k.endswith("_found_slots")}
        np.savez_compressed(done.with_suffix(".npz"), **kept)
    monkeypatch.setattr(nav._Runner, "run", lambda *a: pytest.fail("an episode ran again"))
    again = evaluate.main(ARGS + ["--out", str(old)])
    assert again["scoring"] == nav.SCORING
    assert len(again["episodes"]) == len(result["episodes"])
    for new, ref in zip(again["episodes"], result["episodes"], strict=True):
        assert new.keys() == ref.keys()
        for k in ref:
            assert new[k] == pytest.approx(ref[k], rel=1e-6, abs=1e-9), k
    assert all(json.loads(p.read_text())["scoring"] == nav.SCORING for p in chunks)
    # an old chunk without its paths cannot be re-scored: it runs again
    done = chunks[0]
    saved = json.loads(done.read_text())
    done.write_text(json.dumps({k: v for k, v in saved.items() if k != "scoring"}))
    done.with_suffix(".npz").unlink()
    houses = nav.HouseSet(get_preset("smoke"))
    episodes = [nav.Episode(r["house_seed"], TARGET_NAMES.index(r["category"]))
                for r in saved["episodes"]]  # fmt: skip
    assert nav._finished_chunk(done, episodes, houses) is None


def test_a_methods_files_are_never_anothers(tmp_path):
    """``tfl_reactive``'s chunk files leave ``tfl_reactive_gain``'s alone (resume deletes a
    changed method's files; figures read its paths)."""
    names = ["tfl_reactive_000.json", "tfl_reactive_000.npz", "tfl_reactive_1000.npz",
             "tfl_reactive_999.npz", "tfl_reactive_planner.json", "tfl_reactive_gain_000.npz",
             "tfl_reactive_gain_planner.json"]  # fmt: skip
    for name in names:
        (tmp_path / name).write_text("")
    files = lambda m, s: [f.name for f in nav._method_files(tmp_path, m, s)]
    assert files("tfl_reactive", ".npz") == [
        "tfl_reactive_000.npz", "tfl_reactive_999.npz", "tfl_reactive_1000.npz"]  # fmt: skip
    assert set(files("tfl_reactive", "*")) == set(names[:5])
    assert files("tfl_reactive", "*")[-1] == "tfl_reactive_planner.json"
    assert set(files("tfl_reactive_gain", "*")) == set(names[5:])


def test_gif_animates_the_first_episodes_as_evaluated(table1, tmp_path, monkeypatch):
    """``--gif N`` re-runs the protocol's first N episodes with the frame recorder (never
    the batched path: the finished chunks are reused) and gets the evaluated episodes
    (test_animation.py checks N > 1 and several methods with a stubbed recording)."""
    import shutil

    from PIL import Image

    from bfsop_jax.viz.animation import MAX_FRAMES

    out, _ = table1
    run = tmp_path / "run"
    shutil.copytree(out, run)
    monkeypatch.setattr(nav._Runner, "run", lambda *a: pytest.fail("an episode ran again"))
    args = [a if a != "fbe,bfsop_st" else "fbe" for a in ARGS]
    result = evaluate.main(args + ["--gif", "1", "--out", str(run)])
    first = [r for r in result["episodes"] if r["method"] == "fbe"][:1]
    names = [f"fbe_{r['house']}_{r['category']}.gif" for r in first]
    assert [g["gif"] for g in result["gifs"]] == names
    assert sorted(p.name for p in (run / "gifs").iterdir()) == sorted(names)
    for gif, r in zip(result["gifs"], first, strict=True):
        assert (gif["found"], gif["total"]) == (r["found"], r["total"])
        assert gif["path_length"] == pytest.approx(r["path_length_end"], abs=1e-4)
        with Image.open(run / "gifs" / gif["gif"]) as im:
            assert im.n_frames == min(gif["frames"], MAX_FRAMES)
    assert "gifs" not in json.loads((run / "results.json").read_text())
    with pytest.raises(SystemExit, match="--gif animates the episodes of Table I"):
        evaluate.main(["--scan", "--gif", "1", "--out", str(tmp_path / "scan")])


def test_resume_refuses_another_protocol(table1):
    out, _ = table1
    other = [a if a != "Apple,HousePlant" else "Apple" for a in ARGS]
    with pytest.raises(SystemExit):
        evaluate.main(other + ["--out", str(out)])


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--methods", "fbe,oracle", "unknown method 'oracle'"),
        ("--categories", "Banana", "unknown target category"),
        ("--house-seeds", "1000005:1000005", "empty"),
        ("--house-seeds", "10:20", "training houses"),
        ("--checkpoint", "/nonexistent/run", "--checkpoint"),
        ("--batch", "0", "--batch"),
        ("--gif", "-1", "--gif must be a number of episodes"),
        ("--settings", '{"transformer": {"beam": 4}}', "unexpected keyword argument 'beam'"),
        ("--settings", '{"planner": {}}', "unknown key 'planner'"),
        ("--settings", '{"transformer": {"best_of": 0}}', "best_of must be a positive int"),
        ("--settings", '{"explorer": {"gain": 4}}', "unexpected keyword argument 'gain'"),
        ("--methods", "fbe,tfl_gain", "unknown method 'tfl_gain'; methods are fbe,"),
        ("--methods", "fbe,bfsop_st,fbe", "--methods lists 'fbe' twice"),
        ("--categories", "Apple,HousePlant,Apple", "--categories lists Apple twice"),
        ("--settings", "null", "--settings: expected a JSON object of objects"),
        ("--settings", "[1]", "--settings: expected a JSON object of objects"),
        ("--settings", '{"bfsop": 3}', "--settings: expected a JSON object of objects"),
    ],
)
def test_bad_input_fails_before_running(tmp_path, capsys, flag, value, message):
    args = [a for a in ARGS]
    if flag in args:
        args[args.index(flag) + 1] = value
    else:
        args += [flag, value]
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as err:
        evaluate.main(args + ["--out", str(out)])
    assert message in str(err.value)
    assert not out.exists()


def test_scan_runs_only_the_grids_of_the_given_methods(tmp_path, monkeypatch):
    # two of BFS-Global's settings (each setting is its own compiled rollout)
    monkeypatch.setitem(evaluate.SCAN_GRID, "bfs_global", evaluate.SCAN_GRID["bfs_global"][1:3])
    args = ["--scan", "--preset", "smoke", "--house-seeds", "2000000:2000001", "--categories",
            "HousePlant", "--batch", "1", "--no-progress"]  # fmt: skip
    mine = {"explorer": {"patience": 3}, "bfs_global": {"fraction": 0.9, "max_attempts": 2}}
    rows = evaluate.main(args + ["--methods", "bfs_global", "--out", str(tmp_path),
                                 "--settings", json.dumps(mine)])  # fmt: skip
    assert {r["method"] for r in rows} == {"bfs_global"}
    grid = evaluate.SCAN_GRID["bfs_global"]
    for setting in grid:  # each grid value over the user's settings, the rest kept
        run = tmp_path / f"bfs_global_fraction{setting['fraction']:g}"
        used = json.loads((run / "protocol.json").read_text())["settings"]
        own = {"fraction": setting["fraction"], "max_attempts": 2}
        assert used == {"explorer": {"patience": 3}, "bfs_global": own}
    assert sorted(map(json.dumps, (r["setting"] for r in rows))) == sorted(map(json.dumps, grid))
    best = json.loads((tmp_path / "scan.json").read_text())["best"]
    assert best == {"bfs_global": max(rows, key=lambda r: r["ppl_mean"])["setting"]}
    with pytest.raises(SystemExit, match="none of the methods has a grid"):
        evaluate.main(args + ["--methods", "fbe", "--out", str(tmp_path / "x")])


def test_verification_points_give_a_sane_optimal_length():
    preset = get_preset("smoke")
    houses = nav.HouseSet(preset)
    house = houses[1000000]
    import jax
    import jax.numpy as jnp

    cats = np.asarray(house.object_category)
    c = int(np.bincount(cats[(cats >= 0) & (cats < 9)], minlength=9).argmax())
    idx = np.flatnonzero(cats == c)
    start = jnp.asarray([8.1, 6.1], jnp.float32)
    dist = np.asarray(jax.jit(nav.verification_matrix, static_argnums=4)(
        house, start, jnp.asarray(idx, jnp.int32), jnp.ones(len(idx), bool), preset))  # fmt: skip
    assert dist.shape == (len(idx) + 1, len(idx) + 1)
    assert np.all(np.isfinite(dist)) and np.allclose(dist, dist.T)
    straight = np.linalg.norm(np.asarray(house.object_xy)[idx] - np.asarray(start), axis=1)
    # within the verification distance of each centre, never shorter than the straight line
    assert np.all(dist[0, 1:] >= straight - preset.verify_distance_m - 0.2)
    l_opt = metrics.optimal_visit_length(dist)
    assert l_opt >= dist[0, 1:].min() - 1e-6


def test_transformer_settings_reach_the_planner():
    """``{"transformer": {...}}`` sets the decoding options of BF-SOP (Transformer)."""
    from bfsop_jax.eval.navigation import make_strategy

    policy = object()  # only stored by the planner here
    opts = {"multi_start": 8, "best_of": 4, "fill": True}
    settings = {"transformer": opts, "bfsop": {"walk_limit": 3.0}}
    strategy = make_strategy("bfsop_st", policy, settings)
    planner = strategy.planner
    assert (planner.multi_start, planner.best_of, planner.fill) == (8, 4, True)
    assert planner.policy is policy and strategy.config.walk_limit == 3.0
    plain = make_strategy("bfsop_st", policy).planner
    assert (plain.multi_start, plain.best_of, plain.fill) == (False, 1, False)


@pytest.mark.parametrize("method", [*nav.METHODS, *nav.ABLATIONS])
def test_explorer_settings_reach_every_method(method):
    """``{"explorer": {...}}`` sets the frontier explorer of whichever method runs."""
    from bfsop_jax.agents.bfsop import EXPLORER
    from bfsop_jax.eval.navigation import make_strategy

    def explorer(settings):
        strategy = make_strategy(method, object(), settings)
        return (strategy if method == "fbe" else strategy.explorer).config

    nearest_first = nav.BASELINES + nav.CANDIDATE_METHODS
    own = 0.0 if method in nearest_first else EXPLORER.gain_weight_m
    assert explorer(None).gain_weight_m == own  # the baselines: nearest frontier first
    kept = explorer({"explorer": {"patience": 3}})  # overrides go on top of the method's own
    assert (kept.gain_weight_m, kept.patience) == (own, 3)
    got = explorer({"explorer": {"gain_weight_m": 4.0, "patience": 3}})
    assert (got.gain_weight_m, got.patience) == (4.0, 3)


def test_the_transformer_method_is_described_by_its_model():
    """Resuming with another checkpoint must not reuse the Transformer's chunks: the
    method's description (compared on resume) names the model's weights."""
    from bfsop_jax.policy import StrategicPolicy

    demo, paper = StrategicPolicy.load("demo"), StrategicPolicy.load("paper")
    describe = lambda p: nav.describe_strategy(nav.make_strategy("bfsop_st", p, None))
    assert describe(demo) == describe(StrategicPolicy.load("demo"))
    assert describe(demo) != describe(paper) and paper.fingerprint in describe(paper)
    assert describe(demo).replace(demo.fingerprint, paper.fingerprint) == describe(paper)


def test_ablation_is_tfl_reactive_with_bfsop_explorer():
    """``tfl_reactive_gain``: TFL-Reactive's own settings, BF-SOP's explorer."""
    from bfsop_jax.agents import TFLReactive
    from bfsop_jax.agents.bfsop import BFSOP, EXPLORER

    settings = {"tfl_reactive": {"radius_m": 3.0}}
    strategy = nav.make_strategy("tfl_reactive_gain", None, settings)
    assert isinstance(strategy, TFLReactive) and strategy.config.radius_m == 3.0
    assert strategy.explorer.config == EXPLORER
    assert strategy.explorer.config == BFSOP().explorer.config
    assert nav.make_strategy("tfl_reactive", None, settings).explorer.config != EXPLORER


def test_a_method_keeps_its_colour_whichever_methods_ran():
    every = nav.method_colours([*nav.METHODS, *nav.ABLATIONS])
    assert len(set(every)) == len(every)  # the ablation row is told apart from FBE
    some = nav.method_colours(["tfl_reactive", "bfsop_st", "tfl_reactive_gain"])
    assert some == [every[2], every[4], every[5]]


def test_verdict_reads_the_ratio_to_the_best_baseline_and_the_teacher():
    rng = np.random.default_rng(0)
    records = []
    for h in range(5):
        for c in range(4):
            base = float(rng.uniform(0.1, 0.2))
            for m, ppl in (("fbe", 0.5 * base), ("tfl_reactive", base),
                           ("bfsop_vns", 1.4 * base + 0.01 * rng.normal()),
                           ("bfsop_st", 1.4 * base)):  # fmt: skip
                records.append({"house_seed": 1000000 + h, "category": c, "method": m, "ppl": ppl})
    methods = {m: {"ppl_mean": float(np.mean([r["ppl"] for r in records if r["method"] == m]))}
               for m in ("fbe", "tfl_reactive", "bfsop_vns", "bfsop_st")}  # fmt: skip
    line = nav.verdict({"methods": methods, "episodes": records})
    assert line.startswith("Verdict: BF-SOP (Transformer) PPL")
    assert "1.40x the best baseline (TFL-Reactive) [1.40x, 1.40x]: ahead" in line
    assert "its VNS teacher" in line and ": a tie" in line and "over houses" in line
    del methods["bfsop_st"]
    assert nav.verdict({"methods": methods, "episodes": records}) == ""


def test_table1_ends_with_the_verdict(table1):
    out, _ = table1
    last = (out / "table1.md").read_text().strip().splitlines()[-1]
    assert last.startswith("Verdict: BF-SOP (Transformer)") and "the best baseline (FBE)" in last
