"""One BLAS thread while the package's own numerics run (threadpoolctl).

Every array the estimator factors is small (4 × 4 solves, 7 × 7 Hessians, least squares on a few
thousand rows); a threaded BLAS only adds overhead there, and on a busy machine its spinning
threads make it far worse. The package does not touch the process's environment (a user's other
code keeps its threads): :func:`single_threaded_blas` limits the BLAS for the duration of a block
only, around :func:`~creference_bayes.pipeline.estimate`, every ``creference`` command and every
batch, advice and leave-one-out worker, unless the user chose a thread count in the environment.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

__all__ = ["THREAD_VARS", "USER_SET_THREADS", "single_threaded_blas"]

#: The environment variables that set a BLAS's thread count (read, never written).
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
#: Whether the user set a BLAS thread count in the environment before the package was imported;
#: the package then leaves the thread count alone.
USER_SET_THREADS = any(v in os.environ for v in THREAD_VARS)


@contextmanager
def single_threaded_blas():
    """Limit the BLAS libraries NumPy uses to one thread inside the block."""
    if USER_SET_THREADS:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
