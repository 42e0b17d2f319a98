"""SOPInstance validation, the reference evaluator and Solution helpers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bfsop_jax.sop import Solution, SOPInstance, evaluate, plan_length, validate
from bfsop_jax.sop.io import random_instance


def _line_instance(**overrides) -> SOPInstance:
    """Start at x=0, set 1 = {x=1, x=3}, set 2 = {x=2}; |dx| costs."""
    xs = np.array([0.0, 1.0, 3.0, 2.0])
    args = dict(
        cost=np.abs(xs[:, None] - xs[None, :]),
        set_id=np.array([0, 1, 1, 2]),
        set_reward=np.array([0.0, 1.0, 2.0]),
        start=0,
        end=-1,
        budget=10.0,
        coords=np.stack([xs, np.zeros(4)], axis=1),
    )
    args.update(overrides)
    return SOPInstance.create(**args)


def test_create_gives_numpy_dtypes_and_shapes():
    inst = _line_instance()
    assert inst.cost.dtype == np.float32 and inst.cost.shape == (4, 4)
    assert inst.set_id.dtype == np.int32
    assert inst.num_nodes == 4 and inst.num_sets == 3
    assert plan_length(inst.num_sets) == 4


@pytest.mark.parametrize(
    "overrides, message",
    [
        (dict(cost=np.zeros((3, 3))), "cost must be"),
        (dict(cost=np.full((4, 4), np.nan)), "NaN"),
        (dict(cost=-np.ones((4, 4))), "negative cost"),
        (dict(budget=-1.0), "negative budget"),
        (dict(budget=float("nan")), "budget is NaN"),
        (dict(set_id=np.array([0, 1, 1, 5])), "outside"),
        (dict(set_id=np.array([0, 1, 1, -2])), "outside"),
        (dict(set_reward=np.array([0.0, 1.0, 2.0, 3.0])), "no node"),
        (dict(set_reward=np.array([0.0, -1.0, 2.0])), "negative set reward"),
        (dict(set_reward=np.array([1.0, 1.0, 2.0])), "start set"),
        (dict(set_id=np.array([-1, 1, 1, 2])), "padding"),
        (dict(set_id=np.array([1, 1, 1, 2])), "alone"),
        (dict(start=7), "start node"),
        (dict(end=2), "end node"),
        (dict(end=9), "end node"),
        (dict(coords=np.zeros((4, 3))), "coords"),
        (dict(set_id=np.array([0.0, 1.5, 1.0, 2.0])), "integers"),
    ],
)
def test_validation_names_the_problem(overrides, message):
    with pytest.raises(ValueError, match=message):
        _line_instance(**overrides)


def test_masked_set_with_zero_reward_is_valid():
    inst = _line_instance(set_reward=np.array([0.0, 1.0, 2.0, 0.0]))  # set 3 has no node
    validate(inst)


def test_batched_validation_reports_the_element():
    good = _line_instance()
    batch = SOPInstance(**{k: np.stack([v, v]) for k, v in vars(good).items()})
    validate(batch)
    bad_cost = batch.cost.copy()
    bad_cost[1, 0, 1] = np.nan
    with pytest.raises(ValueError, match=r"batch element \(1,\).*NaN"):
        validate(batch.replace(cost=bad_cost))


def test_evaluate_open_path():
    inst = _line_instance()
    assert evaluate(inst, [0, 1, 3]) == (3.0, 2.0, True)
    assert evaluate(inst, [0, 2, 3, -1, -1]) == (3.0, 4.0, True)  # padding stripped
    assert evaluate(inst, [0]) == (0.0, 0.0, True)
    assert evaluate(inst, [0, 1, 2])[2] is False  # set 1 twice
    assert evaluate(inst, [1, 3])[2] is False  # does not start at the start
    assert evaluate(_line_instance(budget=1.5), [0, 1, 3])[2] is False  # over budget


def test_evaluate_closed_tour():
    inst = _line_instance(end=0)
    assert evaluate(inst, [0, 1, 3, 0]) == (3.0, 4.0, True)
    assert evaluate(inst, [0, 0]) == (0.0, 0.0, True)
    assert evaluate(inst, [0, 1, 3])[2] is False  # does not return


def test_evaluate_rejects_unreachable_steps():
    cost = np.abs(np.arange(4.0)[:, None] - np.arange(4.0)[None, :])
    cost[0, 3] = np.inf
    inst = _line_instance(cost=cost)
    reward, total, ok = evaluate(inst, [0, 3])
    assert reward == 2.0 and np.isinf(total) and not ok


def test_solution_padding_round_trip():
    sol = Solution(nodes=np.array([0, 3, 1], np.int32), reward=np.float32(3), cost=np.float32(2))
    padded = sol.padded(6)
    np.testing.assert_array_equal(padded.nodes, [0, 3, 1, -1, -1, -1])
    assert padded.node_list() == [0, 3, 1]
    with pytest.raises(ValueError, match="does not fit"):
        sol.padded(2)


def test_random_instance_shapes_and_masking():
    inst = random_instance(0, masked_sets=2)
    assert inst.cost.shape == (76, 76) and inst.set_reward.shape == (16,)
    assert (inst.set_id == -1).sum() == 10
    assert inst.set_reward[-2:].sum() == 0
    assert int(inst.end) == -1 and int(inst.start) == 0
    assert int(random_instance(0, closed=True).end) == 0


# -- one validator for single and batched instances -----------------------------------------
_BAD_VALUES = [
    dict(cost=np.full((4, 4), np.nan)),
    dict(cost=-np.ones((4, 4))),
    dict(budget=-1.0),
    dict(budget=float("nan")),
    dict(set_id=np.array([0, 1, 1, 5])),
    dict(set_id=np.array([0, 1, 1, -2])),
    dict(set_reward=np.array([0.0, -1.0, 2.0])),
    dict(set_reward=np.array([1.0, 1.0, 2.0])),
    dict(set_id=np.array([-1, 1, 1, 2])),
    dict(set_id=np.array([1, 1, 1, 2])),
    dict(start=7),
    dict(end=2),
    dict(end=9),
    dict(coords=np.full((4, 2), np.inf)),
]


def _unchecked(**overrides) -> SOPInstance:
    """:func:`_line_instance` without validation (NumPy leaves, SOPInstance dtypes)."""
    good = _line_instance()
    inst = good.replace(**{k: np.asarray(v, getattr(good, k).dtype) for k, v in overrides.items()})
    return inst


def _stack(items: list[SOPInstance]) -> SOPInstance:
    return SOPInstance(**{k: np.stack([vars(i)[k] for i in items]) for k in vars(items[0])})


@pytest.mark.parametrize("overrides", _BAD_VALUES)
def test_batched_validation_gives_the_single_message(overrides):
    bad, good = _unchecked(**overrides), _line_instance()
    with pytest.raises(ValueError) as single:
        validate(bad)
    message = str(single.value)
    with pytest.raises(ValueError) as batched:
        validate(_stack([good, bad, bad]))
    assert str(batched.value) == f"batch element (1,): {message}"
    two_d = _stack([_stack([good, good]), _stack([good, bad])])  # batch shape (2, 2)
    with pytest.raises(ValueError) as nested:
        validate(two_d)
    assert str(nested.value) == f"batch element (1, 1): {message}"


@pytest.mark.parametrize(
    "overrides, message",
    [(dict(cost=np.zeros((3, 3))), "cost must be"), (dict(coords=np.zeros((4, 3))), "coords")],
)
def test_shape_errors_single_and_batched(overrides, message):
    bad = _line_instance().replace(**overrides)
    for inst in (bad, _stack([bad, bad])):
        with pytest.raises(ValueError, match=message):
            validate(inst)


def test_validate_returns_numpy_and_limits_batch_axes():
    good = _line_instance()
    batch = _stack([good, good])
    checked = validate(jax.tree_util.tree_map(jnp.asarray, batch), max_batch_dims=1)
    assert isinstance(checked.cost, np.ndarray) and checked.cost.shape == (2, 4, 4)
    with pytest.raises(ValueError, match="at most 0 leading batch axes"):
        validate(batch, max_batch_dims=0)
    with pytest.raises(ValueError, match="empty instance batch"):
        validate(jax.tree_util.tree_map(lambda x: x[:0], batch))
    with pytest.raises(ValueError, match="batch shape"):
        validate(batch.replace(budget=np.float32(1.0)))
    with pytest.raises(ValueError, match="SOPInstance"):
        validate({"cost": good.cost})


def test_random_batches_validate_like_their_elements():
    insts = [random_instance(s, num_sets=6, viewpoints=3, masked_sets=s % 3) for s in range(6)]
    batch = _stack(insts)
    validate(batch)
    bad = batch.set_reward.copy()
    bad[4, 0] = 1.0  # the start set gets a reward
    with pytest.raises(ValueError, match=r"batch element \(4,\): the start set 0 must have"):
        validate(batch.replace(set_reward=bad))
