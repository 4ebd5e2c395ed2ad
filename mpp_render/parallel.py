"""Work split over a thread pool, with Esc polled while it runs (no bpy).

The compiled kernels and numpy's FFTs release the GIL, so chunks of them run in parallel on
threads; ``run_chunks`` is the one place that does it (the precompute's sweeps and marches,
the first flights' convolutions), and ``worker_count`` the one place that sizes a pool (the
render's tiles too)."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout

from .cancel import check


def worker_count(threads: int = 0) -> int:
    """Threads for a pool: ``threads``, or one per core where it is <= 0."""
    return threads if threads > 0 else (os.cpu_count() or 1)


def run_chunks(n, chunk, work, threads=0, should_cancel=None, stop=None) -> None:
    """Call ``work(a, b)`` for consecutive ranges [a, b) of ``range(n)`` on a thread pool
    (``threads`` <= 0: one per core).  The kernels release the GIL, so chunks run in parallel;
    each chunk must write only its own slice.  Raises Cancelled when ``should_cancel`` stops
    it (the chunks not started are dropped).  ``stop``: None, or a writable uint8 array the
    chunks' compiled loops read while they run (kernels.trace_paths_media): its first byte is
    set to 1 when Esc stops the run, so that a running chunk returns within a few paths, and
    the chunks then run on a pool even with one thread, this thread polling Esc every
    ``POLL_S`` s beside them."""
    starts = list(range(0, n, chunk))
    threads = worker_count(threads)
    if stop is None and (threads == 1 or len(starts) <= 1):
        for a in starts:
            check(should_cancel)
            work(a, min(n, a + chunk))
        return
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futures = [pool.submit(work, a, min(n, a + chunk)) for a in starts]
        try:
            for f in futures:
                # poll before every wait, not only when one times out: chunks shorter than
                # the timeout would otherwise never look at Esc
                while True:
                    check(should_cancel)
                    try:
                        f.result(timeout=POLL_S)
                        break
                    except FuturesTimeout:
                        pass
        except BaseException:
            if stop is not None:   # the running chunks' loops stop too
                stop[0] = 1
            raise
        finally:  # cancelled or failed: drop the chunks not started (leaving the pool
            for g in futures:  # waits only for the running ones)
                g.cancel()


POLL_S = 0.05   # s between polls of Esc while chunks run
