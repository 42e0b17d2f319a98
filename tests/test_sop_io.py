"""The ``.sop`` reader: a hand-made file with known costs, malformed files, the benchmark."""

from __future__ import annotations

import re

import numpy as np
import pytest

from bfsop_jax.sop import read_sop

SMALL = """NAME: small
TYPE: TSP
COMMENT: hand-made
DIMENSION: 4
TMAX: 10
START_SET: 0
END_SET: 0
SETS: 3
EDGE_WEIGHT_TYPE: CEIL_2D
NODE_COORD_SECTION
1 0.0 0.0
2 3.0 4.0
3 1.0 0.5
4 -2.5 0
GTSP_SET_SECTION: set_id set_profit id-vertex-list
0 0 1
1 7 2 3
2 5 4
"""


def _write(tmp_path, text: str, name: str = "case.sop"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_small_file(tmp_path):
    inst = read_sop(_write(tmp_path, SMALL))
    assert inst.cost.shape == (4, 4)
    np.testing.assert_array_equal(inst.set_id, [0, 1, 1, 2])
    np.testing.assert_array_equal(inst.set_reward, [0, 7, 5])
    assert int(inst.start) == 0 and int(inst.end) == 0 and float(inst.budget) == 10
    assert inst.cost[0, 1] == 5  # 3-4-5 triangle
    assert inst.cost[0, 2] == 2  # ceil(1.118)
    assert inst.cost[0, 3] == 3  # ceil(2.5)
    np.testing.assert_array_equal(inst.cost, inst.cost.T)
    np.testing.assert_allclose(inst.coords[3], [-2.5, 0])


def test_windows_line_endings_and_eof(tmp_path):
    inst = read_sop(_write(tmp_path, SMALL.replace("\n", "\r\n") + "EOF\r\n"))
    assert inst.num_nodes == 4


def test_open_path_between_sets(tmp_path):
    text = SMALL.replace("END_SET: 0", "END_SET: 2").replace("2 5 4", "2 0 4")
    inst = read_sop(_write(tmp_path, text))
    assert int(inst.start) == 0 and int(inst.end) == 3


MALFORMED = [
    (lambda t: t.replace("DIMENSION: 4", "DIMENSION: 5"), 4, "DIMENSION is 5"),
    (lambda t: t.replace("DIMENSION: 4\n", ""), 17, "missing header key DIMENSION"),
    (lambda t: t.replace("TMAX: 10", "TMAX: -3"), 5, "TMAX"),
    (lambda t: t.replace("TMAX: 10", "TMAX: ten"), 5, "not a number"),
    (lambda t: t.replace("CEIL_2D", "GEO"), 9, "EDGE_WEIGHT_TYPE"),
    (lambda t: t.replace("3 1.0 0.5", "3 1.0"), 13, "id x y"),
    (lambda t: t.replace("3 1.0 0.5", "3 1.0 abc"), 13, "not a number"),
    (lambda t: t.replace("4 -2.5 0", "3 -2.5 0"), 14, "defined twice"),
    (lambda t: t.replace("2 5 4", "2 5 9"), 18, "outside 1..4"),
    (lambda t: t.replace("2 5 4", "2 5 3"), 18, "in sets 1 and 2"),
    (lambda t: t.replace("2 5 4", "5 5 4"), 18, "outside"),
    (lambda t: t.replace("START_SET: 0", "START_SET: 1"), 17, "exactly one node"),
    (lambda t: t.replace("SETS: 3", "SETS: 4"), 8, "SETS is 4"),
    (lambda t: t.replace("1 7 2 3", "1 -7 2 3"), 17, "negative profit"),
    (lambda t: t.replace("TYPE: TSP", "TYPE TSP"), 2, "KEY: value"),
]


@pytest.mark.parametrize("edit, line, message", MALFORMED)
def test_malformed_file_names_file_and_line(tmp_path, edit, line, message):
    path = _write(tmp_path, edit(SMALL), name="broken.sop")
    with pytest.raises(ValueError) as err:
        read_sop(path)
    text = str(err.value)
    assert "broken.sop" in text
    assert f"line {line}:" in text, text
    assert message in text, text


def test_binary_file_is_rejected(tmp_path):
    path = tmp_path / "bin.sop"
    path.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(ValueError, match="bin.sop"):
        read_sop(path)


def test_every_benchmark_file_parses(shared):
    files = sorted(shared("sop", "instances").glob("*.sop"))
    assert len(files) == 510
    for path in files:
        text = path.read_text()
        dim = int(re.search(r"DIMENSION:\s*(\d+)", text).group(1))
        sets = int(re.search(r"SETS:\s*(\d+)", text).group(1))
        inst = read_sop(path)
        assert inst.num_nodes == dim and inst.num_sets == sets, path.name
        assert int(inst.start) == int(inst.end)  # closed tours at the depot
        assert inst.set_reward[inst.set_id[int(inst.start)]] == 0
        assert (inst.set_id >= 0).all(), path.name  # every node is in a set
