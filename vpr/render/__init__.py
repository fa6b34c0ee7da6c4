"""Procedurally rendered image sequences for tests, encoder studies and demos."""
from .output import contact_sheet, write_scene
from .scene import Scene, SceneRenderer, Traverse, gt_matrix, loop_pairs, render_scene
from .spec import builtin_spec_path, builtin_specs, load_spec

__all__ = [
    "load_spec", "builtin_spec_path", "builtin_specs",
    "Traverse", "Scene", "SceneRenderer", "render_scene", "gt_matrix", "loop_pairs",
    "write_scene", "contact_sheet",
]
