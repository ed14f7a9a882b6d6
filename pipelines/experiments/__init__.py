"""Experiment drivers above single runs: ablations, the speed-accuracy trade-off, the probe bench."""
