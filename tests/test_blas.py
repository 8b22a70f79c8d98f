from threadpoolctl import threadpool_info, threadpool_limits

from mocapfill.runtime.blas import single_blas_thread


def _blas_threads():
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_single_blas_thread_limits_and_restores():
    with threadpool_limits(limits=2, user_api="blas"):  # the session runs on one thread (conftest): widen it first
        before = _blas_threads()
        with single_blas_thread():
            assert all(n == 1 for n in _blas_threads())
        assert _blas_threads() == before
