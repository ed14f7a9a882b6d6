"""Hazy data with exact ground truth (``td-synth``).

* a procedural scene generator: layouts of analytic primitives with procedural textures, traced
  per pixel (``geometry``, ``textures``, ``layouts``, ``trajectories``, ``render``);
* a known participating medium, beta(x) and L(x, v), ray-marched with the method's own
  discretisation (``medium``, ``march``), written as a nerfstudio dataset (``generate``, ``writer``);
* haze added to an existing clean dataset from depth maps or a trained run (``haze_existing``);
* the built-in demo scene (``demo.demo_scene_path``) and a preset gallery (``gallery``).

See docs/synth.md.
"""

from components.synth.demo import demo_scene_path

__all__ = ["demo_scene_path"]
