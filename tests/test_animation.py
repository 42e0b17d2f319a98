"""Episode GIFs: the frame recorder, ``viz.animate_episode``, ``simulate --gif`` and
``evaluate --gif``."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from bfsop_jax import viz
from bfsop_jax.agents import FBE, TFLReactive, rollout
from bfsop_jax.agents.record import EpisodeFrames, Recording, _tour_ahead, belief_states
from bfsop_jax.config import get_preset
from bfsop_jax.env import observe, reset
from bfsop_jax.eval import gifs
from bfsop_jax.eval import navigation as nav
from bfsop_jax.viz.animation import frame_indices

SMOKE = get_preset("smoke")
HOUSE, CATEGORY = 1000000, 8  # HousePlant: three instances in this house
BUDGET = 20.0  # metres: a short episode (about 15 macro steps)
_reset = jax.jit(reset, static_argnums=3)


@pytest.fixture(scope="module")
def episode():
    """A short FBE episode recorded the way the GIF commands record it."""
    houses = nav.HouseSet(SMOKE)
    ep = nav.Episode(HOUSE, CATEGORY)
    state = _reset(ep.key, houses[HOUSE], CATEGORY, SMOKE, None, BUDGET)
    return state, gifs.make_recorder(nav.make_strategy("fbe"), SMOKE).record(state)


def test_recorder_runs_the_rolled_out_episode(episode):
    """The recorded episode is the rollout's, bit for bit, and its frames agree with it."""
    state, rec = episode
    steps = rec.trajectory.active.shape[0]
    final, traj = jax.jit(lambda s: rollout(s, FBE(), SMOKE, steps))(state)
    active = np.asarray(traj.active)
    assert 0 < active.sum() < steps and bool(final.done)  # the budget ended it
    assert float(rec.final.path_length) == float(final.path_length)
    np.testing.assert_array_equal(rec.final.found, np.asarray(final.found))
    np.testing.assert_array_equal(rec.final.belief, np.asarray(final.belief))
    np.testing.assert_array_equal(rec.trajectory.poses, np.asarray(traj.poses))
    np.testing.assert_array_equal(rec.trajectory.active, active)

    f = rec.frames
    assert f.n_frames == 1 + active.sum()  # the start, then one per macro step
    assert f.path_length[0] == 0.0 and f.path_length[-1] == float(final.path_length)
    assert f.found_count[-1] == int(final.found.sum()) and f.budget == BUDGET
    assert f.total == 3 and len(f.found_xy) == len(f.found_frame) == f.found_count[-1]
    np.testing.assert_array_equal(f.belief[-1], belief_states(final.belief, SMOKE))
    assert set(np.unique(f.belief)) <= {-1, 0, 1} and f.belief.dtype == np.int8
    assert (f.belief[-1] != 0).sum() > (f.belief[0] != 0).sum()  # the map filled in
    np.testing.assert_array_equal(f.path_xy[-1], np.asarray(final.pose)[:2])
    np.testing.assert_array_equal(f.path_xy[0], np.asarray(state.pose)[:2])
    assert np.all(np.diff(f.path_frame) >= 0) and f.path_frame[-1] == f.n_frames - 1
    assert len(f.path_xy) == 1 + np.asarray(traj.moved).sum()
    assert not f.tour_valid.any() and not f.touring.any()  # FBE never tours
    np.testing.assert_array_equal(f.macro_steps, np.arange(f.n_frames))


def test_animate_episode_writes_a_gif_of_the_frames(episode, tmp_path):
    _, rec = episode
    f = rec.frames
    path = viz.animate_episode(f, tmp_path / "all.gif", "FBE: HousePlant in house 1000000")
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == f.n_frames
        assert im.info.get("loop") == 0
    few = viz.animate_episode(f, tmp_path / "few.gif", max_frames=5)
    with Image.open(few) as im:
        assert im.n_frames == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["all.gif", "few.gif"]  # no temp files


def test_frame_indices_keep_the_first_and_the_last():
    assert frame_indices(7, 120).tolist() == list(range(7))
    picked = frame_indices(1000, 120)
    assert len(picked) == 120 and picked[0] == 0 and picked[-1] == 999
    assert np.all(np.diff(picked) > 0)
    with pytest.raises(ValueError):
        frame_indices(0, 120)


def _synthetic_frames(n: int = 4) -> EpisodeFrames:
    """A hand-made episode: a square room, a tour ahead, a target found at frame 2."""
    belief = np.zeros((n, 40, 60), np.int8)
    for i in range(n):
        belief[i, 5 : 10 + 8 * i, 5:55] = -1
        belief[i, 4, :] = 1
    tour_xy = np.zeros((n, 4, 2), np.float32)
    tour_xy[:, 1:3] = [[4.0, 2.5], [5.0, 3.0]]
    tour_valid = np.zeros((n, 4), bool)
    tour_valid[1:3, 1:3] = True
    path_xy = np.asarray([[1, 1], [1.5, 1], [2, 1.5], [3, 2], [3.5, 2.5]], np.float32)
    return EpisodeFrames(
        belief=belief, belief_cell_m=0.1,
        pose=np.asarray([[1, 1, 0], [2, 1.5, 0.5], [3, 2, 1.0], [3.5, 2.5, 1.5]], np.float32),
        path_length=np.asarray([0, 1.2, 2.5, 3.2], np.float32),
        found_count=np.asarray([0, 0, 1, 1], np.int32), touring=np.asarray([0, 1, 1, 0], bool),
        macro_steps=np.arange(n, dtype=np.int32), tour_xy=tour_xy, tour_valid=tour_valid,
        path_xy=path_xy, path_touring=np.asarray([0, 0, 1, 1, 0], bool),
        path_frame=np.asarray([0, 1, 1, 2, 3], np.int32),
        found_xy=np.asarray([[3.2, 2.8]], np.float32), found_frame=np.asarray([2], np.int32),
        total=2, budget=10.0,
    )  # fmt: skip


