"""Procedurally rendered image sequences for tests, encoder studies and demos.

A pinhole camera moves along a route through a procedurally generated street
or indoor corridor (textured facades or walls, ground, sky or ceiling, trees,
lamps, signs, parked cars, ...). Every traverse of a scene has its own
conditions (time of day, season, weather, camera noise and blur, lateral
offset and yaw jitter, speed profile with stops) and comes with metric ground
truth. Scenes are described by JSON specs; builtin ones live in
``data/synthetic/``.

Main entry points: :func:`load_spec`, :func:`render_scene` (in memory),
:func:`write_scene` (PNG folders + ``ground_truth.csv`` + ``scene.json``, what
the ``vpr render`` command runs), :func:`gt_matrix` and :func:`loop_pairs`.
"""
from .output import contact_sheet, write_scene
from .scene import Scene, SceneRenderer, Traverse, gt_matrix, loop_pairs, render_scene
from .spec import builtin_spec_path, builtin_specs, load_spec

__all__ = [
    "load_spec", "builtin_spec_path", "builtin_specs",
    "Traverse", "Scene", "SceneRenderer", "render_scene", "gt_matrix", "loop_pairs",
    "write_scene", "contact_sheet",
]
