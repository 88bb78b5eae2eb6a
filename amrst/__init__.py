"""AMRST: marker-free registration of two terrestrial laser scans of one tree."""

__version__ = "0.1.0"
