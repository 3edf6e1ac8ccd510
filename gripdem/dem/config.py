"""The generator configuration: scene physics + preset sizes (:mod:`gripdem.dem.params`), and
every constant derived from them (masses, contact and relaxation times, the DEM step, the
body-force amplitude, the neighbour-list skin, the packed force law both kernels read).

:meth:`GeneratorConfig.from_mappings` checks that every key of the two config groups
(``conf/scene/*.yaml``, ``conf/preset/*.yaml``) is known and present; a DEM step too large for
the contact stiffness or the damping terms is refused at construction.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripdem.boundary import Boundary, Box, LeesEdwards, check_volume_fraction
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
    LAW_SIZE,
    MAX_STEP_PER_DAMPING_TIME,
    MIN_STEPS_PER_CONTACT,
    SOLID_SPHERE_INERTIA,
    PresetParams,
    SceneParams,
    damping_ratio,
    dataclass_from_mapping,
)


@dataclass(frozen=True)
class GeneratorConfig:
    """Everything that determines a generated dataset (hashed by the cache).

    A DEM step too large for the contact stiffness or for the damping terms is refused at
    construction (:meth:`check_time_step`), naming the options that set it.
    """

    scene: SceneParams
    preset: PresetParams
    sims: int
    seed: int
    backend: str = "numba"

    def __post_init__(self) -> None:
        self.check_time_step()

    @classmethod
    def from_mappings(
        cls,
        scene: Mapping[str, Any],
        preset: Mapping[str, Any],
        sims: int | None = None,
        seed: int = 0,
        backend: str = "numba",
    ) -> GeneratorConfig:
        """Build from the ``scene`` and ``preset`` config nodes (dicts or DictConfigs)."""
        scene_p = dataclass_from_mapping(SceneParams, _plain(scene), "scene")
        preset_p = dataclass_from_mapping(PresetParams, _plain(preset), "preset")
        if backend not in ("numba", "torch"):
            raise ValueError(f"backend must be 'numba' or 'torch', got {backend!r}")
        n_sims = preset_p.sims if sims is None else int(sims)
        if n_sims < 1:
            raise ValueError(f"sims must be >= 1, got {n_sims}")
        config = cls(scene_p, preset_p, n_sims, int(seed), backend)
        check_volume_fraction(
            preset_p.particles, scene_p.diameter, config.box, f"scene {scene_p.name!r}"
        )
        config.body_force_amplitude  # noqa: B018  (raises now if it cannot be derived)
        return config

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    # ---------------------------------------------------------------- geometry and particles
    @property
    def radius(self) -> float:
        return 0.5 * self.scene.diameter

    @property
    def box(self) -> Box:
        """Box whose shape is ``box_aspect`` and volume gives ``volume_fraction``."""
        s, p = self.scene, self.preset
        volume = p.particles * math.pi * s.diameter**3 / 6.0 / s.volume_fraction
        aspect = np.asarray(p.box_aspect, dtype=np.float64)
        scale = (volume / float(np.prod(aspect))) ** (1.0 / 3.0)
        return Box(*(float(a * scale) for a in aspect))

    @property
    def boundary(self) -> Boundary:
        if self.scene.boundary == "periodic":
            return Boundary(self.box)
        # time origin 0 = start of the driven spin-up: frame times are absolute
        # (docs/spec/dem.md#time-origin)
        return Boundary(self.box, LeesEdwards(self.scene.shear_rate, sign=1, time_origin=0.0))

    @property
    def mass(self) -> float:
        return self.scene.density * math.pi * self.scene.diameter**3 / 6.0

    @property
    def inertia(self) -> float:
        return SOLID_SPHERE_INERTIA * self.mass * self.radius**2

    # ---------------------------------------------------------------- time scales
    @property
    def contact_time(self) -> float:
        """Duration of a damped head-on contact of two particles (linear spring-dashpot)."""
        m_eff = 0.5 * self.mass
        zeta = damping_ratio(self.scene.restitution)
        return math.pi / (math.sqrt(self.scene.stiffness / m_eff) * math.sqrt(1.0 - zeta**2))

    @property
    def relaxation_time(self) -> float:
        """Stokes relaxation time m / (3 pi mu d); inf without drag."""
        mu = self.scene.fluid_viscosity
        return math.inf if mu == 0 else self.mass / (3.0 * math.pi * mu * self.scene.diameter)

    @property
    def steps_per_frame(self) -> int:
        return max(
            1,
            math.ceil(
                self.preset.frame_interval * self.preset.steps_per_contact / self.contact_time
            ),
        )

    @property
    def dt(self) -> float:
        """DEM step: about contact_time / steps_per_contact, a whole fraction of a frame."""
        return self.preset.frame_interval / self.steps_per_frame

    def damping_times(self) -> dict[str, float]:
        """m / c of each damping term that is switched on (s), keyed by the scene option
        that sets its coefficient: Stokes drag ``m / (3 pi mu d)``; pair lubrication at its
        regularisation gap (its stiffest point), ``m_eff / (6 pi mu_l r_eff^2 / h_min)`` with
        the pair's reduced mass ``m_eff = m / 2`` and reduced radius ``r_eff = d / 4``."""
        s, out = self.scene, {}
        if s.fluid_viscosity > 0:
            out["scene.fluid_viscosity"] = self.relaxation_time
        if s.lubrication_viscosity > 0:
            r_eff = 0.25 * s.diameter
            gap = s.lubrication_min_gap_d * s.diameter
            coefficient = 6.0 * math.pi * s.lubrication_viscosity * r_eff**2 / gap
            out["scene.lubrication_viscosity"] = 0.5 * self.mass / coefficient
        return out

    def check_time_step(self) -> None:
        """Refuse a DEM step the explicit integrator cannot take
        (docs/spec/dem.md#step-and-cost: dt ~ contact time / 20): fewer than
        :data:`MIN_STEPS_PER_CONTACT` steps per contact time, or a step above
        :data:`MAX_STEP_PER_DAMPING_TIME` of a damping time. The message names the option that
        sets the step and the coefficient that makes it too large."""
        dt, contact = self.dt, self.contact_time
        if contact / dt < MIN_STEPS_PER_CONTACT * (1.0 - 1e-9):
            raise ValueError(
                f"DEM time step too large for the contact stiffness: dt = {dt:.3g} s is "
                f"{contact / dt:.3g} steps per contact time ({contact:.3g} s at scene.stiffness "
                f"= {self.scene.stiffness:g} N/m, particle mass {self.mass:.3g} kg); need at "
                f"least {MIN_STEPS_PER_CONTACT:g} (the explicit step diverges near 2-3): raise "
                f"preset.steps_per_contact (now {self.preset.steps_per_contact:g})"
            )
        for option, tau in self.damping_times().items():
            if dt > MAX_STEP_PER_DAMPING_TIME * tau:
                raise ValueError(
                    f"DEM time step too large for the damping set by {option}: dt = {dt:.3g} s "
                    f"exceeds {MAX_STEP_PER_DAMPING_TIME:g} x its damping time m / c = "
                    f"{tau:.3g} s (explicit damping diverges at 2 m / c): raise "
                    f"preset.steps_per_contact (now {self.preset.steps_per_contact:g}) or "
                    f"lower {option}"
                )

    @property
    def spinup_frames(self) -> int:
        return round(self.preset.spinup_time / self.preset.frame_interval)

    @property
    def first_frame_time(self) -> float:
        return self.spinup_frames * self.preset.frame_interval

    @property
    def total_steps(self) -> int:
        return (self.spinup_frames + self.preset.frames - 1) * self.steps_per_frame

    @property
    def body_force_amplitude(self) -> float:
        """a (m/s^2). Default ``a = body_force_shear_rate * lx / (2 pi tau_p)``: with drag
        alone the steady profile ``a tau_p cos(2 pi x / lx)`` peaks at that shear rate."""
        s = self.scene
        if s.boundary == "lees_edwards":
            return 0.0 if s.body_force_amplitude is None else s.body_force_amplitude
        if s.body_force_amplitude is not None:
            return s.body_force_amplitude
        if s.fluid_viscosity == 0:
            raise ValueError(
                "periodic scene without drag (fluid_viscosity = 0): give body_force_amplitude "
                "directly (and another dissipation); the default a = k lx / (2 pi tau_p) "
                "needs tau_p"
            )
        return s.body_force_shear_rate * self.box.lx / (2.0 * math.pi * self.relaxation_time)

    # ---------------------------------------------------------------- interaction range
    @property
    def interaction_gap(self) -> float:
        """Largest surface gap at which any pair force acts, m."""
        s = self.scene
        gap = 0.0
        if s.hamaker > 0:
            gap = max(gap, s.cohesion_cutoff_gap_d * s.diameter)
        if s.lubrication_viscosity > 0:
            gap = max(gap, s.lubrication_cutoff_gap_d * s.diameter)
        return gap

    @property
    def skin(self) -> float:
        return self.preset.skin_d * self.scene.diameter

    @property
    def list_cutoff(self) -> float:
        """Neighbour-list cut-off between centres: 2 r_max + interaction gap + skin."""
        return self.scene.diameter + self.interaction_gap + self.skin

    def force_law(self) -> np.ndarray:
        """The packed ``(LAW_SIZE,)`` float64 constants read by both kernels."""
        s, box, d = self.scene, self.box, self.scene.diameter
        law = np.zeros(LAW_SIZE, dtype=np.float64)
        law[LAW_KN] = s.stiffness
        law[LAW_DAMP_RATIO] = damping_ratio(s.restitution)
        law[LAW_KT] = s.tangential_stiffness_ratio * s.stiffness
        law[LAW_MU] = s.friction
        law[LAW_HAMAKER] = s.hamaker
        law[LAW_COH_HMIN] = s.cohesion_min_gap_d * d
        law[LAW_COH_HCUT] = s.cohesion_cutoff_gap_d * d
        law[LAW_LUB_VISC] = s.lubrication_viscosity
        law[LAW_LUB_HMIN] = s.lubrication_min_gap_d * d
        law[LAW_LUB_HCUT] = s.lubrication_cutoff_gap_d * d
        law[LAW_DRAG_VISC] = s.fluid_viscosity
        law[LAW_SHEAR_RATE] = s.shear_rate
        law[LAW_IMAGE_VEL] = self.boundary.image_velocity
        law[LAW_BODY_ACC] = self.body_force_amplitude
        law[LAW_LX], law[LAW_LY], law[LAW_LZ] = box.lx, box.ly, box.lz
        return law

    def describe(self) -> dict[str, float]:
        """Derived numbers worth printing and storing in provenance."""
        return {
            "box": list(self.box.lengths),
            "volume_fraction": self.box.volume_fraction(self.preset.particles, self.scene.diameter),
            "mass": self.mass,
            "contact_time": self.contact_time,
            "dt": self.dt,
            "steps_per_frame": self.steps_per_frame,
            "spinup_frames": self.spinup_frames,
            "first_frame_time": self.first_frame_time,
            "total_steps_per_sim": self.total_steps,
            "relaxation_time": self.relaxation_time,
            "body_force_amplitude": self.body_force_amplitude,
            "damping_ratio": damping_ratio(self.scene.restitution),
            "list_cutoff": self.list_cutoff,
        }


def _plain(node: Mapping[str, Any]) -> dict[str, Any]:
    """A plain dict from a dict or an OmegaConf node (resolving interpolations)."""
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(node, DictConfig):
            return OmegaConf.to_container(node, resolve=True)  # type: ignore[return-value]
    except ImportError:  # pragma: no cover
        pass
    return dict(node)
