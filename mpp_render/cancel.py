"""Esc as an exception, for every layer of the core (no bpy).

``should_cancel`` is a callable the caller passes down (Blender's ``test_break``, a viewport
that has a newer picture to make); where it is polled and says yes, ``Cancelled`` is raised,
from the kernels' drivers (kernels.trace_paths) up to the stages (parallel.run_chunks), and
the render catches it and returns what it has (render.RenderOutput.cancelled)."""
from __future__ import annotations


class Cancelled(Exception):
    """Esc: ``should_cancel()`` turned true."""


def check(should_cancel) -> None:
    """Raise Cancelled when ``should_cancel`` (None: never) says so."""
    if should_cancel is not None and should_cancel():
        raise Cancelled
