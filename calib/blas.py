"""One thread for the linear algebra libraries (OpenBLAS, twice: numpy's and scipy's), unless the user chose a number.

gyrocal's matrices are small (a few hundred rows at most), so a second BLAS thread has nothing to share; it only spins
waiting for work, and on a two-core gateway that runs the service, its compute workers and a browser it took 29 % more
processor time for the same model checks (measured on the test suite's numerics, tests/calib).
"""

from __future__ import annotations

import os

USER_SETTINGS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """One BLAS thread in this process and the processes it starts, unless one of USER_SETTINGS is set: the libraries
    loaded already are limited now, those loaded later (and a child's) read OPENBLAS_NUM_THREADS as they load."""
    if any(os.environ.get(name) for name in USER_SETTINGS):
        return
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
