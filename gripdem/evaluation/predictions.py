"""``predictions.h5``: the test-window predictions of one run, enough to recompute every metric.

Layout (lengths in the source data's units, metres by default; times in seconds)::

    /pred_positions   (windows, f, particles, 3)  model prediction, wrapped Cartesian
    /true_positions   (windows, f, particles, 3)  float64 truth, wrapped
    /last_positions   (windows, particles, 3)     float64 last observed frame, wrapped
    /times            (windows, f)                float64 absolute times of the predicted frames
    /sim_index        (windows,) int64            optional: simulation each window comes from
    /window_start     (windows,) int64            optional: first frame of each window
    /baseline/<name>  (windows, f, particles, 3)  optional: a baseline's prediction (stay, ...)
    attrs:
      format = "gripdem-predictions", format_version = 1
      box, boundary, shear_rate, le_sign, le_time_origin   as in gripdem.data.schema
      radius, body_force_amplitude                         of the source data
      frame_interval    seconds between frames (also between the last observed and first target)
      in_sample         true when the windows were also trained on (the in_sample protocol)
      protocol          "sims" | "time" | "in_sample" (how train/val/test were separated;
                        a file written before gripdem 0.1's rename says "paper": read as
                        "in_sample")
      run               JSON: free-form run description (scene, split, model, ...)

The LE offset of predicted frame j of window w is ``Boundary.offset(times[w, j])``; the truth
is compared with the prediction at the same frame (that frame's offset), displacements between
frames use the later frame's offset (docs/spec/conventions.md#which-offset).
:func:`gripdem.evaluation.evaluate.evaluate_predictions` recomputes all metrics from the file alone.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from gripdem.boundary import Boundary, Box
from gripdem.data.dataset_io import boundary_from_attrs, read_attr, read_float_attr
from gripdem.data.h5io import atomic_h5_write
from gripdem.data.protocols import current_protocol
from gripdem.data.schema import DatasetError, check_shape, validate_positions

FORMAT_NAME = "gripdem-predictions"
FORMAT_VERSION = 1
PROTOCOLS = ("sims", "time", "in_sample")


def _numpy(values) -> np.ndarray:
    return np.asarray(values.detach().cpu() if hasattr(values, "detach") else values)


def _float_array(values) -> np.ndarray:
    """float32 stays float32 (a model's own precision), everything else becomes float64."""
    arr = _numpy(values)
    return arr if arr.dtype == np.float32 else arr.astype(np.float64)


@dataclass
class Predictions:
    """Predictions of one run on its evaluation windows (see the module docstring for shapes).

    ``frame_interval`` defaults to the spacing of ``times`` (needs a horizon of at least 2).
    ``info`` describes the run (scene, split, model, ...) for titles and tables.
    """

    pred_positions: np.ndarray
    true_positions: np.ndarray
    last_positions: np.ndarray
    times: np.ndarray
    boundary: Boundary
    radius: float
    frame_interval: float | None = None
    in_sample: bool = False
    protocol: str = "sims"
    sim_index: np.ndarray | None = None
    window_start: np.ndarray | None = None
    baselines: dict[str, np.ndarray] = field(default_factory=dict)
    body_force_amplitude: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # torch tensors (a LightningModule's outputs) become numpy; a float32 prediction stays
        self.pred_positions = _float_array(self.pred_positions)
        self.baselines = {k: _float_array(v) for k, v in self.baselines.items()}
        for name in ("true_positions", "last_positions", "times"):
            setattr(self, name, np.asarray(_numpy(getattr(self, name)), dtype=np.float64))
        for name in ("sim_index", "window_start"):
            if getattr(self, name) is not None:
                setattr(self, name, np.asarray(_numpy(getattr(self, name))))
        if self.frame_interval is None:
            times = np.asarray(self.times, dtype=np.float64)
            if times.ndim != 2 or times.shape[1] < 2:
                raise ValueError(
                    "frame_interval is needed when the horizon has fewer than 2 frames"
                )
            self.frame_interval = float(np.median(np.diff(times, axis=1)))
        self.frame_interval = float(self.frame_interval)

    @property
    def box(self) -> Box:
        return self.boundary.box

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius

    @property
    def n_windows(self) -> int:
        return int(self.true_positions.shape[0])

    @property
    def horizon(self) -> int:
        return int(self.true_positions.shape[1])

    @property
    def n_particles(self) -> int:
        return int(self.true_positions.shape[2])

    def offsets(self) -> np.ndarray:
        """float64 LE offsets of the predicted frames ``(windows, horizon)`` (zeros if
        periodic)."""
        return self.boundary.offset(self.times)

    @property
    def offset_increment(self) -> float:
        """Unwrapped growth of the LE offset per frame (0 for a periodic box)."""
        return self.boundary.image_velocity * self.frame_interval

    def title(self) -> str:
        """``scene / split / model`` from ``info`` (what is known), with the protocol."""
        parts = [str(self.info[k]) for k in ("scene", "split", "model") if self.info.get(k)]
        label = " / ".join(parts) if parts else self.boundary.kind
        return f"{label} ({'in-sample' if self.in_sample else 'out-of-sample'}, {self.protocol})"


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------
def _check_positions(path, name: str, array: np.ndarray, box: Box) -> None:
    if not np.issubdtype(array.dtype, np.floating):
        raise DatasetError(path, name, f"expected floating-point values, got {array.dtype}")
    validate_positions(path, array, box, field=name)


def validate(p: Predictions, path=None) -> None:
    """Shapes agree, positions finite and inside the box, times finite, flags sensible."""
    true = np.asarray(p.true_positions)
    check_shape(path, "true_positions", true, (None, None, None, 3), "(windows, f, particles, 3)")
    w, f, n, _ = true.shape
    if min(w, f, n) == 0:
        raise DatasetError(path, "true_positions", f"expected non-empty arrays, got {true.shape}")
    box = p.box
    _check_positions(path, "true_positions", true, box)
    pred = np.asarray(p.pred_positions)
    check_shape(path, "pred_positions", pred, true.shape, f"{true.shape} like true_positions")
    _check_positions(path, "pred_positions", pred, box)
    for name, arr in p.baselines.items():
        arr = np.asarray(arr)
        check_shape(path, f"baseline/{name}", arr, true.shape, f"{true.shape}")
        _check_positions(path, f"baseline/{name}", arr, box)
    last = np.asarray(p.last_positions)
    check_shape(path, "last_positions", last, (w, n, 3), f"(windows, particles, 3) = {(w, n, 3)}")
    _check_positions(path, "last_positions", last, box)
    times = np.asarray(p.times)
    check_shape(path, "times", times, (w, f), f"(windows, f) = {(w, f)}")
    if not np.isfinite(times).all():
        raise DatasetError(path, "times", "expected finite absolute frame times")
    for name in ("sim_index", "window_start"):
        value = getattr(p, name)
        if value is not None:
            check_shape(path, name, np.asarray(value), (w,), f"(windows,) = ({w},)")
    if not (np.isfinite(p.radius) and p.radius > 0):
        raise DatasetError(path, "radius", f"expected a positive radius, got {p.radius!r}")
    if not (np.isfinite(p.frame_interval) and p.frame_interval > 0):
        raise DatasetError(
            path, "frame_interval", f"expected a positive interval, got {p.frame_interval!r}"
        )
    if p.protocol not in PROTOCOLS:
        raise DatasetError(path, "protocol", f"expected one of {PROTOCOLS}, got {p.protocol!r}")
    if (p.protocol == "in_sample") != bool(p.in_sample):
        raise DatasetError(
            path,
            "in_sample",
            f"expected in_sample={p.protocol == 'in_sample'} for protocol {p.protocol!r} (only "
            "the in_sample protocol evaluates on its training windows)",
        )


# --------------------------------------------------------------------------------------------
# writing and reading
# --------------------------------------------------------------------------------------------


def write_predictions(path: str | os.PathLike, p: Predictions, overwrite: bool = False) -> Path:
    """Validate and write atomically; refuses to replace an existing file unless
    ``overwrite=True``. Returns the path."""
    path = Path(path)
    validate(p, path)
    n = p.n_particles
    with atomic_h5_write(path, overwrite) as h5:
        chunks = (1, 1, n, 3)
        h5.create_dataset("pred_positions", data=_float_array(p.pred_positions), chunks=chunks)
        h5.create_dataset(
            "true_positions", data=np.asarray(p.true_positions, np.float64), chunks=chunks
        )
        h5.create_dataset("last_positions", data=np.asarray(p.last_positions, np.float64))
        h5.create_dataset("times", data=np.asarray(p.times, np.float64))
        for name in ("sim_index", "window_start"):
            value = getattr(p, name)
            if value is not None:
                h5.create_dataset(name, data=np.asarray(value, np.int64))
        group = h5.create_group("baseline")
        for name, arr in p.baselines.items():
            group.create_dataset(name, data=_float_array(arr), chunks=chunks)
        attrs = h5.attrs
        attrs["format"] = FORMAT_NAME
        attrs["format_version"] = FORMAT_VERSION
        for key, value in p.boundary.to_attrs().items():
            attrs[key] = value
        attrs["radius"] = float(p.radius)
        attrs["body_force_amplitude"] = float(p.body_force_amplitude)
        attrs["frame_interval"] = float(p.frame_interval)
        attrs["in_sample"] = bool(p.in_sample)
        attrs["protocol"] = str(p.protocol)
        attrs["run"] = json.dumps(p.info, sort_keys=True, default=str)
    return path


def read_predictions(path: str | os.PathLike) -> Predictions:
    """Read and validate a predictions file (errors name the file and the field)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such predictions file")
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise DatasetError(path, "<file>", f"expected an HDF5 file ({exc})") from None
    with h5:
        fmt = read_attr(path, h5, "format", None)
        if fmt != FORMAT_NAME:
            raise DatasetError(path, "format", f"expected {FORMAT_NAME!r}, got {fmt!r}")
        for name in ("pred_positions", "true_positions", "last_positions", "times"):
            if name not in h5:
                raise DatasetError(path, name, "missing dataset")

        def optional(name):
            return np.asarray(h5[name][()]) if name in h5 else None

        try:
            info = json.loads(read_attr(path, h5, "run", "{}"))
        except json.JSONDecodeError:
            raise DatasetError(path, "run", "expected a JSON string") from None
        p = Predictions(
            pred_positions=np.asarray(h5["pred_positions"][()]),
            true_positions=np.asarray(h5["true_positions"][()]),
            last_positions=np.asarray(h5["last_positions"][()]),
            times=np.asarray(h5["times"][()]),
            boundary=boundary_from_attrs(path, h5),
            radius=read_float_attr(path, h5, "radius"),
            frame_interval=read_float_attr(path, h5, "frame_interval"),
            in_sample=bool(read_attr(path, h5, "in_sample")),
            protocol=current_protocol(str(read_attr(path, h5, "protocol")), warn=False),
            sim_index=optional("sim_index"),
            window_start=optional("window_start"),
            baselines={k: np.asarray(v[()]) for k, v in h5.get("baseline", {}).items()},
            body_force_amplitude=read_float_attr(path, h5, "body_force_amplitude", 0.0),
            info=info,
        )
    validate(p, path)
    return p
