"""Compiled CPU kernels (numba): the force law on a pair list and a velocity-Verlet loop.

The force law (same as :mod:`gripdem.dem.forces_torch`, tested against it), per pair
``(i, j, shift)`` with separation ``r = x_i - x_j - n_x (lx, 0, delta) - n_y ly - n_z lz``,
unit normal ``n = r / |r|`` (from j to i), surface gap ``h = |r| - r_i - r_j`` and relative
velocity ``v = v_i - v_j - n_x * image_vel * e_z`` (the image of j across an LE x face moves
with ``n_x * shear_rate * lx`` along z: docs/spec/dem.md#numerical-traps),
``v_n = v . n`` (< 0 approaching):

- contact (h < 0), linear spring-dashpot: ``F_c = k_n (-h) - c_n v_n`` along n,
  ``c_n = 2 zeta sqrt(m_eff k_n)``, zeta from the restitution coefficient;
- tangential spring with history xi (projected onto the current tangent plane each step,
  carried across list rebuilds): ``F_t = -k_t xi - c_t v_t``, ``c_t = 2 zeta sqrt(2/7 m_eff
  k_t)``, capped at ``mu * max(F_c, 0)`` (xi then set back to the value giving the cap);
  torques ``-r_i n x F_t`` on i and ``-r_j n x F_t`` on j; v_t includes rotation
  ``-(r_i w_i + r_j w_j) x n``;
- van der Waals cohesion: ``-A R / (6 max(h, h_min)^2)`` along n for ``h < h_cut``,
  ``R = r_i r_j / (r_i + r_j)``;
- lubrication (squeeze film): ``-6 pi mu_l R^2 v_n / max(h, h_min)`` along n for ``h < h_cut``;
- per particle: Stokes drag ``-6 pi mu r (v - u)``, ``u = (0, 0, shear_rate x)`` and rotational
  drag ``-8 pi mu r^3 (w - (0, -shear_rate/2, 0))``; body force ``m a cos(2 pi x / lx) e_z``.

A term whose coefficient is zero is skipped. Constants come from the packed array of
:meth:`gripdem.dem.config.GeneratorConfig.force_law`.
"""

from __future__ import annotations

import math

import numba

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

#: numba's fastmath flags of both kernels: fused multiply-adds, reassociation, reciprocals and
#: signed zeros, not ``nnan``/``ninf`` (the runs' NaN and Inf checks must keep working); about a
#: tenth of a step, the trajectory changed at the rounding level
#: (experiments/results/dem_data/dem_kernel_options.md)
FASTMATH = {"contract", "arcp", "nsz", "reassoc", "afn"}


