"""Figures on their own Agg canvas, saved atomically and turned into images for TensorBoard.

A figure is drawn once: the PNG is encoded from the same RGBA buffer that TensorBoard's image
comes from (``savefig`` would lay out and draw it a second time, about half of a run's figure
time)."""

from __future__ import annotations

import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from gripdem.data.h5io import atomic_path


def new_figure(width: float = 6.4, height: float = 4.4) -> Figure:
    """A figure with its own Agg canvas (no pyplot state)."""
    fig = Figure(figsize=(width, height), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def figure_to_array(fig: Figure) -> np.ndarray:
    """RGB image ``(height, width, 3)`` uint8 of a figure, for
    ``SummaryWriter.add_image(tag, image, step, dataformats="HWC")``."""
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def save_figure(fig: Figure, path: str | os.PathLike, overwrite: bool = True) -> np.ndarray:
    """Write ``fig`` as PNG atomically and return its RGB array (see :func:`figure_to_array`);
    the figure is drawn once, at its own dpi, for both."""
    image = figure_to_array(fig)
    with atomic_path(path, overwrite) as tmp:
        Image.fromarray(image).save(tmp, format="png", dpi=(fig.dpi, fig.dpi))
    return image
