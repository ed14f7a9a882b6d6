"""Tri-DehazeGS: clean 3D Gaussian reconstruction from hazy multi-view photos.

The plugin package holds the registry, the method presets and the command-line tools;
building blocks live in ``components`` and assembly/training in ``pipelines``.
"""

__version__ = "0.1.0"
