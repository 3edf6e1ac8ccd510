"""gripdem's g(r), coordination and MSD agree with freud-analysis (the optional extra
``analysis``), on hand-placed pairs across the Lees-Edwards x faces and on real DEM data of both
scenes, through ``experiments/analyses/freud_crosscheck.py`` (which also draws the figures).

freud's box for gripdem's LE lattice at offset delta: freud (x, y, z) = ours (z, y, x),
``Lx = lz, Ly = ly, Lz = lx, xz = delta / lx``. freud computes in float32: pairs within ~1e-6 d
of a g(r) bin edge may change bin (contacts sit on the edge r = d), so g(r) must agree (to freud's
float32 normalisation, 3e-5) in every bin whose pair count agrees, and every count difference
must be explained by pairs that close to an edge; MSDs to freud's float32 (1e-4).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from gripdem.boundary import Box, minimum_image
from gripdem.evaluation.physics import neighbour_pairs

freud = pytest.importorskip("freud")

SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "analyses" / "freud_crosscheck.py"


@pytest.fixture(scope="module")
def crosscheck():
    spec = importlib.util.spec_from_file_location("freud_crosscheck", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("delta", [3.1, -2.2, 4.45])
def test_a_pair_across_the_x_face_is_found_at_gripdems_distance(crosscheck, delta):
    box = Box(8.0, 7.0, 9.0)
    a = np.array([3.9, 0.5, 1.0])
    partner = np.array([-3.9, 0.5, 1.0 - delta + 0.2])  # its +x image: a + (0.2, 0, 0.2)
    control = np.array([-3.9, 0.5, 1.2])  # a neighbour only if the x faces did not slide
    positions = np.stack([a, partner, control])
    np.testing.assert_allclose(minimum_image(partner - a, box, delta), [0.2, 0.0, 0.2])
    i, j, dist = neighbour_pairs(positions, box, 0.5, delta)
    assert (i.tolist(), j.tolist()) == ([0], [1])
    fbox = crosscheck.freud_box(box, delta)
    np.testing.assert_allclose(
        fbox.to_matrix(), [[9.0, 0, delta], [0, 7.0, 0], [0, 0, 8.0]], rtol=1e-6, atol=1e-6
    )
    points = crosscheck.freud_points(positions, fbox)
    query = freud.locality.AABBQuery(fbox, points)
    nlist = query.query(points, {"r_max": 0.5, "exclude_ii": True}).toNeighborList()
    assert nlist[:].tolist() == [[0, 1], [1, 0]]
    np.testing.assert_allclose(nlist.distances, [dist[0]] * 2, rtol=1e-5)
    # the same pair across the -x face, seen from the other side
    counts = crosscheck.freud_coordination(positions[::-1], box, delta, 0.5, 1.0)
    assert counts.tolist() == [0, 1, 1]


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_gr_coordination_and_msd_agree_on_real_data(
    crosscheck, scene, tiny_pbc_path, tiny_lebc_path
):
    path = {"pbc": tiny_pbc_path, "lebc": tiny_lebc_path}[scene]
    result = crosscheck.cross_check(path, frames=6)
    assert result["bin_centres_diff"] < 1e-6  # identical bins
    diff = result["count_diff"]
    assert np.abs(diff).sum() <= 2 * result["pairs_near_edges"]  # only float32 at the edges
    same = diff == 0
    assert same.mean() > 0.8 and np.abs(diff).max() <= 3
    np.testing.assert_allclose(result["g"][same], result["g_freud"][same], rtol=3e-5, atol=1e-9)
    assert result["coordination_mismatches_1.01"] == 0  # particle by particle, six frames
    assert result["coordination_mismatches_1.5"] == 0
    assert result["msd_direct_rel_diff"] < 1e-5
    for ours, theirs in result["msd_window"].values():
        assert ours == pytest.approx(theirs, rel=1e-4)


def test_the_independent_unwrap_follows_le_crossers(crosscheck, trajectories):
    """The script's unwrap (used for freud's MSD) is lattice-continuous across the LE faces
    and wraps back to the data: otherwise the MSD comparison would test nothing."""
    data = trajectories(n_sims=1, n_frames=30, n_particles=24, lees_edwards=True, seed=4)
    cont = crosscheck.lattice_continuous(data.positions[0], data.times[0], data.boundary)
    steps = np.diff(cont, axis=0)
    assert np.abs(steps).max() < 0.25 * data.box.lengths.min()
    assert (np.abs(np.diff(data.positions[0][..., 0], axis=0)) > 0.5 * data.box.lx).any()
    from gripdem.boundary import wrap_positions

    back = wrap_positions(cont, data.box, data.offsets()[0][:, None])
    np.testing.assert_allclose(back, data.positions[0], atol=1e-12 * data.box.lengths.max())
