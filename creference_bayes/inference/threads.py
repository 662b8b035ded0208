"""One BLAS thread while an estimate runs (threadpoolctl).

Every array the estimator factors is small (4 × 4 solves, 7 × 7 Hessians, least squares on a few
thousand rows); a threaded BLAS only adds overhead there, and on a busy machine its spinning
threads make it far worse. ``import creference_bayes`` sets ``OPENBLAS_NUM_THREADS`` and friends
to 1, but that only works when NumPy is not imported yet; this limits the BLAS of an
already-running process for the duration of a block, unless the user chose a thread count in the
environment.
"""

from __future__ import annotations

from contextlib import contextmanager

__all__ = ["USER_SET_THREADS", "single_threaded_blas"]

#: Whether the user set a BLAS thread count in the environment before importing the package (set
#: by ``creference_bayes/__init__.py``); the package then leaves the thread count alone.
USER_SET_THREADS = False


@contextmanager
def single_threaded_blas():
    """Limit the BLAS libraries NumPy uses to one thread inside the block."""
    if USER_SET_THREADS:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
