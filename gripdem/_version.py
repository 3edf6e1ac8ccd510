"""The package version (one place; ``gripdem.__version__`` re-exports it)."""

__version__ = "0.3.0"
