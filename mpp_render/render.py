"""The render pipeline: scene description -> per-light precompute -> march -> passes.

(Interface fixed; implementation in progress.)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import numpy as np

from .scene import SceneDescription


@dataclass
class RenderOutput:
    """``passes``: name -> float32 (height, width, channels), row 0 at the top.
    ``timings``: seconds per stage ('precompute', 'march').  ``warnings``: messages for the
    user.  ``cancelled``: True when ``should_cancel`` stopped the render early (the passes
    then hold what was finished, zeros elsewhere)."""

    passes: Dict[str, np.ndarray]
    timings: Dict[str, float] = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    cancelled: bool = False


def render(desc: SceneDescription,
           progress: Optional[Callable[[float, str], None]] = None,
           should_cancel: Optional[Callable[[], bool]] = None) -> RenderOutput:
    """Render one frame.  ``progress(fraction, message)`` is called between tiles;
    ``should_cancel()`` is polled between tiles and precompute chunks (Esc)."""
    raise NotImplementedError
