"""The built-in DEM generator (SPEC §9): the embedded default data source.

params (scene physics + preset sizes, every force-law constant) -> packing (initial state)
-> engine (state, neighbour-list rebuilds; kernels in forces_numba / forces_torch)
-> scenes (spin-up, frames, S simulations) -> validation (report) -> output (validated HDF5).
Entry points: ``python -m gripdem.simulate`` and :func:`gripdem.dem.output.ensure_scene_dataset`.
"""
