"""The C kernels built with AddressSanitizer and UndefinedBehaviorSanitizer pass the kernel
tests and a longer fuzz run (a separate build in a scratch copy, run in a subprocess)."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _libasan():
    cc = shutil.which("gcc") or shutil.which("cc")
    if not cc:
        return None
    path = subprocess.run([cc, "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    return path if os.path.isabs(path) and os.path.exists(path) else None


# the test files run on the sanitized build, and the files they import from tests/ (copied,
# not run): test_kernels.py's ray helper, and test_enclosed.py's scenes (test_nodal's)
RUN = ("test_fuzz.py", "test_kernels.py", "test_sweep.py", "test_skip.py", "test_pyramid.py",
       "test_paths.py", "test_paths_world.py", "test_paths_media.py", "test_sharp_surface.py",
       "test_moments.py", "test_nodal.py", "test_lobefit.py", "test_light_samples.py",
       "test_camera_roulette.py")
HELPERS = ("rays.py", "test_enclosed.py")
SEPARATE = "test_kernels.py"  # the march's twins: about as long as the rest together


@pytest.mark.skipif(_libasan() is None, reason="no gcc with AddressSanitizer on this machine")
def test_kernels_under_asan_and_ubsan(tmp_path):
    work = tmp_path / "asan"
    shutil.copytree(REPO / "mpp_render", work / "mpp_render",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__", "blender"))
    (work / "tests").mkdir()
    for name in RUN + HELPERS:
        shutil.copy(REPO / "tests" / name, work / "tests" / name)
    shutil.copy(REPO / "setup.py", work / "setup.py")
    env = dict(os.environ, MPP_SANITIZE="1")
    build = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=work,
                           env=env, capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-3000:]
    # malloc_context_size: 4 frames of each allocation's and free's stack instead of 30 (a
    # report still names the bad access's whole stack); numpy's allocations under ASan make up
    # much of the run, and the shorter stacks take a sixth off the march twins' case (27 -> 23 s)
    env.update(LD_PRELOAD=_libasan(),
               ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:malloc_context_size=4",
               UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1", MPP_FUZZ_ROUNDS="200",
               MPP_TWIN_RAYS="500",
               PYTHONPATH=str(work))
    where = subprocess.run([sys.executable, "-c", "import mpp_render._kernels as k; print(k.__file__)"],
                           cwd=work, env=env, capture_output=True, text=True)
    assert where.stdout.strip().startswith(str(work)), where.stdout + where.stderr[-2000:]
    # two pytest runs side by side, the march's twins in one and the rest in the other (about
    # the same time each): the machine's second core works while the first does
    groups = [[f"tests/{SEPARATE}"], [f"tests/{name}" for name in RUN if name != SEPARATE]]
    # the cases that run the numpy twins alone: no C to check
    numpy_only = ["tests/test_kernels.py::"
                  "test_an_indirect_lights_single_scattering_is_multiple[numpy]",
                  "tests/test_kernels.py::"
                  "test_light_entering_an_optically_thick_voxel_is_followed_cell_by_cell[numpy]",
                  "tests/test_camera_roulette.py::"
                  "test_it_keeps_the_mean_and_ends_paths_the_camera_cannot_see",
                  "tests/test_camera_roulette.py::test_once_a_path_not_compounded"]
    skip = [a for case in numpy_only for a in ("--deselect", case)]
    runs = [subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                              *files, *skip], cwd=work, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for files in groups]
    outs = []
    try:
        for run in runs:
            outs.append(run.communicate(timeout=900))
    finally:   # a run that timed out, or the other one after it: not left running
        for run in runs:
            if run.poll() is None:
                run.kill()
    for run, (out, err) in zip(runs, outs):
        assert run.returncode == 0, out[-3000:] + err[-3000:]
        assert " passed" in out and "skipped" not in out, out[-2000:]
