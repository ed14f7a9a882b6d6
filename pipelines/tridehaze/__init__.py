"""The Tri-DehazeGS method on the engine: the Gaussian pipeline with its medium, the haze priors,
the haze probe, the depth warm-up and the registered method presets."""
