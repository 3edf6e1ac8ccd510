"""Boundary math on two or three hand-placed particles crossing each face.

Expected numbers are written out by hand (LagrangeBench ``tests/case_test.py`` style).
Box 4 x 6 x 10, shear rate 0.5 -> image velocity k*lx = 2.0; at t = 1.5 (origin 0) the LE
offset is delta = 3.0.
"""

import numpy as np
import pytest
import torch

from gripdem.boundary import (
    Boundary,
    Box,
    LeesEdwards,
    add_affine_flow,
    affine_flow_strain,
    displacement,
    lattice_continuous_steps,
    minimum_image,
    remove_affine_flow,
    rewrap_trajectory,
    step_start_x,
    unwrap_trajectory,
    wrap_positions,
)

BOX = Box(4.0, 6.0, 10.0)
LE = LeesEdwards(shear_rate=0.5)
T = 1.5  # delta = 0.5 * 4 * 1.5 = 3.0


def test_offset_value_and_wrap():
    assert LE.offset(BOX, np.array(T)) == pytest.approx(3.0)
    # 2.0 * 4.0 = 8.0 -> wrapped into [-5, 5): -2.0
    assert LE.offset(BOX, np.array(4.0)) == pytest.approx(-2.0)
    assert LeesEdwards(0.5, sign=-1).offset(BOX, np.array(T)) == pytest.approx(-3.0)
    # time origin: delta = 0 at t = 1.5
    assert LeesEdwards(0.5, time_origin=T).offset(BOX, np.array(T)) == pytest.approx(0.0)


@pytest.mark.parametrize("as_torch", [False, True])
def test_particles_crossing_each_face(as_torch):
    delta = LE.offset(BOX, np.array(T))
    # continuous positions just past a face, with velocities (0, 0, 0.5)
    moved = np.array(
        [
            [2.1, 0.0, 4.0],  # through +x: x - 4, z - 3
            [-2.1, 0.0, 4.5],  # through -x: x + 4, z + 3 = 7.5 -> -2.5 (double wrap)
            [0.0, 3.2, 0.0],  # through +y: y - 6
            [0.0, -3.1, 0.0],  # through -y: y + 6
            [0.0, 0.0, 5.1],  # through +z: z - 10
            [1.0, 0.0, -5.3],  # through -z: z + 10
            [2.0, 0.0, 1.0],  # exactly on the +x face: counts as crossed
            [-2.0, -3.0, -5.0],  # exactly on the lower faces: stays
        ]
    )
    expected = np.array(
        [
            [-1.9, 0.0, 1.0],
            [1.9, 0.0, -2.5],
            [0.0, -2.8, 0.0],
            [0.0, 2.9, 0.0],
            [0.0, 0.0, -4.9],
            [1.0, 0.0, 4.7],
            [-2.0, 0.0, -2.0],
            [-2.0, -3.0, -5.0],
        ]
    )
    velocities = np.tile([0.0, 0.0, 0.5], (len(moved), 1))
    expected_vz = np.array([0.5 - 2.0, 0.5 + 2.0, 0.5, 0.5, 0.5, 0.5, 0.5 - 2.0, 0.5])
    if as_torch:
        moved, velocities = torch.tensor(moved), torch.tensor(velocities)
    wrapped, vel = wrap_positions(moved, BOX, delta, velocities, LE.image_velocity(BOX))
    np.testing.assert_allclose(np.asarray(wrapped), expected, atol=1e-12)
    np.testing.assert_allclose(np.asarray(vel)[:, 2], expected_vz, atol=1e-12)


