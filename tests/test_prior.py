"""The co-occurrence prior: estimation, storage, the shipped table."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from bfsop_jax.world.constants import (
    N_CATEGORIES,
    N_TARGETS,
    RECEPTACLE_NAMES,
    ROOM_FURNITURE,
    ROOM_TYPE_NAMES,
    SPAWN_PROB,
    TARGET_ROOM_WEIGHT,
    category_id,
)
from bfsop_jax.world.prior import default_prior, estimate_prior, load_prior, save_prior
from bfsop_jax.world.types import House


def _house(objects):
    m = 6
    cat = np.full(m, -1, np.int32)
    xy = np.zeros((m, 2), np.float32)
    half = np.zeros((m, 2), np.float32)
    parent = np.full(m, -1, np.int32)
    for k, (c, p, h, par) in enumerate(objects):
        cat[k], xy[k], half[k], parent[k] = category_id(c), p, h, par
    z = np.zeros((4, 4))
    return House(
        occupied=z.astype(bool), room_of_cell=z.astype(np.int32), room_type=np.zeros(1, np.int32),
        object_category=cat, object_xy=xy, object_size=np.ones(m, np.float32),
        object_half_extent=half, object_room=np.zeros(m, np.int32), object_parent=parent,
    )  # fmt: skip


def test_estimate_counts_targets_on_and_near_landmarks():
    a = _house([
        ("Desk", (1, 1), (0.6, 0.3), -1),
        ("Desk", (5, 5), (0.6, 0.3), -1),
        ("Laptop", (1.2, 1.1), (0.1, 0.1), 0),   # on desk 0
        ("Book", (5.0, 5.45), (0.1, 0.1), -1),   # 0.15 m beside desk 1: near
        ("Sofa", (9, 9), (1.0, 0.45), -1),
        ("Book", (3, 3), (0.1, 0.1), -1),        # far from everything
    ])  # fmt: skip
    batch = jax.tree_util.tree_map(lambda x: np.asarray(x)[None], a)
    prior, counts = estimate_prior(batch)
    desk, sofa = category_id("Desk"), category_id("Sofa")
    assert counts[desk] == 2 and counts[sofa] == 1
    assert prior[desk, category_id("Laptop")] == pytest.approx(0.5)
    assert prior[desk, category_id("Book")] == pytest.approx(0.5)
    assert prior[sofa].sum() == 0
    assert prior[:N_TARGETS].sum() == 0  # targets are never landmarks


def test_save_load_roundtrip_and_errors(tmp_path):
    rng = np.random.default_rng(0)
    prior = np.zeros((N_CATEGORIES, N_TARGETS), np.float32)
    prior[N_TARGETS:] = rng.uniform(0, 1, (N_CATEGORIES - N_TARGETS, N_TARGETS))
    path = tmp_path / "p.json"
    save_prior(path, prior, {"houses": 3})
    np.testing.assert_allclose(load_prior(path), prior, atol=1e-6)
    with pytest.raises(ValueError, match="not found"):
        load_prior(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="malformed"):
        load_prior(tmp_path / "bad.json")
    doc = json.loads(path.read_text())
    doc["prior"]["Desk"]["Book"] = 1.5
    (tmp_path / "prob.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="not a probability"):
        load_prior(tmp_path / "prob.json")
    with pytest.raises(ValueError, match="shape"):
        save_prior(tmp_path / "x.json", np.zeros((3, 3)))


def test_shipped_prior_matches_the_placement_rule():
    prior = default_prior()
    assert prior.shape == (N_CATEGORIES, N_TARGETS)
    # Every receptacle that can hold a target in a room type allowing it has evidence.
    for r, t in zip(*np.nonzero(SPAWN_PROB > 0.1), strict=True):
        rooms = [
            k for k, n in enumerate(ROOM_TYPE_NAMES) if RECEPTACLE_NAMES[r] in ROOM_FURNITURE[n]
        ]
        if any(TARGET_ROOM_WEIGHT[t, k] >= 1 for k in rooms):
            assert prior[N_TARGETS + r, t] > 0, (RECEPTACLE_NAMES[r], t)
    # The strongest cue of SoapBottle is the counter top, of Book the desk (ProcTHOR facts).
    assert np.argmax(prior[:, category_id("SoapBottle")]) == category_id("CounterTop")
    assert np.argmax(prior[:, category_id("Book")]) == category_id("Desk")
