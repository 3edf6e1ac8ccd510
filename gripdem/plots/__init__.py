"""Figures drawn from computed reports: the run figures (from
:class:`gripdem.evaluation.figure_data.RunFigureData`), the physics figure (from a
:class:`gripdem.evaluation.physics_report.PhysicsReport`) and the long-rollout figure. Every
function returns a matplotlib ``Figure`` on its own Agg canvas (no pyplot, no global backend
switch, safe in sweep workers); nothing here computes a metric.
"""

from gripdem.plots.common import figure_to_array, new_figure, save_figure

__all__ = ["figure_to_array", "new_figure", "save_figure"]
