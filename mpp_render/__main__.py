"""``python -m mpp_render render|compare|demo``: see ``mpp_render.cli``."""
import sys

from .cli import main

sys.exit(main())