def test_minimum_image_across_le_face():
    a = np.array([1.9, 0.0, 4.5])
    b = np.array([-1.9, 0.0, -4.0])
    # r = (3.8, 0, 8.5): fold x -> -0.2 and z -> 8.5 - 3 = 5.5 -> -4.5
    np.testing.assert_allclose(minimum_image(a - b, BOX, 3.0), [-0.2, 0.0, -4.5], atol=1e-12)
    # the reverse pair is the negative (away from the half-open edge)
    np.testing.assert_allclose(minimum_image(b - a, BOX, 3.0), [0.2, 0.0, 4.5], atol=1e-12)
    # periodic (no offset): z simply folds 8.5 -> -1.5
    np.testing.assert_allclose(minimum_image(a - b, BOX), [-0.2, 0.0, -1.5], atol=1e-12)


def test_three_frames_of_a_crossing_particle_unwrap_and_rewrap():
    """A particle moving +0.2 in x and +0.1 in z per frame crosses +x between frames 1 and 2.

    dt = 0.25 so the offset advances by 2.0 * 0.25 = 0.5 per frame: 3.0, 3.5, 4.0.
    """
    times = np.array([1.5, 1.75, 2.0])
    offsets = LE.offset(BOX, times)
    np.testing.assert_allclose(offsets, [3.0, 3.5, 4.0])
    continuous = np.array([[1.7, 0.0, 0.0], [1.9, 0.0, 0.1], [2.1, 0.0, 0.2]])
    wrapped = np.array([[1.7, 0.0, 0.0], [1.9, 0.0, 0.1], [-1.9, 0.0, 0.2 - 4.0]])
    np.testing.assert_allclose(rewrap_trajectory(continuous, BOX, offsets), wrapped, atol=1e-12)
    # frame-to-frame displacement with the LATER frame's offset is the true step
    step = displacement(wrapped[2], wrapped[1], BOX, offsets[2])
    np.testing.assert_allclose(step, [0.2, 0.0, 0.1], atol=1e-12)
    # the earlier frame's offset (the reference scripts' choice) is off by k*lx*dt = 0.5
    wrong = displacement(wrapped[2], wrapped[1], BOX, offsets[1])
    np.testing.assert_allclose(wrong, [0.2, 0.0, -0.4], atol=1e-12)
    increments = np.diff(times) * LE.image_velocity(BOX)
    back = unwrap_trajectory(wrapped, BOX, offsets, increments)
    np.testing.assert_allclose(back, continuous, atol=1e-12)