@numba.njit(cache=True, fastmath=FASTMATH)
def compute_forces(
    pos,
    vel,
    omega,
    radius,
    mass,
    pair_i,
    pair_j,
    shift,
    history,
    law,
    delta,
    hist_dt,
    force,
    torque,
):
    """Fill ``force`` and ``torque`` ``(n, 3)``; update ``history`` ``(pairs, 3)`` in place
    (spring increment ``v_t * hist_dt``; pass 0 to evaluate without advancing it).
    Returns the largest overlap as a fraction of ``r_i + r_j``."""
    n = pos.shape[0]
    lx = law[LAW_LX]
    ly = law[LAW_LY]
    lz = law[LAW_LZ]
    kn = law[LAW_KN]
    zeta = law[LAW_DAMP_RATIO]
    kt = law[LAW_KT]
    mu = law[LAW_MU]
    hamaker = law[LAW_HAMAKER]
    coh_hmin = law[LAW_COH_HMIN]
    coh_hcut = law[LAW_COH_HCUT]
    lub = law[LAW_LUB_VISC]
    lub_hmin = law[LAW_LUB_HMIN]
    lub_hcut = law[LAW_LUB_HCUT]
    drag = law[LAW_DRAG_VISC]
    rate = law[LAW_SHEAR_RATE]
    image_vel = law[LAW_IMAGE_VEL]
    acc = law[LAW_BODY_ACC]
    reach = 0.0
    if hamaker > 0.0:
        reach = max(reach, coh_hcut)
    if lub > 0.0:
        reach = max(reach, lub_hcut)
    tangential = mu > 0.0 and kt > 0.0

    for p in range(n):
        fx = 0.0
        fy = 0.0
        fz = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        if drag > 0.0:
            c = 6.0 * math.pi * drag * radius[p]
            fx -= c * vel[p, 0]
            fy -= c * vel[p, 1]
            fz -= c * (vel[p, 2] - rate * pos[p, 0])
            cr = 8.0 * math.pi * drag * radius[p] ** 3
            tx -= cr * omega[p, 0]
            ty -= cr * (omega[p, 1] + 0.5 * rate)
            tz -= cr * omega[p, 2]
        if acc != 0.0:
            fz += mass[p] * acc * math.cos(2.0 * math.pi * pos[p, 0] / lx)
        force[p, 0] = fx
        force[p, 1] = fy
        force[p, 2] = fz
        torque[p, 0] = tx
        torque[p, 1] = ty
        torque[p, 2] = tz

    max_overlap = 0.0
    for q in range(pair_i.shape[0]):
        i = pair_i[q]
        j = pair_j[q]
        sx = shift[q, 0]
        rx = pos[i, 0] - pos[j, 0] - sx * lx
        ry = pos[i, 1] - pos[j, 1] - shift[q, 1] * ly
        rz = pos[i, 2] - pos[j, 2] - sx * delta - shift[q, 2] * lz
        ri = radius[i]
        rj = radius[j]
        rsum = ri + rj
        dist2 = rx * rx + ry * ry + rz * rz
        if dist2 >= (rsum + reach) ** 2:
            history[q, 0] = 0.0
            history[q, 1] = 0.0
            history[q, 2] = 0.0
            continue
        dist = math.sqrt(dist2)
        nx = rx / dist
        ny = ry / dist
        nz = rz / dist
        gap = dist - rsum
        vx = vel[i, 0] - vel[j, 0]
        vy = vel[i, 1] - vel[j, 1]
        vz = vel[i, 2] - vel[j, 2] - sx * image_vel
        vn = vx * nx + vy * ny + vz * nz
        fn = 0.0
        if gap < 0.0:
            overlap = -gap
            if overlap > max_overlap * rsum:
                max_overlap = overlap / rsum
            m_eff = mass[i] * mass[j] / (mass[i] + mass[j])
            f_contact = kn * overlap - 2.0 * zeta * math.sqrt(m_eff * kn) * vn
            fn += f_contact
            if tangential:
                wx = ri * omega[i, 0] + rj * omega[j, 0]
                wy = ri * omega[i, 1] + rj * omega[j, 1]
                wz = ri * omega[i, 2] + rj * omega[j, 2]
                cvx = vx - (wy * nz - wz * ny)
                cvy = vy - (wz * nx - wx * nz)
                cvz = vz - (wx * ny - wy * nx)
                cvn = cvx * nx + cvy * ny + cvz * nz
                vtx = cvx - cvn * nx
                vty = cvy - cvn * ny
                vtz = cvz - cvn * nz
                hn = history[q, 0] * nx + history[q, 1] * ny + history[q, 2] * nz
                hx = history[q, 0] - hn * nx + vtx * hist_dt
                hy = history[q, 1] - hn * ny + vty * hist_dt
                hz = history[q, 2] - hn * nz + vtz * hist_dt
                ct = 2.0 * zeta * math.sqrt(TANGENTIAL_MASS_FACTOR * m_eff * kt)
                ftx = -kt * hx - ct * vtx
                fty = -kt * hy - ct * vty
                ftz = -kt * hz - ct * vtz
                ft = math.sqrt(ftx * ftx + fty * fty + ftz * ftz)
                f_max = mu * max(f_contact, 0.0)
                if ft > f_max:
                    scale = f_max / ft
                    ftx *= scale
                    fty *= scale
                    ftz *= scale
                    hx = -(ftx + ct * vtx) / kt
                    hy = -(fty + ct * vty) / kt
                    hz = -(ftz + ct * vtz) / kt
                history[q, 0] = hx
                history[q, 1] = hy
                history[q, 2] = hz
                force[i, 0] += ftx
                force[i, 1] += fty
                force[i, 2] += ftz
                force[j, 0] -= ftx
                force[j, 1] -= fty
                force[j, 2] -= ftz
                cx = ny * ftz - nz * fty
                cy = nz * ftx - nx * ftz
                cz = nx * fty - ny * ftx
                torque[i, 0] -= ri * cx
                torque[i, 1] -= ri * cy
                torque[i, 2] -= ri * cz
                torque[j, 0] -= rj * cx
                torque[j, 1] -= rj * cy
                torque[j, 2] -= rj * cz
        else:
            history[q, 0] = 0.0
            history[q, 1] = 0.0
            history[q, 2] = 0.0
        if hamaker > 0.0 and gap < coh_hcut:
            h_eff = max(gap, coh_hmin)
            fn -= hamaker * (ri * rj / rsum) / (6.0 * h_eff * h_eff)
        if lub > 0.0 and gap < lub_hcut:
            h_eff = max(gap, lub_hmin)
            r_eff = ri * rj / rsum
            fn -= 6.0 * math.pi * lub * r_eff * r_eff * vn / h_eff
        force[i, 0] += fn * nx
        force[i, 1] += fn * ny
        force[i, 2] += fn * nz
        force[j, 0] -= fn * nx
        force[j, 1] -= fn * ny
        force[j, 2] -= fn * nz
    return max_overlap


