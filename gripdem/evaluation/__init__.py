"""Evaluation: the LE-aware RMSE and its splits (metrics), the physics of a flow (g(r),
coordination, MSD, non-affine displacements, velocity profiles, overlaps), the physics report of
a prediction beside the truth and the baselines, the ``predictions.h5`` file that holds what a
run predicted, and the sweep summaries and claims over seeds. Works on arrays and files only:
nothing here trains or draws.
"""
