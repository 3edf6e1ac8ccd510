"""Generator configuration: scene physics + preset sizes, and every derived constant.

This module is the one place where the constants of the force law are defined and derived
(SPEC §9). The numba and torch kernels both read the packed array built by
:meth:`GeneratorConfig.force_law`, indexed by the ``LAW_*`` constants below; neither kernel
derives a coefficient of its own.

Two config groups feed it (``conf/scene/*.yaml`` = physics, ``conf/preset/*.yaml`` = sizes);
:meth:`GeneratorConfig.from_mappings` checks that every key is known and present.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripdem.boundary import Boundary, Box, LeesEdwards, check_volume_fraction

#: Bump when a change of the generator changes its output for the same configuration: the
#: dataset cache is keyed by this version and the configuration.
GENERATOR_VERSION = "1"
GENERATOR_NAME = "gripdem.dem"

# Indices into the packed force-law array (numba reads them as compile-time constants).
LAW_KN = 0  # normal spring stiffness k_n, N/m
LAW_DAMP_RATIO = 1  # normal damping ratio zeta (c_n = 2 zeta sqrt(m_eff k_n)), from restitution
LAW_KT = 2  # tangential spring stiffness k_t, N/m
LAW_MU = 3  # Coulomb friction coefficient
LAW_HAMAKER = 4  # Hamaker constant A, J (0: no cohesion)
LAW_COH_HMIN = 5  # cohesion regularisation gap, m
LAW_COH_HCUT = 6  # cohesion cut-off gap, m
LAW_LUB_VISC = 7  # lubrication viscosity, Pa s (0: no lubrication)
LAW_LUB_HMIN = 8  # lubrication regularisation gap, m
LAW_LUB_HCUT = 9  # lubrication cut-off gap, m
LAW_DRAG_VISC = 10  # Stokes drag viscosity, Pa s (0: no drag)
LAW_SHEAR_RATE = 11  # background flow u_z = shear_rate * x (drag target; LE scene)
LAW_IMAGE_VEL = 12  # z velocity of the +x image cell (shear_rate * lx; 0 when periodic)
LAW_BODY_ACC = 13  # body acceleration amplitude a in a_z = a cos(2 pi x / lx), m/s^2
LAW_LX = 14
LAW_LY = 15
LAW_LZ = 16
LAW_SIZE = 17

#: moment of inertia of a solid sphere / (m r^2); also the effective tangential mass factor
SOLID_SPHERE_INERTIA = 0.4
TANGENTIAL_MASS_FACTOR = 2.0 / 7.0

#: fewest DEM steps per contact time accepted. The explicit spring-dashpot step diverges near
#: 2-3 steps per contact (measured on the tiny LE scene: 3 stays at the 30-step overlaps, 2
#: lets particles pass through each other at 1000x the flow speed without any NaN, so the
#: engine could not notice); 10 keeps a 4x margin and resolves a collision (SPEC §9: ~30).
MIN_STEPS_PER_CONTACT = 10.0
#: the DEM step must stay below this fraction of every damping time m / c (Stokes drag and
#: regularised lubrication): explicit damping diverges at dt = 2 m / c, a 4x margin.
MAX_STEP_PER_DAMPING_TIME = 0.5


def damping_ratio(restitution: float) -> float:
    """Damping ratio zeta of a linear spring-dashpot whose head-on restitution coefficient
    is ``restitution`` (contact ends when the overlap returns to zero):
    ``e = exp(-pi zeta / sqrt(1 - zeta^2))``."""
    if not 0.0 < restitution <= 1.0:
        raise ValueError(f"restitution must lie in (0, 1], got {restitution!r}")
    log_e = math.log(restitution)
    return -log_e / math.sqrt(math.pi**2 + log_e**2)


@dataclass(frozen=True)
class SceneParams:
    """Physics of a scene (``conf/scene/*.yaml``); SI units, gaps in particle diameters."""

    name: str
    boundary: str  # "periodic" | "lees_edwards"
    shear_rate: float  # LE shear rate, 1/s (0 for periodic)
    body_force_amplitude: float | None  # a in m/s^2; None: derived from body_force_shear_rate
    body_force_shear_rate: float  # peak shear rate the derived a aims at (periodic), 1/s
    volume_fraction: float
    diameter: float
    density: float
    stiffness: float  # k_n
    tangential_stiffness_ratio: float  # k_t / k_n
    restitution: float
    friction: float
    fluid_viscosity: float  # Stokes drag; 0 switches drag off
    hamaker: float
    cohesion_min_gap_d: float
    cohesion_cutoff_gap_d: float
    lubrication_viscosity: float  # 0 switches lubrication off
    lubrication_min_gap_d: float
    lubrication_cutoff_gap_d: float

    def __post_init__(self) -> None:
        if self.boundary not in ("periodic", "lees_edwards"):
            raise ValueError(
                f"scene.boundary must be 'periodic' or 'lees_edwards', got {self.boundary!r}"
            )
        if self.boundary == "periodic" and self.shear_rate != 0:
            raise ValueError(
                "scene.shear_rate is the Lees-Edwards rate: it must be 0 for a periodic scene"
            )
        if self.boundary == "lees_edwards" and not self.shear_rate > 0:
            raise ValueError(
                f"scene.shear_rate must be > 0 for lees_edwards, got {self.shear_rate!r}"
            )
        for name in ("diameter", "density", "stiffness", "volume_fraction"):
            if not getattr(self, name) > 0:
                raise ValueError(f"scene.{name} must be > 0, got {getattr(self, name)!r}")
        for name in (
            "friction",
            "fluid_viscosity",
            "hamaker",
            "lubrication_viscosity",
            "tangential_stiffness_ratio",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"scene.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.hamaker > 0 and not 0 < self.cohesion_min_gap_d < self.cohesion_cutoff_gap_d:
            raise ValueError("scene: need 0 < cohesion_min_gap_d < cohesion_cutoff_gap_d")
        if self.lubrication_viscosity > 0 and not (
            0 < self.lubrication_min_gap_d < self.lubrication_cutoff_gap_d
        ):
            raise ValueError("scene: need 0 < lubrication_min_gap_d < lubrication_cutoff_gap_d")
        damping_ratio(self.restitution)


@dataclass(frozen=True)
class PresetParams:
    """Sizes and numerics of a run (``conf/preset/*.yaml``)."""

    name: str
    particles: int
    box_aspect: tuple[float, float, float]  # relative box lengths; scaled to volume_fraction
    frames: int
    frame_interval: float  # s between written frames
    sims: int
    spinup_time: float  # s of driven flow before the first written frame
    steps_per_contact: float  # dt = contact time / steps_per_contact (rounded per frame)
    skin_d: float  # neighbour-list skin, diameters
    pack_volume_fraction: float  # random insertion here, then growth to volume_fraction

    def __post_init__(self) -> None:
        if self.particles < 2 or self.frames < 2 or self.sims < 1:
            raise ValueError("preset: need particles >= 2, frames >= 2, sims >= 1")
        if len(self.box_aspect) != 3 or min(self.box_aspect) <= 0:
            raise ValueError(
                f"preset.box_aspect must be 3 positive numbers, got {self.box_aspect!r}"
            )
        if not (
            self.frame_interval > 0
            and self.spinup_time >= 0
            and self.steps_per_contact > 0
            and self.skin_d > 0
        ):
            raise ValueError(
                "preset: frame_interval, steps_per_contact, skin_d must be > 0 and spinup_time >= 0"
            )


def _dataclass_from_mapping(cls, values: Mapping[str, Any], group: str):
    values = dict(values)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise ValueError(f"unknown key(s) in {group} config: {unknown}; known keys: {names}")
    missing = [n for n in names if n not in values]
    if missing:
        raise ValueError(f"missing key(s) in {group} config: {missing}")
    if "box_aspect" in values:
        values["box_aspect"] = tuple(float(v) for v in values["box_aspect"])
    for f in dataclasses.fields(cls):
        v = values[f.name]
        if v is not None and f.type in ("float", "float | None"):
            values[f.name] = float(v)
        elif f.type == "int":
            values[f.name] = int(v)
    return cls(**values)


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
        scene_p = _dataclass_from_mapping(SceneParams, _plain(scene), "scene")
        preset_p = _dataclass_from_mapping(PresetParams, _plain(preset), "preset")
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
        # time origin 0 = start of the driven spin-up: frame times are absolute (SPEC §9)
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
        """Refuse a DEM step the explicit integrator cannot take (SPEC §9: dt ~ contact time
        / 30): fewer than :data:`MIN_STEPS_PER_CONTACT` steps per contact time, or a step
        above :data:`MAX_STEP_PER_DAMPING_TIME` of a damping time. The message names the
        option that sets the step and the coefficient that makes it too large."""
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
