"""The package version (one place; written into run folders and exported graphs)."""

__version__ = "0.1.0"
