"""Rendering and scoring trained runs: test-view metrics, reports, figures and camera paths."""
