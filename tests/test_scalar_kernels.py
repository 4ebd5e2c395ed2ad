"""The C kernels' scalar code, which CPUs without SSE2 run (common.h's corner_sums; MPP_NO_SIMD
builds it here), gives the SSE2 build's results bit for bit: a separate build in a scratch
copy, run in a subprocess, against this process's build on the same inputs."""
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpp_render import kernels

REPO = Path(__file__).resolve().parents[1]

# the march of test_kernels' random media under every light kind, through the precompute
# (whose trilinear reads take the same sums), written to OUT as npz
SCRIPT = r"""
import sys
import numpy as np
from mpp_render import kernels
from mpp_render.kernels import MarchResult
from test_kernels import all_lights, random_march

assert kernels.backend() == "c", kernels.backend()
_, pre, inputs = random_march(np.random.default_rng(11), all_lights(), 2.0, 600)
r = kernels.march(inputs, backend="c")
fields = {f"field{i}": np.asarray(f) for i, f in enumerate(pre.fields)}
np.savez(sys.argv[1], simd=kernels._c.SIMD, **fields,
         **{name: np.asarray(v) for name, v in zip(MarchResult._fields, r)})
"""


def _run(work: Path, out: Path, env: dict) -> dict:
    (work / "tests" / "scalar_march.py").write_text(SCRIPT)
    run = subprocess.run([sys.executable, "scalar_march.py", str(out)], cwd=work / "tests",
                         env=dict(env, PYTHONPATH=f"{work}{os.pathsep}{work / 'tests'}"),
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    return dict(np.load(out))


@pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")
def test_the_scalar_kernels_give_the_simd_kernels_results_bit_for_bit(tmp_path):
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert kernels._c.SIMD == 1   # this machine's build sums in SSE2
    scalar = tmp_path / "scalar"
    shutil.copytree(REPO / "mpp_render", scalar / "mpp_render",
                    ignore=shutil.ignore_patterns("*.so", "*.pyd", "__pycache__", "blender"))
    shutil.copy(REPO / "setup.py", scalar / "setup.py")
    (scalar / "tests").mkdir()
    for name in ("test_kernels.py", "rays.py"):
        shutil.copy(REPO / "tests" / name, scalar / "tests" / name)
    env = dict(os.environ, CFLAGS="-DMPP_NO_SIMD")
    build = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"],
                           cwd=scalar, env=env, capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-3000:]
    got = _run(scalar, tmp_path / "scalar.npz", dict(os.environ))
    assert int(got["simd"]) == 0
    # the same script on this repository's own build
    here = tmp_path / "here"
    (here / "tests").mkdir(parents=True)
    for name in ("test_kernels.py", "rays.py"):
        shutil.copy(REPO / "tests" / name, here / "tests" / name)
    (here / "mpp_render").symlink_to(REPO / "mpp_render")
    ref = _run(here, tmp_path / "simd.npz", dict(os.environ))
    assert set(got) == set(ref)
    lit = ref["single"] + ref["multiple"]
    assert np.all(np.isfinite(lit)) and lit.max() > 0.0
    for name in ref:
        if name == "simd":
            continue
        np.testing.assert_array_equal(got[name], ref[name], err_msg=name)
