"""patchcloud's version: the one place it is written (pyproject.toml reads it from here), so that neither
``import patchcloud`` nor writing an output reads the installed package's metadata (``importlib.metadata``: 36 ms of
every process)."""

__all__ = ["__version__"]

__version__ = "0.1.0"