@numba.njit(cache=True, fastmath=FASTMATH)
def advance(
    pos,
    vel,
    omega,
    force,
    torque,
    radius,
    mass,
    inertia,
    pair_i,
    pair_j,
    shift,
    history,
    law,
    ref_pos,
    dt,
    n_steps,
    delta_build,
    steps_since_build,
    skin,
    stats,
):
    """Up to ``n_steps`` velocity-Verlet steps; stops early after the step at which the
    neighbour list must be rebuilt (docs/spec/dem.md#numerical-traps rule, made conservative by one
    more step of the fastest particle and of delta). ``force``/``torque`` hold the forces of the
    current state on entry and on return. ``stats[0]`` keeps the largest overlap fraction seen.
    Returns ``(steps done, rebuild due)``."""
    n = pos.shape[0]
    image_vel = law[LAW_IMAGE_VEL]
    for s in range(n_steps):
        max_d2 = 0.0
        max_v2 = 0.0
        for p in range(n):
            hm = 0.5 * dt / mass[p]
            hi = 0.5 * dt / inertia[p]
            for k in range(3):
                vel[p, k] += hm * force[p, k]
                omega[p, k] += hi * torque[p, k]
                pos[p, k] += dt * vel[p, k]
            dx = pos[p, 0] - ref_pos[p, 0]
            dy = pos[p, 1] - ref_pos[p, 1]
            dz = pos[p, 2] - ref_pos[p, 2]
            max_d2 = max(max_d2, dx * dx + dy * dy + dz * dz)
            max_v2 = max(max_v2, vel[p, 0] ** 2 + vel[p, 1] ** 2 + vel[p, 2] ** 2)
        moved = steps_since_build + s + 1
        delta = delta_build + image_vel * moved * dt
        overlap = compute_forces(
            pos,
            vel,
            omega,
            radius,
            mass,
            pair_i,
            pair_j,
            shift,
            history,
            law,
            delta,
            dt,
            force,
            torque,
        )
        stats[0] = max(stats[0], overlap)
        for p in range(n):
            hm = 0.5 * dt / mass[p]
            hi = 0.5 * dt / inertia[p]
            for k in range(3):
                vel[p, k] += hm * force[p, k]
                omega[p, k] += hi * torque[p, k]
        reach_next = 2.0 * (math.sqrt(max_d2) + 2.0 * math.sqrt(max_v2) * dt)
        if abs(image_vel) * (moved + 2) * dt + reach_next > skin:
            return s + 1, True
    return n_steps, False
