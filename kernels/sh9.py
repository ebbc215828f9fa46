"""Order-2 (9-coefficient) real spherical harmonics basis, the one definition: its normalisation
constants (lighting.sh evaluates the basis with numpy from them) and the Warp function `sh9` the
kernels evaluate it with.

Coefficient order: (0,0), (1,-1), (1,0), (1,1), (2,-2), (2,-1), (2,0), (2,1), (2,2); directions are
unit vectors in world coordinates.
"""
from __future__ import annotations

import warp as wp

C0 = 0.282094791773878
C1 = 0.488602511902920
C2 = 1.092548430592079
C3 = 0.315391565252520
C4 = 0.546274215296040
_C0, _C1, _C2, _C3, _C4 = (wp.constant(c) for c in (C0, C1, C2, C3, C4))
_D0, _D1, _D2, _D3, _D4 = (wp.constant(wp.float64(c)) for c in (C0, C1, C2, C3, C4))  # sh9_64's, in float64


@wp.func
def sh9(d: wp.vec3, k: int) -> float:
    """Y_k at the unit direction d (k in 0..8, the order above)."""
    x = d[0]
    y = d[1]
    z = d[2]
    if k == 0:
        return _C0
    if k == 1:
        return _C1 * y
    if k == 2:
        return _C1 * z
    if k == 3:
        return _C1 * x
    if k == 4:
        return _C2 * x * y
    if k == 5:
        return _C2 * y * z
    if k == 6:
        return _C3 * (3.0 * z * z - 1.0)
    if k == 7:
        return _C2 * x * z
    return _C4 * (x * x - y * y)


@wp.func
def sh9_64(d: wp.vec3d, k: int) -> wp.float64:
    """sh9 in float64 (lighting.sh.basis' arithmetic: the same products in the same order)."""
    x = d[0]
    y = d[1]
    z = d[2]
    if k == 0:
        return _D0
    if k == 1:
        return _D1 * y
    if k == 2:
        return _D1 * z
    if k == 3:
        return _D1 * x
    if k == 4:
        return _D2 * x * y
    if k == 5:
        return _D2 * y * z
    if k == 6:
        return _D3 * (wp.float64(3.0) * z * z - wp.float64(1.0))
    if k == 7:
        return _D2 * x * z
    return _D4 * (x * x - y * y)
