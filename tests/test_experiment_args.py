"""Small experiment scripts refuse bad arguments before writing anything."""

from __future__ import annotations

import pytest


def test_estimate_prior_refuses_an_empty_or_bad_range(tmp_path) -> None:
    from experiments import estimate_prior

    out = tmp_path / "prior.json"
    for args in (["--houses", "0"], ["--batch", "0"], ["--seed-start", "-1"]):
        with pytest.raises(SystemExit, match="need --houses >= 1"):
            estimate_prior.main([*args, "--out", str(out)])
    with pytest.raises(SystemExit, match="evaluation seeds"):
        estimate_prior.main(["--seed-start", "999990", "--houses", "20", "--out", str(out)])
    assert not out.exists()


@pytest.mark.parametrize("budget", ["0", "-5", "nan", "inf"])
def test_simulate_refuses_a_budget_that_is_not_positive(tmp_path, budget) -> None:
    from experiments import simulate

    with pytest.raises(SystemExit, match="--budget must be a positive number"):
        simulate.main(["--budget", budget, "--out", str(tmp_path / "sim")])
    assert not (tmp_path / "sim").exists()
