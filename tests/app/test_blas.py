"""app.blas: a frame's matrix products on one OpenBLAS thread, the process's own count after it."""
import numpy as np
import pytest

from app import blas
from app.glue import FrameTimer


def _numpy_uses_openblas() -> bool:
    cfg = np.show_config(mode="dicts")
    return "openblas" in str(cfg.get("Build Dependencies", {}).get("blas", {}).get("name", "")).lower()


@pytest.mark.skipif(not _numpy_uses_openblas(), reason="numpy is not built on OpenBLAS")
def test_frame_timer_runs_blas_on_one_thread_and_restores_it():
    own = blas.threads()
    assert own, "numpy's OpenBLAS was not found among the loaded libraries"
    ft = FrameTimer()
    assert blas.threads() == [1] * len(own)
    ft.close()
    assert blas.threads() == own


@pytest.mark.skipif(not _numpy_uses_openblas(), reason="numpy is not built on OpenBLAS")
def test_one_thread_gives_the_same_products_to_rounding():
    # the drag object's probe weights' product (U,27) @ (27,27) and a larger one, on one BLAS thread and on
    # the process's own: the same products to rounding. Not bit for bit on every CPU: OpenBLAS picks its
    # kernel and its split by the CPU it runs on, and on some (seen on a 2-core x86-64 machine for the
    # (3000,400) @ (400,64) product) it splits the inner sum too, which reorders the additions
    rng = np.random.default_rng(3)
    for shape in ((2000, 27, 27), (3000, 400, 64)):
        a, b = rng.random(shape[:2]), rng.random(shape[1:])
        threaded = a @ b
        blas.one_thread()
        try:
            single = a @ b
        finally:
            blas.own_threads()
        # entries are sums of shape[1] products in [0, 1): rounding moves them by a few ulp of the sum
        np.testing.assert_allclose(single, threaded, rtol=1e-13, atol=0)
