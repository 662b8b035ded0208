"""One BLAS thread while an estimate runs (threadpoolctl).

Every array the estimator factors is small (4 × 4 solves, 7 × 7 Hessians, least squares on a few
thousand rows); a threaded BLAS only adds overhead there, and on a busy machine its spinning
threads make it far worse (measured: a 1500 × 28 least-squares fit of the sampler's coordinates
took 170 ms with the default threads while another process kept the second core busy, 0.7 ms with
one). ``import creference_bayes`` sets ``OPENBLAS_NUM_THREADS`` and friends to 1, but that only
works when NumPy is not imported yet; this limits the BLAS of an already-running process for the
duration of a block, unless the user chose a thread count in the environment.
"""

from __future__ import annotations

from contextlib import contextmanager, nullcontext

__all__ = ["USER_SET_THREADS", "single_threaded_blas"]

#: Whether the user set a BLAS thread count in the environment before importing the package (set
#: by ``creference_bayes/__init__.py``); the package then leaves the thread count alone.
USER_SET_THREADS = False


@contextmanager
def single_threaded_blas():
    """Limit the BLAS libraries NumPy uses to one thread inside the block."""
    if USER_SET_THREADS:
        with nullcontext():
            yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