def test_particle_in_image_cell_drifts_with_the_image():
    """After crossing, the continuous (image-cell) coordinate keeps advancing with the image.

    Particle at rest in the primary cell after a crossing at frame 1: its continuous z in
    image cell +1 moves by +0.5 per frame (the image velocity times dt).
    """
    times = np.array([1.5, 1.75, 2.0, 2.25])
    offsets = LE.offset(BOX, times)
    wrapped = np.array([[1.9, 0.0, 0.0], [-1.9, 0.0, -3.5], [-1.9, 0.0, -3.5], [-1.9, 0.0, -3.5]])
    increments = np.diff(times) * LE.image_velocity(BOX)
    continuous = unwrap_trajectory(wrapped, BOX, offsets, increments)
    np.testing.assert_allclose(continuous[:, 0], [1.9, 2.1, 2.1, 2.1], atol=1e-12)
    np.testing.assert_allclose(continuous[:, 2], [0.0, 0.0, 0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(rewrap_trajectory(continuous, BOX, offsets), wrapped, atol=1e-12)


def test_boundary_object_attrs_and_offsets():
    periodic = Boundary(BOX)
    assert periodic.kind == "periodic" and periodic.image_velocity == 0.0
    np.testing.assert_array_equal(periodic.offset(np.array([1.0, 2.0])), [0.0, 0.0])
    sheared = Boundary(BOX, LE)
    assert sheared.kind == "lees_edwards" and sheared.image_velocity == 2.0
    attrs = sheared.to_attrs()
    assert attrs["boundary"] == "lees_edwards" and attrs["le_sign"] == 1
    np.testing.assert_array_equal(attrs["box"], [4.0, 6.0, 10.0])


def test_invalid_settings_are_refused_with_names():
    with pytest.raises(ValueError, match="Box.ly"):
        Box(1.0, -1.0, 1.0)
    with pytest.raises(ValueError, match="shear_rate"):
        LeesEdwards(float("nan"))
    with pytest.raises(ValueError, match="sign"):
        LeesEdwards(1.0, sign=2)


@pytest.mark.parametrize("as_torch", [False, True])
def test_lattice_continuous_steps_follow_the_image_of_the_anchor(as_torch):
    """A particle riding the affine flow u_z = k x out through +x between frames 0 and 1.

    Times 1.5 .. 2.25 (dt 0.25): offsets 3.0, 3.5, 4.0, 4.5, the image cell advances by
    inc = 0.5 per frame, the flow's strain per frame is 0.5 * 0.25 = 0.125. Continuous x =
    1.9, 2.1, 2.3, 2.5 and z steps 0.125 * x_mid = 0.25, 0.275, 0.3. Seen from the cell it
    occupies at frame 3 (x = -1.5 after the crossing), the same particle was at x = -2.1 and
    its z steps are 0.125 * x_mid with x_mid = -2.0, -1.8, -1.6, i.e. one inc lower each.
    """
    times = np.array([1.5, 1.75, 2.0, 2.25])
    offsets = LE.offset(BOX, times)
    wrapped = np.array(
        [[1.9, 0.0, 0.0], [-1.9, 0.0, -3.25], [-1.7, 0.0, -3.475], [-1.5, 0.0, -3.675]]
    )
    if as_torch:
        wrapped, offsets = torch.tensor(wrapped), torch.tensor(offsets)
    from_first = lattice_continuous_steps(wrapped, BOX, offsets, anchor=0)
    from_last = lattice_continuous_steps(wrapped, BOX, offsets, anchor=-1)
    np.testing.assert_allclose(
        from_first, [[0.2, 0, 0.25], [0.2, 0, 0.275], [0.2, 0, 0.3]], atol=1e-12
    )
    np.testing.assert_allclose(
        from_last, [[0.2, 0, -0.25], [0.2, 0, -0.225], [0.2, 0, -0.2]], atol=1e-12
    )
    # the same as anchor=3; summed from the anchor and wrapped, the frames come back
    np.testing.assert_allclose(lattice_continuous_steps(wrapped, BOX, offsets, anchor=3), from_last)
    rebuilt = np.asarray(wrapped)[3:4] - np.cumsum(np.asarray(from_last)[::-1], 0)[::-1]
    np.testing.assert_allclose(
        rewrap_trajectory(np.asarray(rebuilt), BOX, np.asarray(offsets)[:3]),
        np.asarray(wrapped)[:3],
        atol=1e-12,
    )
    # flow-relative steps do not depend on the image: the particle only moves along x
    strain = affine_flow_strain(Boundary(BOX, LE), 0.25)
    assert strain == pytest.approx(0.125)
    for steps, x_end in ((from_first, 2.5), (from_last, -1.5)):
        x_end = torch.tensor(x_end) if as_torch else np.array(x_end)
        relative = remove_affine_flow(steps, step_start_x(steps, x_end), strain)
        np.testing.assert_allclose(relative, [[0.2, 0, 0]] * 3, atol=1e-12)
        back = add_affine_flow(relative, step_start_x(steps, x_end), strain)
        np.testing.assert_allclose(back, steps, atol=1e-12)


def test_lattice_continuous_steps_in_a_periodic_box_are_minimum_images():
    wrapped = np.array([[1.9, 2.9, 4.9], [-1.9, -2.9, -4.9], [-1.7, -2.7, -4.7]])
    steps = lattice_continuous_steps(wrapped, BOX)
    np.testing.assert_allclose(steps, [[0.2, 0.2, 0.2], [0.2, 0.2, 0.2]], atol=1e-12)
