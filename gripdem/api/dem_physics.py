"""The built-in DEM and the physics report from Python: generate a scene, measure any
trajectory."""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

from gripdem.api.trajectory import Trajectory
from gripdem.config_files import config_dir
from gripdem.errors import GenerationError

if TYPE_CHECKING:
    from gripdem.evaluation.trajectory_physics import TrajectoryPhysics

#: validation checks that say whether data suits training, not whether the physics is sound: a
#: warning here (a short single simulation may have no Lees-Edwards face crossing)
ADVISORY_CHECKS = ("le_crossings_present",)
#: the configuration folder (scenes: ``conf/scene/*.yaml``, sizes: ``conf/preset/*.yaml``)
CONF_DIR = config_dir()


def _group(group: str, name: str) -> dict[str, Any]:
    from omegaconf import OmegaConf

    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
        raise ValueError(f"{group} {name!r}: no {path}; expected one of {known}")
    return dict(OmegaConf.to_container(OmegaConf.load(path), resolve=True))


def generate(
    scene: str = "pbc",
    preset: str = "tiny",
    *,
    sims: int | None = None,
    seed: int = 0,
    particles: int | None = None,
    frames: int | None = None,
    frame_interval: float | None = None,
    physics: dict[str, Any] | None = None,
    backend: str = "numba",
    workers: int | None = None,
    progress: bool = False,
    validate: bool = True,
) -> Trajectory:
    """Generate trajectories with the built-in DEM and return them in memory.

    Args:
        scene: ``"pbc"`` (periodic box, sinusoidal body force) or ``"lebc"`` (Lees-Edwards
            shear): the physics of ``conf/scene/<scene>.yaml``.
        preset: the sizes of ``conf/preset/<preset>.yaml`` (``tiny``: 400 particles x 61
            frames; ``default``: 2000 x 201).
        sims: independent simulations (default: the preset's).
        seed: the base seed (simulation ``s`` uses ``SeedSequence(seed).spawn(sims)[s]``, as
            ``python -m gripdem.simulate``).
        particles: override the preset's particle count.
        frames: override the preset's written frames per simulation.
        frame_interval: override the preset's seconds between frames.
        physics: override scene options (e.g. ``{"friction": 0.5, "shear_rate": 500.0}``).
        backend: ``"numba"`` (CPU) or ``"torch"``.
        workers: processes, one simulation each (default one per CPU).
        progress: show the DEM's progress bar.
        validate: run the plausibility checks of ``gripdem.simulate``: raise when one fails
            (finite, overlaps, the imposed profile, measurable non-affine motion); warn when
            a Lees-Edwards run has no face crossing (fine for a rollout, thin for training).

    Returns:
        a ``Trajectory`` with velocities and the generator's provenance.

    Raises:
        ValueError: an unknown scene or preset (the known ones listed), or an option the
            generator refuses (named: e.g. a volume fraction above random close packing).
        GenerationError: ``validate`` and the data failed a plausibility check (named).

    Examples:
        A small sheared scene: one simulation of 300 particles, 21 frames (the box follows
        from the particle count at the scene's volume fraction):

        >>> import gripdem
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> data.positions.shape, data.times.shape
        ((1, 21, 300, 3), (1, 21))
        >>> data.scene.boundary, data.scene.shear_rate, data.scene.diameter
        ('lees_edwards', 1000.0, 2.5e-06)
        >>> data.velocities.shape
        (1, 21, 300, 3)
        >>> data.provenance["generator"], data.provenance["parameters"]["seed"]
        ('gripdem.dem', 0)
        >>> gripdem.generate("walls")
        Traceback (most recent call last):
            ...
        ValueError: scene 'walls': no .../walls.yaml; expected one of ['lebc', 'pbc']
    """
    from gripdem.dem.config import GeneratorConfig
    from gripdem.dem.scenes import generate
    from gripdem.dem.validation import validate_trajectories

    scene_cfg = {**_group("scene", scene), **(physics or {})}
    preset_cfg = _group("preset", preset)
    for key, value in (
        ("particles", particles),
        ("frames", frames),
        ("frame_interval", frame_interval),
    ):
        if value is not None:
            preset_cfg[key] = value
    config = GeneratorConfig.from_mappings(
        scene_cfg, preset_cfg, sims=sims, seed=seed, backend=backend
    )
    data, _ = generate(config, progress=progress, workers=workers)
    if validate:
        report = validate_trajectories(data)
        failed = [k for k, ok in report.get("checks", {}).items() if not ok]
        advisory = [k for k in failed if k in ADVISORY_CHECKS]
        if advisory:
            warnings.warn(
                f"the generated data does not meet {advisory}: no particle crossed a "
                "Lees-Edwards x face (fine for a rollout, thin data for training: more "
                "frames or simulations add crossings)",
                stacklevel=2,
            )
        if set(failed) - set(advisory):
            raise GenerationError(
                f"the generated data failed the validation checks "
                f"{sorted(set(failed) - set(advisory))} (scene {scene!r}, preset {preset!r})"
            )
    return Trajectory._from_data(data)


def physics(
    trajectory: Trajectory,
    sim: int = 0,
    *,
    lags: list[int] | None = None,
    structure_frames: int = 10,
) -> TrajectoryPhysics:
    """The physics of simulation ``sim`` of ``trajectory``: g(r), contact coordination,
    overlaps, the mean-flow profile, the MSD and non-affine MSD against the lag and (from 1000
    frames) the self-diffusion coefficients; a
    ``PhysicsReport`` (``.table()`` prints it).

    The same definitions as the rollout statistics, so a DEM trajectory and a rollout
    (``RolloutResult.trajectory()``) are reported alike.

    Args:
        trajectory: any ``Trajectory``: generated, read from a file or rolled out.
        sim: which simulation of it.
        lags: of the MSD, in frames (default 1, 2, 5, 10, 20, ... up to half the frames).
        structure_frames: frames, spread evenly over the trajectory, over which g(r),
            coordination and overlaps are averaged.

    Returns:
        a ``PhysicsReport``: arrays in numpy, lengths in particle diameters.

    Raises:
        ValueError: ``sim`` outside the trajectory, or lags longer than it.

    Examples:
        The physics of a small sheared scene of the built-in DEM:

        >>> import gripdem
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> report = gripdem.physics(data)
        >>> report.frames, report.particles, report.profile_kind
        (21, 300, 'linear')
        >>> 0.95 < report.peak_over_d < 1.05  # g(r) peaks at contact, r = d
        True
        >>> abs(report.profile[0] / data.scene.shear_rate - 1) < 0.1  # the imposed shear
        True
        >>> report.lags.tolist()
        [1, 2, 5, 10]
        >>> gripdem.physics(data, sim=1)
        Traceback (most recent call last):
            ...
        ValueError: sim 1: the trajectory holds simulations 0..0
    """
    from gripdem.evaluation.trajectory_physics import trajectory_physics

    if not 0 <= sim < trajectory.n_sims:
        raise ValueError(f"sim {sim}: the trajectory holds simulations 0..{trajectory.n_sims - 1}")
    return trajectory_physics(
        trajectory.positions[sim],
        trajectory.times[sim],
        trajectory.scene.to_boundary(),
        trajectory.scene.diameter,
        lags=lags,
        structure_frames=structure_frames,
    )
