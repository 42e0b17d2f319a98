"""experiments.compare: strategies across recorded runs on their shared episodes."""

from __future__ import annotations

import json

import pytest

from experiments import compare


def _run(tmp_path, name, method, ppl, houses=(1, 2, 3), totals=(1, 4, 12)):
    episodes = [
        {"method": method, "house_seed": h, "category": "Book", "total": t,
         "ppl": p, "progress": p * 2}  # fmt: skip
        for h, t, p in zip(houses, totals, ppl, strict=True)
    ]
    run = tmp_path / name
    run.mkdir()
    (run / "results.json").write_text(json.dumps({"episodes": episodes}))
    return str(run)


def test_compare_pairs_shared_episodes_and_bins_by_count(tmp_path, capsys):
    a = _run(tmp_path, "a", "tfl_reactive", (0.1, 0.2, 0.3))
    b = _run(tmp_path, "b", "bfsop_st", (0.2, 0.2, 0.5, 0.9), houses=(1, 2, 3, 4),
             totals=(1, 4, 12, 7))  # fmt: skip
    table, by_bin, names = compare.compare([f"{a}:tfl_reactive", f"{b}:bfsop_st"], ["T", "B"])
    assert table.startswith("3 shared episodes, 3 houses")  # house 4 is not shared
    assert names == ["1-2 (1)", "3-5 (1)", "6-10 (0)", "11+ (1)"]
    assert by_bin[1, 0] == pytest.approx(0.2) and by_bin[1, 3] == pytest.approx(0.5)
    row = table.splitlines()[-1]
    assert row.startswith("| B | 0.300 | 0.600 | +0.100") and "1.50x" in row
    png = tmp_path / "c.png"
    assert compare.main([f"{a}:tfl_reactive", f"{b}:bfsop_st", "--png", str(png)]) == 0
    assert png.stat().st_size > 0
    capsys.readouterr()
    # each method keeps its Table I colour; a second run of one method gets a lighter shade
    from bfsop_jax.eval.navigation import method_colours
    from bfsop_jax.viz.style import method_colour

    assert compare.run_colours([f"{b}:bfsop_st", f"{a}:tfl_reactive"]) == method_colours(
        ["bfsop_st", "tfl_reactive"])  # fmt: skip
    first, second = compare.run_colours([f"{a}:bfsop_st", f"{b}:bfsop_st"])
    assert first == method_colours(["bfsop_st"])[0] and second not in (first, "#ffffff")
    assert compare.run_colours([f"{a}:x", f"{b}:y"]) == [method_colour(0), method_colour(1)]


def test_compare_accounts_for_the_unverified_targets(tmp_path):
    a = _run(tmp_path, "a", "tfl_reactive", (0.1, 0.2, 0.3))
    b = _run(tmp_path, "b", "bfsop_st", (0.2, 0.2, 0.5))
    path = tmp_path / "b" / "results.json"
    saved = json.loads(path.read_text())
    cases = ((0, 1, 0.5, 1), (1, 1, 0.2, 0), (2, 4, 0.2, 2))
    for e, (seen, unseen, share, away) in zip(saved["episodes"], cases, strict=True):
        found = e["total"] - seen - unseen
        e.update(found=found, missed_seen=seen, missed_unseen=unseen, missed_floor=0,
                 missed_unentered=away, touring_share=share, found_touring=found // 2)  # fmt: skip
    path.write_text(json.dumps(saved))
    table, _, _ = compare.compare([f"{a}:tfl_reactive", f"{b}:bfsop_st"], ["T", "B"])
    # only the run that records the fields gets a row: means over the three episodes
    assert "| B | 2.67 | 1.00 | 2.00 | 0.00 | 1.00 | 0.30 | 0.50 |" in table  # found 0, 2, 6
    assert "| T | " not in table.split("Targets per episode")[1]
    png = tmp_path / "c.png"
    assert compare.main([f"{a}:tfl_reactive", f"{b}:bfsop_st", "--png", str(png)]) == 0
    assert png.stat().st_size > 0 and (tmp_path / "c_targets.png").stat().st_size > 0
    means = compare.compare_targets([f"{a}:tfl_reactive", f"{b}:bfsop_st"], ["T", "B"])
    assert list(means) == ["B"] and means["B"][0] == pytest.approx(8 / 3)


def test_compare_names_bad_input(tmp_path, capsys):
    a = _run(tmp_path, "a", "tfl_reactive", (0.1, 0.2, 0.3))
    assert compare.main([f"{a}:fbe"]) == 2
    assert "no episodes of method 'fbe'" in capsys.readouterr().err
    assert compare.main([f"{tmp_path}/missing:fbe"]) == 2
    assert "no results.json" in capsys.readouterr().err
    assert compare.main([a]) == 2
    assert "expected RUN_DIR:METHOD" in capsys.readouterr().err


def test_compare_refuses_runs_scored_another_way_and_overlapping_joins(tmp_path, capsys):
    """Runs of another scoring (L_opt), preset or budget are not compared; ``+`` joins
    disjoint runs only; with one shared house there is no interval over houses."""
    a = _run(tmp_path, "a", "tfl_reactive", (0.1, 0.2, 0.3))
    b = _run(tmp_path, "b", "bfsop_st", (0.2, 0.2, 0.5))
    path = tmp_path / "b" / "results.json"
    saved = json.loads(path.read_text())
    path.write_text(json.dumps(dict(saved, scoring=2)))  # `a` predates the field: scoring 1
    assert compare.main([f"{a}:tfl_reactive", f"{b}:bfsop_st"]) == 2
    err = capsys.readouterr().err
    assert "the runs differ in scoring (1 in" in err and "to re-score it" in err
    path.write_text(json.dumps(dict(saved, preset="paper")))
    assert compare.main([f"{a}:tfl_reactive", f"{b}:bfsop_st"]) == 2
    assert "the runs differ in preset (None in" in capsys.readouterr().err
    path.write_text(json.dumps(saved))
    c = _run(tmp_path, "c", "tfl_reactive", (0.4,), houses=(3,), totals=(12,))
    assert compare.main([f"{a}:tfl_reactive+{c}:tfl_reactive", f"{b}:bfsop_st"]) == 2
    assert "episode (3, 'Book') is also in an earlier run" in capsys.readouterr().err
    one = _run(tmp_path, "one", "tfl_reactive", (0.1,), houses=(2,), totals=(4,))
    table, _, _ = compare.compare([f"{one}:tfl_reactive", f"{b}:bfsop_st"], ["T", "B"])
    assert table.startswith("1 shared episodes, 1 houses")
    assert "| B | 0.200 | 0.400 | - (one house) | 2.00x |" in table
