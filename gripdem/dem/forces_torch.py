"""The force law of :mod:`gripdem.dem.forces_numba`, vectorised over pairs in torch.

Same equations, same packed constants, so the generator runs on a GPU (``backend=torch``,
``device=cuda``) and the two paths are tested against each other on one configuration.
Tensors: positions/velocities/omega ``(n, 3)``, pair indices ``(pairs,)`` int64, shifts
``(pairs, 3)``, history ``(pairs, 3)``; float64 by default. Gathers use ``index_select``
(advanced indexing ``pos[idx]`` was ~3000x slower on the CPU build measured here).
"""

from __future__ import annotations

import math

import torch

from gripdem.dem.params import (
    LAW_BODY_ACC,
    LAW_COH_HCUT,
    LAW_COH_HMIN,
    LAW_DAMP_RATIO,
    LAW_DRAG_VISC,
    LAW_HAMAKER,
    LAW_IMAGE_VEL,
    LAW_KN,
    LAW_KT,
    LAW_LUB_HCUT,
    LAW_LUB_HMIN,
    LAW_LUB_VISC,
    LAW_LX,
    LAW_LY,
    LAW_LZ,
    LAW_MU,
    LAW_SHEAR_RATE,
    TANGENTIAL_MASS_FACTOR,
)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.linalg.cross(a, b, dim=-1)


def compute_forces(
    pos, vel, omega, radius, mass, pair_i, pair_j, shift, history, law, delta, hist_dt
):
    """Returns ``(force, torque, new_history, max_overlap_fraction)``.

    ``law`` is the numpy array of :meth:`GeneratorConfig.force_law` (python floats are read
    from it); ``shift`` is a float tensor of whole numbers.
    """
    c = [float(v) for v in law]
    lx, ly, lz = c[LAW_LX], c[LAW_LY], c[LAW_LZ]
    kn, zeta, kt, mu = c[LAW_KN], c[LAW_DAMP_RATIO], c[LAW_KT], c[LAW_MU]
    hamaker, lub, drag = c[LAW_HAMAKER], c[LAW_LUB_VISC], c[LAW_DRAG_VISC]
    rate, acc = c[LAW_SHEAR_RATE], c[LAW_BODY_ACC]

    force = torch.zeros_like(pos)
    torque = torch.zeros_like(pos)
    if drag > 0.0:
        u = torch.zeros_like(vel)
        u[:, 2] = rate * pos[:, 0]
        force -= (6.0 * math.pi * drag * radius)[:, None] * (vel - u)
        w_fluid = torch.zeros_like(omega)
        w_fluid[:, 1] = -0.5 * rate
        torque -= (8.0 * math.pi * drag * radius**3)[:, None] * (omega - w_fluid)
    if acc != 0.0:
        force[:, 2] += mass * acc * torch.cos(2.0 * math.pi * pos[:, 0] / lx)

    sx, sy, sz = shift[:, 0], shift[:, 1], shift[:, 2]
    r = pos.index_select(0, pair_i) - pos.index_select(0, pair_j)
    r = torch.stack([r[:, 0] - sx * lx, r[:, 1] - sy * ly, r[:, 2] - sx * delta - sz * lz], -1)
    ri, rj = radius.index_select(0, pair_i), radius.index_select(0, pair_j)
    rsum = ri + rj
    dist = torch.linalg.vector_norm(r, dim=-1)
    n = r / dist[:, None]
    gap = dist - rsum
    v = vel.index_select(0, pair_i) - vel.index_select(0, pair_j)
    v = torch.stack([v[:, 0], v[:, 1], v[:, 2] - sx * c[LAW_IMAGE_VEL]], -1)
    vn = (v * n).sum(-1)

    contact = gap < 0.0
    overlap = torch.clamp(-gap, min=0.0)
    mi, mj = mass.index_select(0, pair_i), mass.index_select(0, pair_j)
    m_eff = mi * mj / (mi + mj)
    f_contact = torch.where(contact, kn * overlap - 2.0 * zeta * torch.sqrt(m_eff * kn) * vn, 0.0)
    fn = f_contact.clone()
    new_history = torch.zeros_like(history)
    if mu > 0.0 and kt > 0.0:
        w = ri[:, None] * omega.index_select(0, pair_i) + rj[:, None] * omega.index_select(
            0, pair_j
        )
        cv = v - _cross(w, n)
        vt = cv - (cv * n).sum(-1, keepdim=True) * n
        h = history - (history * n).sum(-1, keepdim=True) * n + vt * hist_dt
        ct = 2.0 * zeta * torch.sqrt(TANGENTIAL_MASS_FACTOR * m_eff * kt)[:, None]
        ft = -kt * h - ct * vt
        ft_mag = torch.linalg.vector_norm(ft, dim=-1)
        f_max = mu * torch.clamp(f_contact, min=0.0)
        slip = ft_mag > f_max
        scale = torch.where(slip, f_max / torch.where(slip, ft_mag, 1.0), 1.0)[:, None]
        ft = ft * scale
        h = torch.where(slip[:, None], -(ft + ct * vt) / kt, h)
        ft = torch.where(contact[:, None], ft, 0.0)
        new_history = torch.where(contact[:, None], h, 0.0)
        force.index_add_(0, pair_i, ft)
        force.index_add_(0, pair_j, -ft)
        nxf = _cross(n, ft)
        torque.index_add_(0, pair_i, -ri[:, None] * nxf)
        torque.index_add_(0, pair_j, -rj[:, None] * nxf)
    r_eff = ri * rj / rsum
    if hamaker > 0.0:
        h_eff = torch.clamp(gap, min=c[LAW_COH_HMIN])
        fn = fn - torch.where(gap < c[LAW_COH_HCUT], hamaker * r_eff / (6.0 * h_eff**2), 0.0)
    if lub > 0.0:
        h_eff = torch.clamp(gap, min=c[LAW_LUB_HMIN])
        f_lub = 6.0 * math.pi * lub * r_eff**2 * vn / h_eff
        fn = fn - torch.where(gap < c[LAW_LUB_HCUT], f_lub, 0.0)
    fvec = fn[:, None] * n
    force.index_add_(0, pair_i, fvec)
    force.index_add_(0, pair_j, -fvec)
    max_overlap = (overlap / rsum).max() if len(rsum) else torch.zeros((), dtype=pos.dtype)
    return force, torque, new_history, max_overlap


