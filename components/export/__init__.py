"""Exports of a trained run: the clean Gaussians as a 3DGS PLY and the medium as a grid (docs/export.md)."""
