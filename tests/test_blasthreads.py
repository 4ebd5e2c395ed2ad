"""numpy's OpenBLAS is held to one thread while a frame renders, and given back after."""
import numpy as np
import pytest

from mpp_render import blasthreads, render


def test_openblas_is_found_beside_this_numpy():
    # the pinned numpy wheel bundles OpenBLAS; finding it is what the saving rests on
    assert blasthreads.blas_threads(), "no OpenBLAS found for numpy " + np.__version__


def test_one_thread_within_the_block_and_the_count_restored_after_an_error():
    before = blasthreads.blas_threads()
    with pytest.raises(RuntimeError):
        with blasthreads.one_blas_thread():
            assert blasthreads.blas_threads() == [1] * len(before)
            raise RuntimeError("inside")
    assert blasthreads.blas_threads() == before


def test_a_frame_renders_with_one_blas_thread(monkeypatch):
    seen = []
    monkeypatch.setattr(render, "_render", lambda *a: seen.append(blasthreads.blas_threads()))
    render.render(None)
    assert seen and all(n == 1 for n in seen[0])
