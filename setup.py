"""Builds mpp_render's compiled kernels (``mpp_render._kernels``) from C source.

``python setup.py build_ext --inplace`` puts the module next to its numpy twins; tools/dev.sh
does this before tests and renders.  ``MPP_SANITIZE=1`` builds with AddressSanitizer and
UndefinedBehaviorSanitizer for the robustness tests.
"""
import os

from setuptools import Extension, setup

cflags = ["-O3", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter", "-fno-math-errno"]
ldflags = []
if os.environ.get("MPP_SANITIZE"):
    cflags = ["-O1", "-g", "-std=c99", "-fsanitize=address,undefined", "-fno-sanitize-recover=undefined",
              "-fno-omit-frame-pointer"]
    ldflags = ["-fsanitize=address,undefined"]

setup(
    name="mpp_render_kernels",
    version="0.1.0",
    ext_modules=[Extension("mpp_render._kernels", ["mpp_render/_kernels.c"],
                           extra_compile_args=cflags, extra_link_args=ldflags)],
)
