"""Derived parameters of the default scenes (docs/spec/dem.md#default-parameters) and the initial
packing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gripdem.boundary import minimum_image
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.neighbours import build_pairs
from gripdem.dem.packing import random_packing
from gripdem.dem.params import LAW_SIZE

D = 2.5e-6


def test_default_scene_numbers_match_the_spec(make_config):
    cfg = make_config("pbc", "default")
    assert cfg.box.lx == pytest.approx(3.2e-5, rel=1e-3)  # the paper's cube
    assert cfg.box.volume_fraction(2000, D) == pytest.approx(0.5)
    assert cfg.mass == pytest.approx(2500 * math.pi * D**3 / 6)
    assert cfg.relaxation_time == pytest.approx(8.7e-7, rel=0.01)
    assert cfg.body_force_amplitude == pytest.approx(5.9e3, rel=0.01)
    assert cfg.dt == pytest.approx(1.62e-8, rel=0.01)  # ~ contact time / 20
    assert cfg.steps_per_frame * cfg.dt == pytest.approx(5e-6)  # frames on whole steps
    assert cfg.total_steps == pytest.approx(1.29e5, rel=0.01)
    assert cfg.first_frame_time == pytest.approx(1.1e-3)
    assert cfg.force_law().shape == (LAW_SIZE,)
    le = make_config("lebc", "default")
    assert le.boundary.image_velocity == pytest.approx(1000 * le.box.lx)
    assert le.body_force_amplitude == 0.0
    # the LE offset at the first written frame is not zero (absolute frame times)
    assert abs(le.boundary.offset(le.first_frame_time)) > 0.1 * le.box.lz


def test_config_errors_name_the_key(make_config):
    with pytest.raises(ValueError, match="unknown key.*stifness"):
        make_config("pbc", stifness=2.0)
    with pytest.raises(ValueError, match="random close packing"):
        make_config("pbc", volume_fraction=0.7)
    with pytest.raises(ValueError, match="without drag"):
        make_config("pbc", fluid_viscosity=0.0)
    with pytest.raises(ValueError, match="shear_rate is the Lees-Edwards rate"):
        make_config("pbc", shear_rate=10.0)
    s = {"name": "x"}
    with pytest.raises(ValueError, match="missing key"):
        GeneratorConfig.from_mappings(s, {})


@pytest.mark.parametrize("aspect", [(1.0, 1.0, 1.0), (1.0, 0.8, 1.25)])
def test_packing_has_no_overlap_at_the_target_fraction(make_config, aspect):
    cfg = make_config("lebc", particles=400, box_aspect=list(aspect))
    assert cfg.box.ly / cfg.box.lx == pytest.approx(aspect[1])
    pos = random_packing(400, cfg.box, D, np.random.default_rng(2))
    assert pos.shape == (400, 3)
    assert np.all(np.abs(pos) <= 0.5 * cfg.box.lengths)
    pairs = build_pairs(pos, cfg.box, 0.0, 1.1 * D)
    r = np.linalg.norm(minimum_image(pos[pairs.i] - pos[pairs.j], cfg.box), axis=1)
    assert r.min() > (1 - 1e-4) * D
    assert cfg.box.volume_fraction(400, D) == pytest.approx(0.5)
