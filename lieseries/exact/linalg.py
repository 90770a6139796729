"""A small 3x3 linear-algebra kit on lists of mpf (in this thread's mpmath context): products, rotations about
an axis, the exponential of a hat matrix."""

from __future__ import annotations

from ..precision import thread_mp as mp


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def norm(a):
    return mp.sqrt(dot(a, a))


def matvec(A, v):
    return [A[i][0] * v[0] + A[i][1] * v[1] + A[i][2] * v[2] for i in range(3)]


def matmul(A, B):
    return [[A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3)]
            for i in range(3)]


def transpose(A):
    return [[A[j][i] for j in range(3)] for i in range(3)]


def identity():
    return [[mp.mpf(1) if i == j else mp.mpf(0) for j in range(3)] for i in range(3)]


def axis_rotation(axis, angle):
    """exp(angle hat(axis)) for a unit vector ``axis`` (Rodrigues)."""
    x, y, z = axis
    c = mp.cos(angle)
    s = mp.sin(angle)
    C = 2 * mp.sin(angle / 2) ** 2  # 1 - cos, without cancellation
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def expm_hat(w, t):
    """exp(t hat(w)) for any vector ``w``."""
    nw = norm(w)
    if nw == 0:
        return identity()
    return axis_rotation([wi / nw for wi in w], nw * t)


def rz(angle):
    c = mp.cos(angle)
    s = mp.sin(angle)
    z = mp.mpf(0)
    return [[c, -s, z], [s, c, z], [z, z, mp.mpf(1)]]


def det3(A):
    return (A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1])
            - A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0])
            + A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]))
