"""A fluid domain's baked OpenVDB cache on disk, read in a reader process (bpy-side glue).

Blender's layout (``DNA_fluid_types.h``, ``fluid.cc``, Mantaflow's ``smoke_script.h`` /
``iovdb.cc``; named, not copied)::

    <cache_directory>/data/fluid_data_####.vdb     density, flame, color_r/g/b and the heat
                                                   grid (named 'temperature')
    <cache_directory>/noise/fluid_noise_####.vdb   density_noise, flame_noise, color_*_noise

where #### is the cache frame (``cache_frame``).  ``read_cache_file`` reads the grids asked
for with the openvdb module Blender bundles (``vdb.read_window``: only the index box of the
domain's resolution; sizes in a file are not trusted) in a separate process with a time
limit (``MPP_FLUID_READ_TIMEOUT_S``, seconds) and a memory cap, because a damaged file can
hang or exhaust the reader.  fluid.py places the grids in the domain.
"""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
import tempfile
from typing import Dict, Tuple

import numpy as np

from . import vdb as vdb_reader

DATA_DIR, NOISE_DIR = "data", "noise"            # FLUID_DOMAIN_DIR_DATA / _NOISE
DATA_NAME, NOISE_NAME = "fluid_data", "fluid_noise"  # FLUID_NAME_DATA / _NOISE
# grid names inside the cache files (Mantaflow's grid names, smoke_script.h)
DATA_GRIDS = {"density": "density", "flame": "flame", "heat": "temperature",
              "color_r": "color_r", "color_g": "color_g", "color_b": "color_b"}
NOISE_GRIDS = {"density": "density_noise", "flame": "flame_noise", "color_r": "color_r_noise",
               "color_g": "color_g_noise", "color_b": "color_b_noise"}
READ_TIMEOUT_ENV = "MPP_FLUID_READ_TIMEOUT_S"
READ_TIMEOUT_S = 120.0   # seconds a reader process may take for one cache file


def cache_file(directory: str, frame: int, noise: bool = False) -> str:
    """Blender's path of a domain's OpenVDB cache frame (data, or noise with ``noise``)."""
    sub, stem = (NOISE_DIR, NOISE_NAME) if noise else (DATA_DIR, DATA_NAME)
    return os.path.join(directory, sub, f"{stem}_{int(frame):04d}.vdb")


def cache_frame(dse, frame: int) -> int:
    """The cache frame Blender loads at scene frame ``frame``: minus ``cache_frame_offset``
    for the Modular and All cache types (fluid.cc); the frame itself for Replay."""
    if getattr(dse, "cache_type", "REPLAY") in ("MODULAR", "ALL"):
        return int(frame) - int(getattr(dse, "cache_frame_offset", 0))
    return int(frame)


# -- reading cache files in a reader process --------------------------------------------------

_DRIVER = '''
import json, sys
import numpy as np
request = json.load(open(sys.argv[1]))
sys.path.insert(0, request["openvdb_dir"])
try:
    import resource
    cap = int(request["memory_cap"])
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
except Exception:
    pass
import openvdb as vdb
status, arrays = {"grids": {}}, {}
try:
    found = {g.name: type(g).__name__ for g in vdb.readAllGridMetadata(request["path"])}
except Exception as e:
    status["error"] = type(e).__name__ + ": " + str(e)
    found = None
if found is not None:
    status["names"] = sorted(found)
    for i, g in enumerate(request["grids"]):
        name = g["name"]
        if name not in found:
            continue
        try:
            block = read_window(vdb, request["path"], name, np.float32, g["lo"], g["shape"])
        except Exception as e:
            status["grids"][name] = {"error": type(e).__name__ + ": " + str(e)}
            continue
        if block is None:
            status["grids"][name] = {"empty": True}
            continue
        values, origin, background, clipped = block
        arrays["g%d" % i] = values
        status["grids"][name] = {"key": "g%d" % i, "origin": list(origin), "clipped": clipped,
                                 "background": background}
np.savez(request["arrays"], **arrays)
json.dump(status, open(request["status"], "w"))
'''


