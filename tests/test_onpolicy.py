"""experiments.onpolicy: the Transformer against the VNS on BF-SOP's own instances."""

from __future__ import annotations

from experiments import onpolicy


def test_onpolicy_names_bad_input(capsys):
    assert onpolicy.main(["--houses", "1000000:1000002"]) == 2
    assert "training seeds below" in capsys.readouterr().err
    assert onpolicy.main(["--houses", "5:2"]) == 2
    assert "empty or negative" in capsys.readouterr().err
    assert onpolicy.main(["--categories", "0"]) == 2
    assert "--categories must be >= 1" in capsys.readouterr().err
