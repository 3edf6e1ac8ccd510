"""Generator parameters: scene physics and preset sizes, and the indices of the force law.

This module (indices) and :mod:`gripdem.dem.config` (values) are the one place where the
constants of the force law are defined and derived (docs/spec/dem.md#default-parameters). The
numba and torch kernels both read the packed array built by
:meth:`gripdem.dem.config.GeneratorConfig.force_law`, indexed by the ``LAW_*`` constants below;
neither kernel derives a coefficient of its own.

Two config groups feed it (``conf/scene/*.yaml`` = physics, ``conf/preset/*.yaml`` = sizes);
:meth:`gripdem.dem.config.GeneratorConfig.from_mappings` checks that every key is known and present.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

#: Bump when a change of the generator changes its output for the same configuration: the
#: dataset cache is keyed by this version and the configuration.
GENERATOR_VERSION = "2"  # 2: the kernels with fastmath flags (0.3.0)
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
#: engine could not notice); 10 keeps a 4x margin and resolves a collision
#: (docs/spec/dem.md#step-and-cost: ~30).
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


def dataclass_from_mapping(cls, values: Mapping[str, Any], group: str):
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
