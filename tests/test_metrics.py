"""The error metric (shared/reference/metrics.md) on synthetic images with known answers."""
import math

import numpy as np
import pytest

from mpp_render import exr, metrics


def runs_around(mean, k=4, sigma=0.1, shape=(16, 24, 3), seed=0):
    rng = np.random.default_rng(seed)
    return [mean + sigma * rng.standard_normal(shape) for _ in range(k)]


def test_candidate_equal_to_reference_mean_scores_zero():
    runs = runs_around(1.0)
    m = metrics.compare(np.mean(runs, axis=0), runs)
    assert m["rel_rmse"] == 0.0 and m["rel_rmse_4"] == 0.0
    assert abs(m["bias"]) < 1e-12
    assert not m["failed"] and m["runs"] == 4 and m["ref_downsample"] == 1


def test_constant_offset_gives_bias_and_rel_rmse():
    ref = np.full((16, 24, 3), 2.0)
    runs = [ref, ref.copy()]  # no noise: floor 0
    m = metrics.compare(ref * 1.1, runs)
    assert m["bias"] == pytest.approx(0.1)
    assert m["rel_rmse"] == pytest.approx(0.1)
    assert m["rel_rmse_4"] == pytest.approx(0.1)
    assert m["floor"] == 0.0 and m["floor_4"] == 0.0


def test_floor_and_noise_subtraction_follow_the_formulas():
    runs = runs_around(1.0, k=5, sigma=0.2, seed=3)
    r = np.stack(runs)
    ref = r.mean(0)
    noise = r.var(0, ddof=1) / 5
    x = ref + 0.3
    m = metrics.compare(x, runs)
    assert m["floor"] == pytest.approx(math.sqrt(noise.mean()) / ref.mean())
    expect = math.sqrt(max(0.09 - noise.mean(), 0.0)) / ref.mean()
    assert m["rel_rmse"] == pytest.approx(expect)
    # Downsampled: each 4x4 block averages 16 independent pixels, so the floor drops ~4x.
    r4 = np.stack([metrics.box_downsample(ri, 4) for ri in runs])
    noise4 = r4.var(0, ddof=1) / 5
    assert m["floor_4"] == pytest.approx(math.sqrt(noise4.mean()) / r4.mean())
    assert m["floor_4"] < m["floor"] / 2.5


def test_noise_subtraction_clamps_at_zero():
    runs = runs_around(1.0, k=2, sigma=0.5)
    m = metrics.compare(np.mean(runs, axis=0) + 1e-3, runs)
    assert m["rel_rmse"] == 0.0


def test_alpha_is_ignored_and_box_downsample_means_blocks():
    img = np.arange(8 * 8 * 1, dtype=float).reshape(8, 8, 1)
    d = metrics.box_downsample(img, 4)
    assert d.shape == (2, 2, 1)
    assert d[0, 0, 0] == pytest.approx(img[:4, :4].mean())
    ref = np.ones((8, 8, 4))
    x = ref.copy()
    x[..., 3] = 123.0
    assert metrics.compare(x, [ref, ref])["rel_rmse"] == 0.0


def test_non_finite_candidate_is_a_failure():
    runs = runs_around(1.0)
    x = np.mean(runs, axis=0)
    x[3, 4, 1] = np.nan
    m = metrics.compare(x, runs)
    assert m["failed"] and m["rel_rmse"] is None and m["rel_rmse_4"] is None


def test_lower_resolution_candidate_is_scored_against_downsampled_references():
    rng = np.random.default_rng(1)
    truth = rng.random((32, 48, 3))
    runs = [truth, truth]
    m = metrics.compare(metrics.box_downsample(truth, 4), runs)
    assert m["ref_downsample"] == 4 and m["rel_rmse"] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError):
        metrics.compare(np.zeros((10, 10, 3)), runs)


def test_compare_files_reads_reference_runs(tmp_path):
    runs = runs_around(1.0, k=3, shape=(8, 12, 4), seed=2)
    for i, r in enumerate(runs, start=1):
        exr.write_passes(str(tmp_path / f"ref_s{i}.exr"), {"Combined": r})
    exr.write_passes(str(tmp_path / "ss_s1.exr"), {"Combined": runs[0]})
    exr.write_passes(str(tmp_path / "ss_s2.exr"), {"Combined": runs[1]})
    cand = tmp_path / "cand.exr"
    exr.write_passes(str(cand), {"Combined": np.mean(runs, axis=0) * 1.1, "Depth": np.zeros((8, 12, 1))})
    m = metrics.compare_files(str(cand), str(tmp_path))
    assert m["references"] == ["ref_s1.exr", "ref_s2.exr", "ref_s3.exr"]
    assert m["bias"] == pytest.approx(0.1, rel=1e-5)
    s = metrics.compare_files(str(cand), str(tmp_path), single=True)
    assert s["references"] == ["ss_s1.exr", "ss_s2.exr"]


def test_scene_names_lists_the_folders_with_a_blend_file(tmp_path):
    for name in ("b_scene", "a_scene", "no_blend"):
        (tmp_path / name).mkdir()
    (tmp_path / "a_scene" / "scene.blend").write_bytes(b"")
    (tmp_path / "b_scene" / "scene.blend").write_bytes(b"")
    (tmp_path / "scene.blend").write_bytes(b"")
    assert metrics.scene_names(str(tmp_path)) == ["a_scene", "b_scene"]
    assert metrics.scene_names(str(tmp_path), "x,y") == ["x", "y"]
