"""Two-particle tests with analytic answers (issue 3), on both kernels where it applies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gripdem.dem.engine import Simulation
from gripdem.dem.params import damping_ratio

D = 2.5e-6
OFF = dict(fluid_viscosity=0.0, hamaker=0.0, friction=0.0, lubrication_viscosity=0.0)


def _far(cfg):
    """Positions of two particles that never interact (half a box apart)."""
    return np.array([[-0.25 * cfg.box.lx, 0.0, 0.0], [0.25 * cfg.box.lx, 0.0, 0.0]])


def _restitution(cfg, gap: float, v: float = 2e-3) -> float:
    pos = np.array([[-0.5 * D - gap / 2, 0.0, 0.0], [0.5 * D + gap / 2, 0.0, 0.0]])
    vel = np.array([[v, 0.0, 0.0], [-v, 0.0, 0.0]])
    sim = Simulation(cfg, pos, vel)
    sim.run(int(gap / (2 * v) / cfg.dt) + int(3 * cfg.contact_time / cfg.dt))
    _, after, _ = sim.snapshot()
    assert np.abs(after[:, 1:]).max() < 1e-12  # a head-on collision stays on its axis
    return (after[1, 0] - after[0, 0]) / (2 * v)


@pytest.mark.parametrize("preset", ["tiny", "default"])
@pytest.mark.parametrize("restitution", [0.3, 0.5, 0.9])
def test_head_on_restitution_matches_damping(two_particles, make_config, restitution, preset):
    """e = exp(-pi zeta / sqrt(1 - zeta^2)). Where the contact ends inside a step scatters e
    by O(dt / contact time) and the dashpot sees the half-step velocity (a bias of the same
    order, largest for strong damping): at each preset's steps per contact time (tiny 30,
    default 20) the average over contact phases is within 1 / steps per contact (measured:
    -3.0 % and -4.7 % at e = 0.3, -0.6 % and -1.1 % at the scenes' 0.5), and single contacts
    converge as the step shrinks."""
    steps_per_contact = make_config("pbc", preset).preset.steps_per_contact
    cfg = two_particles(restitution=restitution, steps_per_contact=steps_per_contact, **OFF)
    v = 2e-3
    phases = [0.01 * D + f * 2 * v * cfg.dt for f in np.linspace(0.0, 1.0, 6, endpoint=False)]
    assert np.mean([_restitution(cfg, g, v) for g in phases]) == pytest.approx(
        restitution, rel=1.0 / steps_per_contact
    )
    fine = two_particles(restitution=restitution, steps_per_contact=480, **OFF)
    assert _restitution(fine, 0.01 * D, v) == pytest.approx(restitution, rel=0.005)


def test_damping_ratio_inverts_restitution():
    for e in (0.1, 0.5, 0.99):
        z = damping_ratio(e)
        assert math.exp(-math.pi * z / math.sqrt(1 - z * z)) == pytest.approx(e, rel=1e-12)
    assert damping_ratio(1.0) == 0.0


@pytest.mark.parametrize("steps_per_contact", [30, 300])
def test_drag_relaxes_exponentially(two_particles, backend, steps_per_contact):
    """v(t) = v0 exp(-t/tau), w(t) = w0 exp(-t/tau_rot). Velocity Verlet evaluates the drag
    at half-step velocities, which then decay by (1 - dt/tau) per step instead of
    exp(-dt/tau): a relative error t dt / (2 tau^2) (0.4% at t = 0.7 tau, tau = 80 steps),
    asserted with a factor 2 margin at two step sizes."""
    cfg = two_particles(**{**OFF, "fluid_viscosity": 1e-3, "steps_per_contact": steps_per_contact})
    tau = cfg.mass / (3 * math.pi * 1e-3 * D)
    assert cfg.relaxation_time == pytest.approx(tau)
    tau_rot = 0.1 * cfg.mass * D**2 / (math.pi * 1e-3 * D**3)  # I / (pi mu d^3)
    v0 = np.array([[1e-3, -2e-3, 5e-4], [0.0, 0.0, -1e-3]])
    w0 = np.array([[1e3, 0.0, -2e3], [0.0, 5e2, 0.0]])
    sim = Simulation(cfg, _far(cfg), v0, omega=w0, backend=backend)
    for _ in range(3):
        sim.run(round(0.7 * tau / cfg.dt))
        _, vel, omega = sim.snapshot()
        t, h = sim.time, cfg.dt
        np.testing.assert_allclose(vel, v0 * math.exp(-t / tau), rtol=t * h / tau**2, atol=1e-15)
        np.testing.assert_allclose(
            omega, w0 * math.exp(-t / tau_rot), rtol=t * h / tau_rot**2, atol=1e-9
        )


def test_drag_pulls_towards_the_affine_flow_in_lees_edwards(two_particles, backend):
    cfg = two_particles("lebc", **{**OFF, "fluid_viscosity": 1e-3})
    pos = _far(cfg)
    sim = Simulation(cfg, pos, np.zeros((2, 3)), backend=backend)
    sim.run(round(10 * cfg.relaxation_time / cfg.dt))
    p, vel, omega = sim.snapshot()
    np.testing.assert_allclose(vel[:, 2], 1000.0 * p[:, 0], rtol=1e-3)
    np.testing.assert_allclose(omega[:, 1], -500.0, rtol=1e-3)  # half the fluid vorticity


@pytest.mark.parametrize("gap_d", [0.03, 0.05, 0.08])
def test_lubrication_scales_as_inverse_gap(two_particles, pair_kernel, backend, gap_d):
    mu_l = 1e-3
    cfg = two_particles(**{**OFF, "lubrication_viscosity": mu_l})
    vn = -1e-3  # approaching along x
    pos = [[0.0, 0.0, 0.0], [-(D + gap_d * D), 0.0, 0.0]]
    force, *_ = pair_kernel(cfg, pos, [[vn, 0, 0], [0, 0, 0]], backend=backend)
    r_eff = D / 4
    expected = 6 * math.pi * mu_l * r_eff**2 * abs(vn) / (gap_d * D)
    assert force[0, 0] == pytest.approx(expected, rel=1e-12)  # pushes particle 0 back
    np.testing.assert_allclose(force[0], -force[1], rtol=0, atol=1e-30)
    # separating: attraction of the same size; below the minimum gap: regularised; beyond
    # the cut-off: nothing
    sep, *_ = pair_kernel(cfg, pos, [[-vn, 0, 0], [0, 0, 0]], backend=backend)
    assert sep[0, 0] == pytest.approx(-expected, rel=1e-12)
    close = [[0.0, 0, 0], [-(D + 0.005 * D), 0, 0]]
    f_close, *_ = pair_kernel(cfg, close, [[vn, 0, 0], [0, 0, 0]], backend=backend)
    assert f_close[0, 0] == pytest.approx(expected * gap_d / 0.02, rel=1e-12)
    far = [[0.0, 0, 0], [-(D + 0.11 * D), 0, 0]]
    f_far, *_ = pair_kernel(cfg, far, [[vn, 0, 0], [0, 0, 0]], backend=backend)
    assert np.all(f_far == 0.0)


@pytest.mark.parametrize("gap_d", [0.004, 0.01, 0.05, 0.09])
def test_cohesion_matches_hamaker(two_particles, pair_kernel, backend, gap_d):
    hamaker = 1e-20
    cfg = two_particles(**{**OFF, "hamaker": hamaker})
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    pos = [[0.0, 0, 0], list(-(D + gap_d * D) * direction)]
    force, *_ = pair_kernel(cfg, pos, np.zeros((2, 3)), backend=backend)
    expected = hamaker * (D / 4) / (6 * (gap_d * D) ** 2)  # A R / (6 h^2), R = r/2
    np.testing.assert_allclose(force[0], -expected * direction, rtol=1e-12)  # towards 1
    np.testing.assert_allclose(force[1], expected * direction, rtol=1e-12)
    # regularised at 5 nm (0.002 d), zero beyond 0.1 d
    inside = [[0.0, 0, 0], [-(D - 0.001 * D), 0, 0]]
    f_in, *_ = pair_kernel(
        cfg.__class__.from_mappings(
            {**cfg.to_dict()["scene"], "stiffness": 1e-30}, cfg.to_dict()["preset"], sims=1
        ),
        inside,
        np.zeros((2, 3)),
        backend=backend,
    )
    assert -f_in[0, 0] == pytest.approx(hamaker * (D / 4) / (6 * (0.002 * D) ** 2), rel=1e-6)
    beyond = [[0.0, 0, 0], [-(D + 0.101 * D), 0, 0]]
    f_out, *_ = pair_kernel(cfg, beyond, np.zeros((2, 3)), backend=backend)
    assert np.all(f_out == 0.0)


def test_friction_caps_at_mu_times_normal_force(two_particles, pair_kernel, backend):
    mu = 0.3
    cfg = two_particles(**{**OFF, "friction": mu})
    law = cfg.force_law()
    kn, kt = law[0], law[2]
    overlap = 1e-3 * D
    pos = [[0.0, 0, 0], [-(D - overlap), 0, 0]]  # n = +x from 1 to 0
    vt = 1e-3
    vel = [[0.0, vt, 0.0], [0.0, 0.0, 0.0]]  # sliding along +y
    fn = kn * overlap
    m_eff = cfg.mass / 2
    ct = 2 * damping_ratio(0.5) * math.sqrt(2 / 7 * m_eff * kt)
    history = np.zeros(3)
    dt = cfg.dt
    seen_cap = False
    for k in range(1, 4000):
        force, torque, history, _ = pair_kernel(
            cfg, pos, vel, history=history, hist_dt=dt, backend=backend
        )
        f_t = force[0, 1]
        stick = -(kt * vt * k * dt + ct * vt)
        if abs(stick) < mu * fn:
            assert f_t == pytest.approx(stick, rel=1e-9)
        else:
            seen_cap = True
            assert f_t == pytest.approx(-mu * fn, rel=1e-12)  # opposes the sliding
        assert force[0, 0] == pytest.approx(fn, rel=1e-12)
        # torques -r n x F_t on both particles (n = +x, F_t along y -> torque along -z)
        np.testing.assert_allclose(torque[0], [0, 0, -(D / 2) * f_t], rtol=1e-12, atol=1e-40)
        np.testing.assert_allclose(torque[1], torque[0], rtol=1e-12, atol=1e-40)
    assert seen_cap
    # the stored spring stays consistent with the cap (no wind-up while sliding)
    assert kt * np.linalg.norm(history) == pytest.approx(mu * fn - ct * vt, rel=1e-9)


def test_le_crossing_remaps_position_and_velocity(two_particles, backend):
    cfg = two_particles("lebc", **OFF)
    box, k = cfg.box, 1000.0
    x0 = np.array([0.5 * box.lx - 0.02 * D, 0.1 * box.ly, 0.3 * box.lz])
    v0 = np.array([0.5, 0.0, 0.002])  # fast along x: crosses, and several rebuilds happen
    pos = np.stack([x0, [-0.1 * box.lx, -0.3 * box.ly, -0.3 * box.lz]])
    vel = np.stack([v0, np.zeros(3)])
    sim = Simulation(cfg, pos, vel, backend=backend)
    t_start = sim.time
    sim.run(200)
    t = sim.time - t_start
    p, v, _ = sim.snapshot()
    delta = k * box.lx * sim.time  # time origin 0: delta(t) = shear_rate * lx * t
    cont = x0 + v0 * t
    assert cont[0] > 0.5 * box.lx  # it did cross the +x face
    expected_z = (cont[2] - delta + 0.5 * box.lz) % box.lz - 0.5 * box.lz
    assert p[0, 0] == pytest.approx(cont[0] - box.lx, abs=1e-15)
    assert p[0, 2] == pytest.approx(expected_z, abs=1e-15)
    assert v[0, 2] == pytest.approx(v0[2] - k * box.lx, rel=1e-12)
    assert v[0, 0] == pytest.approx(v0[0])
    # the engine's own state was remapped at its rebuilds, not only the snapshot
    assert sim.rebuilds > 1
    _, state_vel, _ = sim.state()
    assert state_vel[0, 2] == pytest.approx(v0[2] - k * box.lx, rel=1e-12)


def test_pair_across_le_face_feels_what_it_feels_inside(two_particles, pair_kernel, backend):
    """docs/spec/dem.md#numerical-traps: across the x faces the relative velocity needs v_z -/+
    shear_rate*lx, like the separation needs z -/+ delta. A pair in affine flow straddling the +x
    face must feel exactly the forces of the same pair in the middle of the box."""
    cfg = two_particles(
        "lebc", friction=0.3, hamaker=1e-20, lubrication_viscosity=1e-3, fluid_viscosity=0.0
    )
    box, k = cfg.box, 1000.0
    r = np.array([0.6, 0.1, 0.79]) * D * 0.999 / np.linalg.norm([0.6, 0.1, 0.79])
    omega = np.array([[100.0, -300.0, 50.0], [-20.0, 10.0, 400.0]])
    history = np.array([0.0, 1e-10, 0.0])
    # inside: particle 0 at r/2, particle 1 at -r/2, affine velocities u_z = k x
    inside = np.stack([0.5 * r, -0.5 * r])
    vel_in = np.zeros((2, 3))
    vel_in[:, 2] = k * inside[:, 0]
    f_in, t_in, h_in, _ = pair_kernel(
        cfg, inside, vel_in, omega, history=history, hist_dt=cfg.dt, backend=backend
    )
    # across the face: particle 0 just inside +x, particle 1 wrapped to -x (x - lx, z - delta)
    delta = 0.37 * box.lz
    p0 = np.array([0.5 * box.lx - 0.2 * D, 0.0, 0.1 * box.lz])
    p1_image = p0 - r  # beyond +x
    p1 = np.array([p1_image[0] - box.lx, p1_image[1], p1_image[2] - delta])
    across = np.stack([p0, p1])
    vel_x = np.zeros((2, 3))
    vel_x[:, 2] = k * across[:, 0]  # u_z = k x in the primary cell (p1's image: + k lx)
    # separation x0 - x1 - n_x (lx, 0, delta) with n_x = +1: the image of 1 across +x
    f_x, t_x, h_x, _ = pair_kernel(
        cfg,
        across,
        vel_x,
        omega,
        shift=(1, 0, 0),
        history=history,
        delta=delta,
        hist_dt=cfg.dt,
        backend=backend,
    )
    np.testing.assert_allclose(f_x, f_in, rtol=1e-9, atol=1e-9 * np.abs(f_in).max())
    np.testing.assert_allclose(t_x, t_in, rtol=1e-9, atol=1e-9 * np.abs(t_in).max())
    np.testing.assert_allclose(h_x, h_in, rtol=1e-9, atol=1e-25)
