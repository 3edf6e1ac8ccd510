"""gripdem: graph-based interaction-aware trajectory forecasts for DEM unit cells."""

__version__ = "0.1.0"
