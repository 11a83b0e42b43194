"""The measured materials (granular.materials): a thick slab of each, rendered under a
white dome at the examples' grain size, reflects its stated target albedo. The tolerance
is the target's own band widened by three standard errors of the render (fixed seed)."""
import functools

import numpy as np
import pytest

from granular.materials import ICE, MATERIALS, QUARTZ_SAND, SUCROSE, slab_albedo


@functools.lru_cache(maxsize=None)
def _slab(name):
    """(albedo, standard error) of the material's slab, rendered once per test session."""
    return slab_albedo(MATERIALS[name], spp=32, seed=7)


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_a_thick_layer_reflects_the_target_albedo(name):
    m = MATERIALS[name]
    albedo, se = _slab(name)
    assert np.all(se < 0.01), se
    for c in range(3):
        lo, hi = m.target[c]
        assert lo - 3 * se[c] <= albedo[c] <= hi + 3 * se[c], (name, c, albedo, se, m.target)


def test_per_radius_absorption_follows_the_grain_size():
    # A bulk coefficient (1/m) times the radius; a fitted per-radius value stays put.
    assert ICE.absorption_per_radius(0.0004) == pytest.approx([0.13 * 0.0004, 0.05 * 0.0004, 0.02 * 0.0004])
    assert ICE.absorption_per_radius(0.001) == pytest.approx([0.13e-3, 0.05e-3, 0.02e-3])
    assert QUARTZ_SAND.absorption_per_radius(0.01) == QUARTZ_SAND.absorption_per_radius(0.0001)
    assert SUCROSE.absorption_per_radius(0.00025) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="ice"):
        ICE.absorption_per_radius(0.0)


def test_ice_is_bluer_than_it_is_red():
    # Ice absorbs red most: a deep layer of snow reflects less red than blue.
    albedo, se = _slab(ICE.name)
    assert albedo[2] - albedo[0] > 3 * np.hypot(se[0], se[2])
