"""Trajectory data: the HDF5 schema, importers, windows, features, graphs, DataModules."""
