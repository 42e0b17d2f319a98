import pytest

from bfsop_jax.config import PRESET_NAMES, Preset, get_preset


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_presets_are_hashable_and_consistent(name):
    p = get_preset(name)
    assert isinstance(p, Preset)
    hash(p)  # static jit argument
    h, w = p.grid_shape
    assert abs(h * p.cell_size - p.height_m) < p.cell_size
    assert abs(w * p.cell_size - p.width_m) < p.cell_size
    assert p.n_sop_nodes == 1 + p.n_loi * p.n_viewpoints
    assert get_preset(p) is p


def test_unknown_preset_lists_valid_names():
    with pytest.raises(ValueError, match="smoke.*demo.*paper"):
        get_preset("huge")
