"""Host arithmetic that gives the same bits on every x86-64 CPU (issue 40).

NumPy and OpenBLAS pick their SIMD code by the CPU: BLAS products (matmul, solve,
lstsq, eigh), float32 transcendentals and, on AVX-512, float64 ones round differently
from one machine to the next. Elementwise + - * / and sqrt are correctly rounded on every
path, and NumPy's reductions (sum) run in a fixed order; the functions here use only
those, or round once from a float64 value within a known bound of exact and recompute
the rare value near a rounding boundary in a fixed order (as the M1/M3 searches'
arbiters do), so that M2 gives the same output on any machine.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["dot3", "eigh3_fixed", "exp_fixed", "gram_fixed", "log_fixed", "lstsq_fixed", "norm3", "round_log_f32", "solve_fixed",
           "sum_products_f32", "times3x3", "unit_fixed", "vdot_fixed"]


def times3x3(p: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``p @ m`` for (k, 3) p and a (3, 3) m in a fixed order, ((p0 m0 + p1 m1) + p2 m2):
    elementwise, so correctly rounded alike on every CPU (BLAS's products are not)."""
    return p[:, 0:1] * m[0] + p[:, 1:2] * m[1] + p[:, 2:3] * m[2]


def norm3(v: np.ndarray) -> np.ndarray:
    """The lengths of (k, 3) vectors, sqrt((x x + y y) + z z) in that order: (k,) float.
    ``np.linalg.norm(v, axis=1)`` reduces its three squares in an order NumPy's SIMD code
    picks by the CPU (a last-bit difference seen between AVX2 and SSE4)."""
    return np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])


# fdlibm's e_log.c: ln2 split so that k * _LN2_HI is exact, and its polynomial for log(1 + f)
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10
_LG = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
       1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)


def log_fixed(x: np.ndarray) -> np.ndarray:
    """The natural log of positive finite float64 ``x`` (any shape) by fdlibm's method
    (error < 1 ulp) in elementwise NumPy (frexp, + - * /): the same bits on every CPU,
    where NumPy's own log may dispatch to SIMD code that rounds differently (AVX-512)."""
    m, e = np.frexp(np.asarray(x, np.float64))  # x = m 2^e, m in [0.5, 1)
    low = m < 0.7071067811865476
    m = np.where(low, 2.0 * m, m)  # [sqrt(1/2), sqrt(2)): log(1 + f) with |f| < 0.42
    k = (e - low).astype(np.float64)
    f = m - 1.0  # exact
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG[1] + w * (_LG[3] + w * _LG[5]))
    t2 = z * (_LG[0] + w * (_LG[2] + w * (_LG[4] + w * _LG[6])))
    r = t2 + t1
    hfsq = 0.5 * f * f
    return k * _LN2_HI - ((hfsq - (s * (hfsq + r) + k * _LN2_LO)) - f)


_MID = np.int64(1 << 28)  # a float64's 29 bits below float32's mantissa, at a float32 rounding boundary
_LOW29 = np.int64((1 << 29) - 1)


def round_log_f32(x: np.ndarray, scratch: np.ndarray | None = None) -> np.ndarray:
    """``log(x)`` rounded to float32, the same bits on every CPU, for positive float64 ``x``
    (2-D) whose logs are normal float32 numbers or 0 (x within float32's range).

    NumPy's float64 log is within an ulp of exact but its last bit depends on the SIMD
    path (AVX-512 has its own); rounded to float32 that matters only within a few float64
    ulps of a float32 rounding boundary (the low 29 bits near 2^28). Those entries (about
    one in 2^24) are recomputed by the scalar ``math.log`` (the C library's, correctly
    rounded in practice) before rounding; every other entry rounds alike anyway."""
    import math

    lg = np.log(x, out=scratch)
    # |low 29 bits - 2^28| <= 16, as one unsigned comparison ((bits - (2^28 - 16)) as
    # uint64 <= 32), with NumPy arrays for the constants: a Python integer operand sends
    # the int64 ufuncs through a path ten times slower
    bits = np.bitwise_and(lg.view(np.int64), _LOW29)
    np.subtract(bits, _MID - np.int64(16), out=bits)
    close = np.flatnonzero(bits.view(np.uint64) <= np.uint64(32))
    if close.size:
        flat_x, flat_lg = x.reshape(-1), lg.reshape(-1)
        flat_lg[close] = [math.log(float(v)) for v in flat_x[close]]
    return lg.astype(np.float32)


