"""Tests of components.metrics."""
