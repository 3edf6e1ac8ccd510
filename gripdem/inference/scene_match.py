"""How close a dataset's scene must be to a model's training scene (used by
:func:`gripdem.inference.checkpoint.check_compatible`).

What a gripdem model reads, and in which units (``gripdem.models.module``,
``gripdem.nn.contact``, ``gripdem.data.graph``; ``gripdem.predict`` builds the model with
the DATA's scene):

- geometry, in the data's own units: pair vectors and surface gaps in the data's diameter
  (graph, contact gaps, cut-off in diameters), the x phase ``2 pi x / lx`` and the sin/cos
  features with the data's box, wrapping and Lees-Edwards offsets from the data's box, shear
  rate, sign and time origin, the affine flow removed with the data's strain per frame
  (shear rate x frame interval). Dimensionless, and exact in any scene;
- motion, in the training scene's units: observed steps (metres per frame) over the model's
  velocity unit (the spread of the training data's steps across the flow) or over the
  normaliser's statistics (paper encodings: sin/cos differences per frame), and the output in
  the training data's velocity-change unit. Dimensionless, but a scene whose velocity scale
  differs moves them: the steps scale with the frame interval times the velocity scale, and
  that with the shear rate x d (Lees-Edwards) or with the drive, A tau_p (periodic, tau_p ~ d^2),
  so a relative difference e in diameter, frame interval, shear rate or body force shifts the
  step inputs by about e; a box e larger lowers the volume fraction by about 3 e (same count)
  and stretches the periodic drive's wavelength by e.

Every model's inputs are therefore dimensionless, and a scene within :data:`SCENE_TOLERANCE`
(1 %) of the training scene gives inputs within about 1 % of the training scene's: less than
the spread of the velocity unit between simulations of one scene (1.1 % in the default
Lees-Edwards scene, 1.3 % in the periodic one, six simulations each), which training already
covers. Such a model is applied with the data's own values and a note says what differs;
beyond the tolerance it is refused, naming the field, both values and the tolerance. Exception
kept from before: exact-frame ``grip`` models of the sheared scene without x-position features
read relative geometry only and are applied in any box.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

#: a scene parameter may differ from the training scene's by this relative amount (see above)
SCENE_TOLERANCE = 0.01
#: below this relative difference two values are the same (float round-off of a frame
#: interval averaged over frames, of a box written in decimal); nothing is noted
SAME_RTOL = 1e-6

#: per field: what a difference means when accepted (within the tolerance) and when refused
CONSEQUENCE = {
    "box": "applied in the data's box",
    "diameter": "pair geometry measured in the data's diameter",
    "frame_interval": "one predicted frame per data frame interval",
    "shear_rate": "offsets and affine flow from the data's shear rate",
    "body_force_amplitude": "the model predicts the flow of its own drive",
}
REFUSAL = {
    "box": "the volume fraction and the drive's wavelength differ from the training scene's",
    "diameter": "another particle size moves the step inputs and the contact scale",
    "frame_interval": "the model predicts one frame of its own scene per step",
    "shear_rate": "another shear rate, another flow",
    "body_force_amplitude": "another drive, another flow (a_z = A cos(2 pi x / lx), m/s^2)",
}


def relative_difference(model: float | Sequence[float], data: float | Sequence[float]) -> float:
    """Signed relative difference ``data / model - 1`` (the largest in size over components;
    ``inf`` when the model's value is 0 and the data's is not)."""
    m = np.atleast_1d(np.asarray(model, np.float64))
    d = np.atleast_1d(np.asarray(data, np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(m != 0, (d - m) / np.abs(m), np.where(d == m, 0.0, np.inf * np.sign(d)))
    return float(rel[np.argmax(np.abs(rel))])


def _value(v) -> str:
    values = np.atleast_1d(np.asarray(v, np.float64))
    if values.size > 1 and np.all(values == values[0]):
        return f"{values[0]:.5g}"
    if values.size > 1:
        return "(" + ", ".join(f"{x:.5g}" for x in values) + ")"
    return f"{values[0]:.5g}"


def _percent(rel: float) -> str:
    if not math.isfinite(rel):
        return "from zero"
    p = 100 * rel
    return f"{p:+.2g} %" if abs(p) < 1 else f"{p:+.1f} %"


def compare(
    field: str,
    model,
    data,
    fail: Callable[[str, str], Exception],
    tolerance: float = SCENE_TOLERANCE,
    beyond_ok: str | None = None,
    why: str | None = None,
) -> str | None:
    """``None`` when ``data`` equals ``model`` (``SAME_RTOL``), a note when it lies within
    ``tolerance`` (or beyond it with ``beyond_ok``, the reason it is harmless), else raises
    ``fail(field, message)`` naming both values and the tolerance (and ``why`` it matters)."""
    rel = relative_difference(model, data)
    if abs(rel) <= SAME_RTOL:
        return None
    told = (
        f"{field}: data {_value(data)} vs model {_value(model)} ({_percent(rel)}), "
        f"{{}} the {100 * tolerance:g} % tolerance"
    )
    if abs(rel) <= tolerance:
        return told.format("within") + f", {CONSEQUENCE[field]}"
    if beyond_ok is not None:
        return told.format("beyond") + f", {CONSEQUENCE[field]}: {beyond_ok}"
    raise fail(field, told.format("beyond") + f": {why or REFUSAL[field]}")