def advance(
    state: dict,
    law,
    dt: float,
    n_steps: int,
    delta_build: float,
    steps_since_build: int,
    skin: float,
) -> tuple[int, float]:
    """Velocity-Verlet steps on the tensors in ``state`` (keys pos, vel, omega, force, torque,
    radius, mass, inertia, pair_i, pair_j, shift, history, ref_pos), with the same early-stop
    rebuild rule as the numba kernel. Returns ``(steps done, rebuild due, largest overlap
    fraction)``."""
    s = state
    image_vel = float(law[LAW_IMAGE_VEL])
    inv_m = (0.5 * dt / s["mass"])[:, None]
    inv_i = (0.5 * dt / s["inertia"])[:, None]
    worst = torch.zeros((), dtype=s["pos"].dtype, device=s["pos"].device)
    done, due = 0, False
    for step in range(n_steps):
        s["vel"] += inv_m * s["force"]
        s["omega"] += inv_i * s["torque"]
        s["pos"] += dt * s["vel"]
        moved = steps_since_build + step + 1
        delta = delta_build + image_vel * moved * dt
        s["force"], s["torque"], s["history"], overlap = compute_forces(
            s["pos"],
            s["vel"],
            s["omega"],
            s["radius"],
            s["mass"],
            s["pair_i"],
            s["pair_j"],
            s["shift"],
            s["history"],
            law,
            delta,
            dt,
        )
        worst = torch.maximum(worst, overlap)
        s["vel"] += inv_m * s["force"]
        s["omega"] += inv_i * s["torque"]
        done = step + 1
        max_d = torch.linalg.vector_norm(s["pos"] - s["ref_pos"], dim=-1).max()
        max_v = torch.linalg.vector_norm(s["vel"], dim=-1).max()
        reach_next = float(2.0 * (max_d + 2.0 * max_v * dt))  # one sync per step
        if abs(image_vel) * (moved + 2) * dt + reach_next > skin:
            due = True
            break
    return done, due, float(worst)