def test_animate_episode_draws_tours_and_stars(tmp_path):
    """A touring episode: the frames differ and the tour ahead is drawn in touring blue."""
    frames = _synthetic_frames()
    path = viz.animate_episode(frames, tmp_path / "tour.gif", "hand-made", dpi=60)
    images = []
    with Image.open(path) as im:
        assert im.n_frames == frames.n_frames
        for i in range(im.n_frames):
            im.seek(i)
            images.append(np.asarray(im.convert("RGB"), np.int16))
    blue = np.asarray([0x1F, 0x77, 0xB4])
    bluish = [int((np.abs(img - blue).sum(-1) < 40).sum()) for img in images]
    assert bluish[1] > bluish[0] and bluish[2] > bluish[0]  # the tour ahead, touring moves
    gold = [int((np.abs(img - [255, 215, 0]).sum(-1) < 60).sum()) for img in images]
    assert gold[2] > gold[1] + 10  # the star of the target found at frame 2


def test_tour_ahead_is_the_rest_of_the_tour(episode):
    """The viewpoints still ahead of a tour memory; none for a strategy that does not tour."""
    obs = observe(episode[0])
    memory = TFLReactive().init(obs, SMOKE)
    xy, valid = _tour_ahead(memory, SMOKE)
    assert xy.shape == (SMOKE.n_loi + 1, 2) and not bool(valid.any())
    goal = jnp.arange(SMOKE.n_loi * 2, dtype=jnp.float32).reshape(-1, 2)
    tour = memory.tour.replace(
        touring=jnp.ones((), bool), goal=goal, length=jnp.int32(4), position=jnp.int32(1),
        extra=jnp.ones((), bool), extra_goal=jnp.asarray([9.0, 9.0]),
    )  # fmt: skip
    xy, valid = _tour_ahead(memory.replace(tour=tour), SMOKE)
    assert np.flatnonzero(np.asarray(valid)).tolist() == [0, 2, 3, 4]  # completion, 1..3
    np.testing.assert_array_equal(np.asarray(xy)[0], [9.0, 9.0])
    np.testing.assert_array_equal(np.asarray(xy)[2:5], np.asarray(goal)[1:4])
    _, none = _tour_ahead(FBE().init(obs, SMOKE), SMOKE)
    assert not bool(none.any())


def test_belief_states_downsample_keeps_walls():
    belief = jnp.zeros((5, 7)).at[0, 0].set(-1.0).at[1, 1].set(2.0).at[4, 6].set(-3.0)
    full = np.asarray(belief_states(belief, SMOKE))
    assert full[0, 0] == -1 and full[1, 1] == 1 and full[2, 2] == 0
    half = np.asarray(belief_states(belief, SMOKE, downsample=2))
    assert half.shape == (3, 4)
    assert half[0, 0] == 1 and half[2, 3] == -1 and half[1, 1] == 0  # occupied wins


def test_simulate_gif(tmp_path):
    from experiments import simulate

    out = tmp_path / "sim"
    summary = simulate.main(["--preset", "smoke", "--method", "fbe", "--budget", "6",
                             "--gif", "--out", str(out)])  # fmt: skip
    for name in ("house.png", "belief.png", "trajectory.png", "summary.json", "episode.gif"):
        assert (out / name).is_file(), name
    with Image.open(out / "episode.gif") as im:
        assert im.n_frames == summary["gif_frames"] >= 2
    saved = json.loads((out / "summary.json").read_text())
    assert saved["method"] == "fbe" and saved["path_length_m"] <= 6.0 + 1e-4
    assert saved["gif_bytes"] == (out / "episode.gif").stat().st_size


def test_episode_gifs_one_per_method_and_episode(tmp_path, monkeypatch):
    """``evaluate --gif N``'s GIFs: every method's first N episodes, each from the
    protocol's reset (its key, house, category and the preset's budget), named
    ``{method}_{house}_{category}.gif``. The recording is stubbed here (the real one of
    ``evaluate --gif`` is tested in test_evaluate.py)."""
    houses = nav.HouseSet(SMOKE)
    episodes = [nav.Episode(HOUSE, CATEGORY), nav.Episode(1000001, 3)]
    starts = []

    class Stub:
        def __init__(self, strategy, preset):
            self.strategy = strategy

        def record(self, state, progress=None):
            starts.append((type(self.strategy).__name__, state))
            return Recording(final=state, trajectory=None, frames=_synthetic_frames())

    monkeypatch.setattr(gifs, "make_recorder", Stub)
    rows = gifs.write_episode_gifs(["fbe", "tfl_reactive"], episodes, houses, tmp_path / "g",
                                   progress=False)  # fmt: skip
    names = ["fbe_1000000_HousePlant.gif", "fbe_1000001_Laptop.gif",
             "tfl_reactive_1000000_HousePlant.gif", "tfl_reactive_1000001_Laptop.gif"]  # fmt: skip
    assert [r["gif"] for r in rows] == names
    assert sorted(p.name for p in (tmp_path / "g").iterdir()) == names
    assert [s[0] for s in starts] == ["FBE", "FBE", "TFLReactive", "TFLReactive"]
    for (_, state), ep in zip(starts, episodes * 2, strict=True):
        expected = _reset(ep.key, houses[ep.house], ep.category, SMOKE, None, BUDGET)
        np.testing.assert_array_equal(np.asarray(state.pose), np.asarray(expected.pose))
        assert int(state.category) == ep.category and float(state.budget) == SMOKE.budget_m
    assert rows[0]["found"] == 1 and rows[0]["total"] == 2 and rows[0]["frames"] == 4
