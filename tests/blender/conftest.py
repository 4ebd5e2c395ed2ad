"""Shared fixtures for the tests that need the bpy module."""
import os
import pathlib

import pytest

bpy = pytest.importorskip("bpy")

REPO = pathlib.Path(__file__).resolve().parents[2]


def find_scenes():
    """The public scene suite: $MPP_SCENES, else ``shared/scenes`` beside the checkout (in
    the repository's parent folder)."""
    if os.environ.get("MPP_SCENES"):
        return pathlib.Path(os.environ["MPP_SCENES"]).resolve()
    return (REPO.parent / "shared" / "scenes").resolve()


SCENES = find_scenes()


@pytest.fixture
def registered():
    """The MPP engine and its scene settings registered (use with
    ``pytestmark = pytest.mark.usefixtures("registered")``)."""
    from mpp_render.blender import engine, properties
    properties.register()
    engine.register()
    yield


@pytest.fixture
def empty_scene():
    """A factory-empty file with a world; returns bpy.context.scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.world = bpy.data.worlds.new("World")
    return sc


@pytest.fixture
def scenes_dir():
    assert SCENES.is_dir(), f"public scene suite missing at {SCENES}"
    return SCENES
