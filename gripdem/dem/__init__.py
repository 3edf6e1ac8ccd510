"""The built-in DEM generator (docs/spec/dem.md): the embedded default data source.

params (scene physics, preset sizes, force-law indices) -> config (every derived constant)
-> packing (initial state) -> engine (state, neighbour-list rebuilds; kernels in forces_numba /
forces_torch) -> scenes (spin-up, frames, S simulations in worker processes that end with the
command however it ends: workers) -> validation (report) -> output
(validated HDF5, and the built-in scenes in the dataset cache). Entry points:
``python -m gripdem.simulate`` and :func:`gripdem.dem.output.ensure_scene_dataset`.
"""