def sum_products_f32(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a @ b`` rounded to float32, the same bits on every CPU: (m, n) float32 ``a``,
    (n, k) float64 ``b`` holding float32 values, (m, k) float32 ``out``.

    Each product a_ri b_ik is exact in float64, so any order of summing them (BLAS's dgemm
    differs by CPU) is within gamma_n sum_i |a_ri b_ik| <= gamma_n S_r B_k of the exact sum
    (S_r = sum_i |a_ri|, B_k = max_i |b_ik|), far below float32's rounding. A sum within
    2.5 such bounds of a float32 rounding boundary (rare) is summed again in NumPy's fixed
    order (elementwise products, ``np.sum``) before it is rounded; any other rounds to the
    same float32 on every CPU as the fixed order's would."""
    a64 = a.astype(np.float64)
    v = a64 @ b
    n = a.shape[1]
    gamma = n * 2.0 ** -53 / (1.0 - n * 2.0 ** -53)
    # S_r = sum_i |a_ri| in float32 (|a| is float32 already), raised by 1% for the float32
    # sum's own error (at most n 2^-24 relative): still an upper bound, at half the traffic
    s_r = np.abs(a).sum(axis=1, dtype=np.float64) * 1.01
    tol = (2.5 * gamma) * s_r[:, None] * np.abs(b).max(axis=0)[None, :]
    v32 = v.astype(np.float32)
    # the gap to v32's neighbour on v's side: np.spacing(|v32|) away from zero, and toward
    # zero too except at a power of two, where it is half (np.nextafter is several times
    # slower); the rounding boundary lies half that gap from v32
    mag = np.abs(v32)
    gap = np.spacing(mag).astype(np.float64)
    toward_zero_at_power = (np.abs(v) < mag) & ((v32.view(np.int32) & np.int32(0x7FFFFF)) == np.int32(0))
    gap[toward_zero_at_power] *= 0.5
    margin = 0.5 * gap - np.abs(v - v32.astype(np.float64))
    rows, cols = np.nonzero(margin <= tol)
    if rows.size:
        v32[rows, cols] = (a64[rows] * b[:, cols].T).sum(axis=1).astype(np.float32)
    out[...] = v32


def solve_fixed(a: np.ndarray, b: np.ndarray, tiny: float = 1e-13) -> np.ndarray | None:
    """x with ``a x = b`` ((n, n) and (n, k) float64) by Gaussian elimination with partial
    pivoting (the first largest pivot), every step elementwise NumPy in a fixed order: the
    same bits on every CPU, where LAPACK's blocked kernels round by the CPU's SIMD width.
    None when a pivot is at most ``tiny`` times the largest entry (singular to rounding).
    (n, n) work per column: fine for the spline's few hundred unknowns."""
    a = np.array(a, np.float64)
    b = np.array(b, np.float64)
    n = len(a)
    big = float(np.abs(a).max()) if n else 0.0
    if not big > 0:
        return None if n else b
    scratch = np.empty((max(n - 1, 1), max(n - 1, 1)))  # the elimination's products, one buffer
    for k in range(n):
        p = k + int(np.argmax(np.abs(a[k:, k])))
        if not abs(a[p, k]) > tiny * big:
            return None
        if p != k:
            a[[k, p]] = a[[p, k]]
            b[[k, p]] = b[[p, k]]
        if k + 1 < n:
            col = a[k + 1:, k] / a[k, k]
            update = np.multiply.outer(col, a[k, k + 1:], out=scratch[:n - k - 1, :n - k - 1])
            a[k + 1:, k + 1:] -= update
            b[k + 1:] -= col[:, None] * b[k]
    x = np.empty_like(b)
    for k in range(n - 1, -1, -1):
        acc = b[k].copy()
        for_k = a[k, k + 1:]
        if for_k.size:
            acc -= (for_k[:, None] * x[k + 1:]).sum(axis=0)
        x[k] = acc / a[k, k]
    return x


# fdlibm's e_exp.c: its polynomial for exp(r), |r| <= ln2 / 2
_EP = (1.66666666666666019037e-01, -2.77777777770155933842e-03, 6.61375632143793436117e-05,
       -1.65339022054652515390e-06, 4.13813679705723846039e-08)


def exp_fixed(x: np.ndarray) -> np.ndarray:
    """exp of finite float64 ``x`` <= 709 (any shape) by fdlibm's method (error < 1 ulp) in
    elementwise NumPy (rint, + - * /, ldexp): the same bits on every CPU, where NumPy's own
    exp may dispatch to SIMD code that rounds differently (AVX-512)."""
    x = np.maximum(np.asarray(x, np.float64), -746.0)  # below: 0 (ldexp underflows)
    k = np.rint(x * 1.44269504088896338700e+00)  # x = k ln2 + r
    hi = x - k * _LN2_HI  # exact for |k| < 2^11
    lo = k * _LN2_LO
    r = hi - lo
    z = r * r
    c = r - z * (_EP[0] + z * (_EP[1] + z * (_EP[2] + z * (_EP[3] + z * _EP[4]))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    return np.ldexp(y, k.astype(np.int64))


def dot3(p: np.ndarray, v) -> np.ndarray:
    """``p @ v`` for (k, 3) p and a (3,) v in a fixed order, (p0 v0 + p1 v1) + p2 v2: (k,)
    float64, the same bits on every CPU (BLAS's gemv is not)."""
    v = np.asarray(v, np.float64)
    return p[:, 0] * v[0] + p[:, 1] * v[1] + p[:, 2] * v[2]


def vdot_fixed(a, b) -> float:
    """The dot product of two short 1-D float64 vectors, summed left to right in Python
    floats (``a @ b`` and ``np.linalg.norm`` of a vector call BLAS's ddot)."""
    s = 0.0
    for x, y in zip(np.asarray(a, np.float64).tolist(), np.asarray(b, np.float64).tolist()):
        s += x * y
    return s


def unit_fixed(d) -> np.ndarray:
    """``d / |d|`` for a short 1-D vector, the length from :func:`vdot_fixed`."""
    d = np.asarray(d, np.float64)
    return d / math.sqrt(vdot_fixed(d, d))


def gram_fixed(a: np.ndarray) -> np.ndarray:
    """``a.T @ a`` for an (n, m) float64 ``a`` with small m: each entry one NumPy sum of
    elementwise products (pairwise summation in a fixed order), the same bits on every CPU."""
    a = np.asarray(a, np.float64)
    m = a.shape[1]
    g = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            g[i, j] = g[j, i] = float(np.sum(a[:, i] * a[:, j]))
    return g


def lstsq_fixed(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The least-squares solution of ``a x = b`` ((n, m) with small m, (n,)) by the normal
    equations, their sums in a fixed order (:func:`gram_fixed`) and solved by
    :func:`solve_fixed`: the same bits on every CPU, where LAPACK's lstsq is not. Squares
    the condition number: centre and scale the columns first. None when singular."""
    a = np.asarray(a, np.float64)
    rhs = np.array([float(np.sum(a[:, i] * b)) for i in range(a.shape[1])])
    x = solve_fixed(gram_fixed(a), rhs[:, None])
    return None if x is None else x[:, 0]


def eigh3_fixed(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and unit eigenvectors (columns) of a symmetric 3x3 float64
    matrix, as ``np.linalg.eigh`` returns them, by cyclic Jacobi rotations in Python floats
    (+ - * / and sqrt, correctly rounded on every CPU; LAPACK's eigh is not)."""
    a = [[float(x) for x in row] for row in np.asarray(c, np.float64)]
    v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    for _ in range(50):
        off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2]
        scale = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2]
        if off == 0.0 or off <= 1e-40 * scale:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = a[p][q]
            if apq == 0.0:
                continue
            theta = (a[q][q] - a[p][p]) / (2.0 * apq)
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            cs = 1.0 / math.sqrt(t * t + 1.0)
            sn = t * cs
            for k in range(3):  # columns p, q of a
                akp, akq = a[k][p], a[k][q]
                a[k][p], a[k][q] = cs * akp - sn * akq, sn * akp + cs * akq
            for k in range(3):  # rows p, q
                apk, aqk = a[p][k], a[q][k]
                a[p][k], a[q][k] = cs * apk - sn * aqk, sn * apk + cs * aqk
            a[p][q] = a[q][p] = 0.0
            for k in range(3):
                vkp, vkq = v[k][p], v[k][q]
                v[k][p], v[k][q] = cs * vkp - sn * vkq, sn * vkp + cs * vkq
    w = [a[0][0], a[1][1], a[2][2]]
    order = sorted(range(3), key=lambda i: (w[i], i))
    vals = np.array([w[i] for i in order])
    vecs = np.array([[v[k][i] for i in order] for k in range(3)])
    vecs /= np.sqrt(vecs[0] * vecs[0] + vecs[1] * vecs[1] + vecs[2] * vecs[2])[None, :]
    return vals, vecs
