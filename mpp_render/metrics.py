"""The error metric of ``shared/reference/metrics.md``: a candidate image against k Cycles runs.

With reference runs r_1..r_k (linear RGB, same resolution as the candidate x)::

    ref       = mean_i r_i
    noise     = var_i(r_i) / k               (per pixel and channel, ddof = 1)
    rel_rmse  = sqrt(max(mean((x - ref)^2) - mean(noise), 0)) / mean(ref)
    floor     = sqrt(mean(noise)) / mean(ref)
    bias      = (mean(x) - mean(ref)) / mean(ref)

Means run over all pixels and the three colour channels (alpha is ignored).  ``rel_rmse_4``
and ``floor_4`` are the same after a 4x4 box downsample of x and every r_i.  A non-finite
value anywhere in x is a failure (``failed`` True, the numbers None), not a number.

Resolution: when every side of the references is the same integer multiple of the
candidate's (e.g. a render at 25 % against 100 % references) the references are first
box-downsampled by that factor: with Cycles' 1 px box filter that average is a render at the
lower resolution.  A box downsample by f drops the last rows/columns that do not fill a whole
f x f block.
"""
from __future__ import annotations

import glob
import os
import re
from typing import List, Optional, Sequence

import numpy as np

DOWNSAMPLE = 4
# Samples per pixel of our single-scattering comparisons with a public scene where the usual
# 16 leave our own noise above the 0.03 target: fog_beam's narrow, bright beam where it enters
# the box (16 spp: rel_rmse_4 0.044-0.064 over two seeds; 256 spp: 0.028-0.030).
SINGLE_SCATTERING_SAMPLES = {"fog_beam": 256}


def box_downsample(img: np.ndarray, f: int) -> np.ndarray:
    """Mean over f x f pixel blocks of an (H, W, C) image; trailing partial blocks dropped."""
    if f == 1:
        return np.asarray(img, np.float64)
    h, w = img.shape[0] // f, img.shape[1] // f
    if h == 0 or w == 0:
        raise ValueError(f"image {img.shape[:2]} is smaller than a {f}x{f} block")
    a = np.asarray(img[:h * f, :w * f], np.float64)
    return a.reshape(h, f, w, f, -1).mean(axis=(1, 3))


def error_terms(x: np.ndarray, runs: Sequence[np.ndarray]) -> dict:
    """rel_rmse, floor and bias of candidate ``x`` (H, W, C) against ``runs`` (each (H, W, C)),
    all arrays already at the same resolution.  ``floor`` is None with a single run (no
    variance estimate); the noise term is then 0."""
    x = np.asarray(x, np.float64)
    r = np.stack([np.asarray(ri, np.float64) for ri in runs])
    if r.shape[1:] != x.shape:
        raise ValueError(f"candidate {x.shape} and reference {r.shape[1:]} differ in shape")
    k = r.shape[0]
    ref = r.mean(axis=0)
    noise = r.var(axis=0, ddof=1) / k if k > 1 else np.zeros_like(ref)
    mref = ref.mean()
    mse = np.mean((x - ref) ** 2)
    mnoise = noise.mean()
    return {
        "rel_rmse": float(np.sqrt(max(mse - mnoise, 0.0)) / mref),
        "floor": float(np.sqrt(mnoise) / mref) if k > 1 else None,
        "bias": float((x.mean() - mref) / mref),
    }


def compare(x: np.ndarray, runs: Sequence[np.ndarray]) -> dict:
    """The full metric set of candidate ``x`` against ``runs`` (RGB or RGBA; alpha dropped):
    rel_rmse, floor, bias, rel_rmse_4, floor_4, runs (k), ref_downsample (the factor applied
    to the references to reach the candidate's resolution), failed (non-finite candidate)."""
    x = np.asarray(x)[:, :, :3]
    runs = [np.asarray(r)[:, :, :3] for r in runs]
    if not runs:
        raise ValueError("no reference runs")
    f = resolution_factor(runs[0].shape[:2], x.shape[:2])
    out = {"runs": len(runs), "ref_downsample": f, "failed": False}
    keys = ("rel_rmse", "floor", "bias", "rel_rmse_4", "floor_4")
    if not np.all(np.isfinite(x)):
        out.update({k: None for k in keys})
        out["failed"] = True
        out["reason"] = f"{int(np.size(x) - np.isfinite(x).sum())} non-finite values in the candidate"
        return out
    runs = [box_downsample(r, f) for r in runs]
    out.update(error_terms(x, runs))
    coarse = error_terms(box_downsample(x, DOWNSAMPLE), [box_downsample(r, DOWNSAMPLE) for r in runs])
    out["rel_rmse_4"] = coarse["rel_rmse"]
    out["floor_4"] = coarse["floor"]
    return out


def resolution_factor(ref_hw, cand_hw) -> int:
    """The integer f with ref_hw == f * cand_hw; ValueError when there is none."""
    (rh, rw), (ch, cw) = ref_hw, cand_hw
    if ch > 0 and cw > 0 and rh % ch == 0 and rw % cw == 0 and rh // ch == rw // cw:
        return rh // ch
    raise ValueError(f"candidate {cw}x{ch} is not the reference resolution {rw}x{rh} "
                     "divided by an integer")


def scene_names(root: str, chosen: Optional[str] = None) -> List[str]:
    """The scenes to run: ``chosen`` (comma-separated names) or else every folder of the
    suite ``root`` that holds a ``scene.blend``, sorted."""
    if chosen:
        return chosen.split(",")
    return sorted(d for d in os.listdir(root) if os.path.isfile(os.path.join(root, d, "scene.blend")))


def reference_paths(scene_dir: str, single: bool = False) -> List[str]:
    """The scene's reference runs: ``ref_s<seed>.exr`` (or ``ss_s<seed>.exr``, single
    scattering only, when ``single``), sorted by seed."""
    prefix = "ss" if single else "ref"
    paths = glob.glob(os.path.join(scene_dir, f"{prefix}_s*.exr"))

    def seed(p):
        m = re.search(r"_s(\d+)\.exr$", p)
        return int(m.group(1)) if m else -1

    return sorted((p for p in paths if seed(p) >= 0), key=seed)


def compare_files(candidate_exr: str, scene_dir: str, single: bool = False,
                  layer: Optional[str] = None) -> dict:
    """Metrics of the Combined pass of ``candidate_exr`` against a scene folder's runs."""
    from .exr import read_passes

    paths = reference_paths(scene_dir, single)
    if not paths:
        raise FileNotFoundError(f"no {'ss' if single else 'ref'}_s*.exr in {scene_dir}")
    x = read_passes(candidate_exr, layer=layer, names=("Combined",)).get("Combined")
    if x is None:
        raise ValueError(f"{candidate_exr} has no Combined pass")
    runs = [read_passes(p, names=("Combined",))["Combined"] for p in paths]
    out = compare(x, runs)
    out["references"] = [os.path.basename(p) for p in paths]
    return out
