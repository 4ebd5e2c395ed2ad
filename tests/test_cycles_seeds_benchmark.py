"""benchmarks/cycles_seeds.py's comparisons: a pair of reference runs that shares an error
shows it against the extra runs, where two extra runs against the others show noise alone."""
import importlib.util
import os

import numpy as np
import pytest

PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks",
                    "cycles_seeds.py")
spec = importlib.util.spec_from_file_location("cycles_seeds_benchmark", PATH)
cycles_seeds = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cycles_seeds)

TRUTH = np.full((32, 48, 3), 0.5)


def runs(n, rng, sigma=0.05, shared=None):
    """n noisy runs of TRUTH (Gaussian noise of ``sigma`` per pixel), each plus ``shared``."""
    return [TRUTH + rng.normal(0.0, sigma, TRUTH.shape) + (0.0 if shared is None else shared)
            for _ in range(n)]


def test_an_ordinary_pair_scores_like_two_extra_runs_and_the_truth_within_the_noise():
    rng = np.random.default_rng(1)
    row = cycles_seeds.check(runs(2, rng), runs(4, rng), ours=TRUTH)
    assert row["runs"] == [2, 4]
    # a two-run mean against other runs: its own noise, sigma / sqrt(2) / 4 over 4x4 blocks
    expected = 0.05 / np.sqrt(2.0) / 4.0 / 0.5
    assert row["pair_vs_extra"]["rel_rmse_4"] == pytest.approx(expected, rel=0.25)
    assert row["extra_halves"]["rel_rmse_4"] == pytest.approx(expected, rel=0.25)
    assert row["pair_floor_4"] == pytest.approx(expected, rel=0.25)
    for key in ("ours_vs_pair", "ours_vs_extra", "ours_vs_all"):
        assert row[key]["rel_rmse_4"] < 0.3 * expected   # the truth: the floor subtracted
    assert abs(row["ours_vs_all"]["bias"]) < 0.01


def test_a_pair_that_shares_an_error_stands_out_against_the_extra_runs():
    rng = np.random.default_rng(2)
    shared = np.zeros_like(TRUTH)
    shared[8:16, 8:24] = 0.1     # both runs of the pair 20 % bright in one region
    row = cycles_seeds.check(runs(2, rng, shared=shared), runs(4, rng), ours=TRUTH)
    assert row["pair_vs_extra"]["rel_rmse_4"] > 3.0 * row["extra_halves"]["rel_rmse_4"]
    # the truth scores as badly against the pair, and within the noise against the rest
    assert row["ours_vs_pair"]["rel_rmse_4"] > 3.0 * row["ours_vs_extra"]["rel_rmse_4"]
    assert row["ours_vs_extra"]["rel_rmse_4"] < 0.01


def test_two_extra_runs_give_no_halves_and_the_report_leaves_that_cell_empty(tmp_path):
    rng = np.random.default_rng(3)
    row = cycles_seeds.check(runs(2, rng), runs(2, rng))
    assert "extra_halves" not in row and "ours_vs_all" not in row
    row.update(scene="s", render="single", seeds=[3, 4], spp=1024)
    cycles_seeds.write_report([row], str(tmp_path))
    text = (tmp_path / "cycles_seeds.md").read_text()
    line = [ln for ln in text.splitlines() if ln.startswith("| s |")][0]
    assert "3,4 (1024)" in line and line.count("|") == 10


def test_the_report_sums_up_our_error_against_the_pair_and_against_every_run(tmp_path):
    rng = np.random.default_rng(4)
    shared = np.zeros_like(TRUTH)
    shared[8:16, 8:24] = 0.1
    rows = []
    for name, pair_error in (("a", None), ("b", shared)):
        row = cycles_seeds.check(runs(2, rng, shared=pair_error), runs(4, rng), ours=TRUTH)
        row.update(scene=name, render="single", seeds=[3, 4, 5, 6], spp=1024)
        rows.append(row)
    lines = cycles_seeds.summary(rows)
    assert len(lines) == 1 and lines[0].startswith("- Single scattering, 2 scenes")
    worst_pair = max(r["ours_vs_pair"]["rel_rmse_4"] for r in rows)
    assert "worst %.4f (b)" % worst_pair in lines[0]     # the pair that shares an error
    cycles_seeds.write_report(rows, str(tmp_path))
    assert lines[0] in (tmp_path / "cycles_seeds.md").read_text()
