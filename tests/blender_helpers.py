"""bpy (Blender as a Python module) for the Blender tests: imported for real, skipped only
outside CI when it is not installed (in CI, CI=true, a missing bpy fails the tests)."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import pytest
from cmu import DATA, ROOT

BLENDER_DIR = ROOT / "blender"


def require_bpy() -> Any:
    """The bpy module; a skip (outside CI) or an ImportError (in CI) when it is missing."""
    try:
        import bpy
    except ImportError:
        if os.environ.get("CI") == "true":
            raise
        pytest.skip("bpy is not installed (pip install 'bpy==4.2.*')", allow_module_level=True)
    if str(BLENDER_DIR) not in sys.path:
        sys.path.insert(0, str(BLENDER_DIR))
    return bpy


def import_clip(bpy: Any, name: str, rotate_mode: str = "NATIVE") -> Any:
    """A fresh empty scene with one clip imported by Blender's BVH importer (start frame 1;
    rotations as the file's Euler order, or as quaternions)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(DATA / f"{name}.bvh"), update_scene_fps=True,
                            update_scene_duration=True, rotate_mode=rotate_mode)
    return bpy.context.active_object


def clip_path(name: str) -> Path:
    """Path of a shared BVH clip."""
    return DATA / f"{name}.bvh"
