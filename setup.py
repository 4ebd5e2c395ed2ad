"""Builds mpp_render's compiled kernels (``mpp_render._kernels``) from C source.

One extension from every ``mpp_render/csrc/*.c`` (one file per kernel over shared headers;
``module.c`` holds the method table).  ``python setup.py build_ext --inplace`` puts the module
next to its numpy twins; tools/dev.sh does this before tests and renders.  ``MPP_SANITIZE=1``
builds with AddressSanitizer and UndefinedBehaviorSanitizer for the robustness tests.
"""
import glob
import os

from setuptools import Extension, setup

CSRC = "mpp_render/csrc"
# hidden visibility: the kernels' shared helpers link across the files without being exported
cflags = ["-O3", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter", "-fno-math-errno",
          "-fvisibility=hidden"]
ldflags = []
if os.environ.get("MPP_SANITIZE"):
    cflags = ["-O1", "-g", "-std=c99", "-fsanitize=address,undefined", "-fno-sanitize-recover=undefined",
              "-fno-omit-frame-pointer", "-fvisibility=hidden"]
    ldflags = ["-fsanitize=address,undefined"]

setup(
    name="mpp_render_kernels",
    version="0.1.0",
    ext_modules=[Extension("mpp_render._kernels", sorted(glob.glob(f"{CSRC}/*.c")),
                           depends=sorted(glob.glob(f"{CSRC}/*.h")),
                           extra_compile_args=cflags, extra_link_args=ldflags)],
)