def read_timeout() -> float:
    text = os.environ.get(READ_TIMEOUT_ENV, "")
    try:
        return float(text) if text.strip() else READ_TIMEOUT_S
    except ValueError:
        return READ_TIMEOUT_S


def read_cache_file(path: str, requests: Dict[str, Tuple[str, tuple]], timeout: float = None):
    """Read grids of one cache file in a reader process.

    ``requests``: our name -> (grid name in the file, (nx, ny, nz) cells); each grid is read
    only inside the index box (0, 0, 0) .. shape - 1.  Returns ``(grids, problems, names)``:
    our name -> ``(values float32, ijk origin, clipped)``; messages about the file or single
    grids; the grid names the file holds (None when it could not be read at all)."""
    vdb = vdb_reader.openvdb_module()
    if vdb is None:
        return {}, ["could not be read: Blender's openvdb module is not available"], None
    timeout = read_timeout() if timeout is None else float(timeout)
    source = inspect.getsource(vdb_reader.read_window) + _DRIVER
    want = [(ours, fname, tuple(int(v) for v in shape)) for ours, (fname, shape) in requests.items()]
    biggest = max((int(np.prod(s)) * 4 * 3 for _, _, s in want), default=0)
    with tempfile.TemporaryDirectory(prefix="mpp_fluid_") as tmp:
        req = {"path": path, "openvdb_dir": os.path.dirname(os.path.abspath(vdb.__file__)),
               "grids": [{"name": f, "lo": [0, 0, 0], "shape": list(s)} for _, f, s in want],
               "arrays": os.path.join(tmp, "grids.npz"), "status": os.path.join(tmp, "status.json"),
               "memory_cap": max(4 << 30, 8 * biggest)}
        with open(os.path.join(tmp, "request.json"), "w") as f:
            json.dump(req, f)
        try:
            run = subprocess.run([sys.executable, "-c", source, os.path.join(tmp, "request.json")],
                                 capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {}, [f"took longer than {timeout:g} s to read and may be damaged "
                        f"({READ_TIMEOUT_ENV} sets the limit)"], None
        except OSError as e:
            return {}, [f"could not be read: no reader process could be started ({e})"], None
        if run.returncode != 0 or not os.path.exists(req["status"]):
            tail = (run.stderr or "").strip().splitlines()[-1:] or [f"exit status {run.returncode}"]
            return {}, [f"could not be read: the openvdb reader failed ({tail[0][:200]})"], None
        with open(req["status"]) as f:
            status = json.load(f)
        if "error" in status:
            return {}, [f"could not be read; the file may be truncated or corrupt "
                        f"({status['error'][:200]})"], None
        grids, problems = {}, []
        with np.load(req["arrays"], allow_pickle=False) as npz:
            for ours, fname, shape in want:
                st = status["grids"].get(fname)
                if st is None:
                    continue
                if "error" in st:
                    problems.append(f"grid '{fname}' could not be read; the file may be "
                                    f"truncated or corrupt ({st['error'][:200]})")
                    continue
                if st.get("empty"):
                    continue
                values = npz[st["key"]]
                origin = tuple(int(v) for v in st["origin"])
                # never trust the reader's sizes either: the block must lie in the box
                if (values.ndim != 3 or any(o < 0 for o in origin)
                        or any(o + n > s for o, n, s in zip(origin, values.shape, shape))):
                    problems.append(f"grid '{fname}' does not fit the domain's {shape} cells; "
                                    "skipped")
                    continue
                grids[ours] = (values.astype(np.float32, copy=False), origin, bool(st["clipped"]))
        return grids, problems, status.get("names")


def place(block, shape) -> np.ndarray:
    """A (values, origin, clipped) block placed in a zero grid of ``shape`` cells."""
    values, origin, _ = block
    out = np.zeros(tuple(shape), np.float32)
    sl = tuple(slice(o, o + n) for o, n in zip(origin, values.shape))
    out[sl] = values
    return out
