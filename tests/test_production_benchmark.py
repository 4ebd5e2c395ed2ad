"""benchmarks/production.py's equal-error arithmetic: the samples Cycles needs to reach an
error, interpolated log-log on its curve and extrapolated beyond it as noise falls."""
import importlib.util
import os

import numpy as np
import pytest

PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks",
                    "production.py")
spec = importlib.util.spec_from_file_location("production_benchmark", PATH)
production = importlib.util.module_from_spec(spec)
spec.loader.exec_module(production)


def test_samples_to_reach_interpolates_and_extrapolates_as_noise_falls():
    curve = [(1, 0.4), (4, 0.2), (16, 0.1), (64, 0.05)]       # error ~ spp^-1/2
    n, extrapolated = production.samples_to_reach(0.1, curve)
    assert n == pytest.approx(16.0) and not extrapolated
    n, extrapolated = production.samples_to_reach(0.2 / np.sqrt(2.0), curve)
    assert n == pytest.approx(8.0) and not extrapolated        # log-log between 4 and 16
    n, extrapolated = production.samples_to_reach(0.025, curve)
    assert n == pytest.approx(256.0) and extrapolated          # beyond the curve: (0.05/0.025)^2
    n, extrapolated = production.samples_to_reach(0.9, curve)
    assert n == 1.0 and not extrapolated                        # worse than Cycles' cheapest
    assert production.samples_to_reach(None, curve) == (None, False)
    assert production.samples_to_reach(0.1, []) == (None, False)


def _row(name, commit):
    return {"scene": name, "commit": commit,
            "ours_small": {"seconds": 1.0, "rel_rmse_4": 0.02, "floor_4": 0.01, "bias": 0.0},
            "ours_hd": {"seconds": 10.0, "precompute": 2.0, "march": 7.0, "pixel_samples": 1.2,
                        "samples_per_s_per_core": 4e6},
            "cycles_hd": {"per_sample": 5.0, "fixed": 1.0}, "cycles_spp_needed": 100.0,
            "extrapolated": True, "cycles_hd_seconds_at_our_error": 501.0, "speedup": 50.1}


def test_report_names_the_commits_its_rows_measured(tmp_path):
    production.write_report([_row("a", "abc1234"), _row("b", "def5678"), _row("c", "abc1234")],
                            str(tmp_path), (1920, 1080))
    text = (tmp_path / "production.md").read_text()
    assert "Commits measured: abc1234, def5678." in text
    assert "median 50.1x" in text
    production.write_report([_row("a", "abc1234")], str(tmp_path), (1920, 1080))
    assert "Commit measured: abc1234." in (tmp_path / "production.md").read_text()


def test_report_writes_its_summary_into_error_vs_time_and_keeps_the_page(tmp_path):
    page = tmp_path / "error_vs_time.md"
    page.write_text("# Error against time\n\nintro\n\n## Summary\n\n| a | b |\n\n## cloud_vdb\n")
    unreached = _row("b", "abc1234")     # Cycles' curve gave no sample count: no such keys
    for key in ("speedup", "cycles_hd_seconds_at_our_error"):
        del unreached[key]
    rows = [_row("a", "abc1234"), unreached]
    production.write_report(rows, str(tmp_path), (1920, 1080))
    text = page.read_text()
    begin, end = production.docblocks.markers("production")
    assert text.count(begin) == 1 and text.count(end) == 1
    assert text.index("intro") < text.index(begin) < text.index(end) < text.index("## Summary")
    assert "| a | 0.0200 | 10.0 | 501 | 50.1x |" in text and "| b | 0.0200 | 10.0 | – | – |" in text
    assert (tmp_path / "production.png").stat().st_size > 0
    # a second report replaces the block, and the page's own rewrite carries it over
    production.write_report([dict(_row("a", "fff0000"), speedup=120.0)], str(tmp_path),
                            (1920, 1080))
    text = page.read_text()
    assert text.count(begin) == 1 and "120.0x" in text and "50.1x" not in text
    kept = production.docblocks.kept_block(str(page), "production")
    assert kept[0] == begin and kept[-2] == end and kept[-1] == ""
    assert "| a | 0.0200 | 10.0 | 501 | 120.0x |" in kept


def test_blocks_are_left_alone_where_the_page_or_block_is_missing(tmp_path):
    docblocks = production.docblocks
    assert not docblocks.put_block(str(tmp_path / "none.md"), "production", ["x"])
    assert docblocks.kept_block(str(tmp_path / "none.md"), "production") == []
    page = tmp_path / "p.md"
    page.write_text("# t\n<!-- production:begin -->\nno end\n")
    assert docblocks.find_block(page.read_text(), "production") is None
    assert docblocks.put_block(str(page), "production", ["new"], after="## Nowhere")
    assert page.read_text().endswith("<!-- production:begin -->\nnew\n<!-- production:end -->\n")


def test_the_report_says_which_cycles_samples_its_rows_timed():
    """The text names the Cycles sample counts the rows' per-sample seconds came from (rows
    of runs before HD_SPP was 4 hold 2), not the current constant alone."""
    old = {"cycles_hd": {"seconds_1spp": 3.0, "seconds_2spp": 5.0}}
    new = {"cycles_hd": {"seconds_1spp": 3.0, f"seconds_{production.HD_SPP}spp": 9.0}}
    assert production.hd_samples([old]) == "2"
    assert production.hd_samples([old, new]) == f"2 or {production.HD_SPP}"
    assert production.hd_samples([new, new]) == str(production.HD_SPP)
