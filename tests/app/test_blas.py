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
def test_one_thread_gives_the_same_products_bit_for_bit():
    # the drag object's probe weights' product (U,27) @ (27,27) and a larger one: OpenBLAS splits rows and
    # columns over its threads, never a sum, so one thread changes no bit
    rng = np.random.default_rng(3)
    for shape in ((2000, 27, 27), (3000, 400, 64)):
        a, b = rng.random(shape[:2]), rng.random(shape[1:])
        threaded = a @ b
        blas.one_thread()
        try:
            single = a @ b
        finally:
            blas.own_threads()
        assert np.array_equal(threaded, single)
