"""Which smooth surface underlies the capture? Breckon and Fisher, "Plausible 3D colour
surface completion using non-parametric techniques", Sec. 3 (the underlying geometric
surface fit and its completion) and Sec. 3's deterministic local reference frames.

Least-squares fits of a plane, a sphere or a cylinder to captured points, chosen by
residual or named; the projection of points onto the fit, its normal, a 2D parameter
domain in length units (plane: (u, v); sphere: (azimuth, polar) angles; cylinder:
(angle, height)), the paper's tangent frame and the region of the fit to complete.

- Plane: centroid + the singular vector of least variance.
- Sphere: the algebraic fit ``|p|^2 = 2 c . p + d`` refined by Gauss-Newton on the
  geometric distance ``|p - c| - r`` (``scipy.optimize.least_squares``).
- Cylinder: axis candidates (the direction of least variance of the normals, and the
  three principal axes of the points), a circle fitted to the points projected along
  each, then the geometric distance ``dist(p, axis) - r`` refined over direction,
  centre and radius; the candidate with the lowest residual wins.
- Choice (``kind=None``): the simplest model (plane, sphere, cylinder in that order)
  whose RMS residual is within 25% of the best one's; a sphere or cylinder whose
  radius is over 50x the capture's extent is a plane and is dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geosynth.core.exact import dot3, eigh3_fixed, gram_fixed, lstsq_fixed, norm3, unit_fixed, vdot_fixed

__all__ = ["FIT_KINDS", "SurfaceFit", "fit_frames", "fit_surface", "latitude_axis", "relief_frame", "tangent_frames"]

FIT_KINDS = ("plane", "sphere", "cylinder")
_CHOICE_SLACK = 1.25  # a simpler model within 25% of the best residual is preferred
_FLAT_RADIUS = 50.0  # radius / extent above which a sphere or cylinder is a plane
_FAR_RELATIVE = 0.05  # a named fit is far when its RMS > 5% of the extent ...
_FAR_FACTOR = 3.0  # ... and > 3x the best fit's RMS


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The paper's deterministic frames (Sec. 3): for a unit normal n = (x, y, z), if |x|
    is the smallest component u = (0, -z, y); if |y|, u = (z, 0, -x); if |z|, u = (-y, x, 0)
    (the same construct cyclically);
    u normalized and v = n x u. Ties go to the first axis.

    Args:
        normals: (N, 3) unit normals (float64 or float32).

    Returns:
        (u, v): two (N, 3) float64 arrays, unit, orthogonal to n and to each other.
    """
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    a = np.abs(n)
    k = np.argmin(a, axis=1)  # first minimum on ties
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    zero = np.zeros_like(x)
    u = np.where((k == 0)[:, None], np.stack([zero, -z, y], 1),
                 np.where((k == 1)[:, None], np.stack([z, zero, -x], 1), np.stack([-y, x, zero], 1)))
    u /= np.maximum(norm3(u)[:, None], 1e-300)
    v = np.cross(n, u)
    return u, v


def fit_frames(fit: "SurfaceFit", normals: np.ndarray, axis=None) -> tuple[np.ndarray, np.ndarray]:
    """Frames that follow the fit's own orientation, one tangent field without turns (our
    alternative to the paper's per-normal construct, whose choice of axis switches between
    vertices and turns the frame by 90 degrees there): on a cylinder u = axis x n (around
    the circumference) and v = n x u = the axis (up); on a plane u = basis[0], v = n x u.
    A relief with a preferred direction (rows of arches, vertical ridges) keeps it under
    these frames, so that R = 1 (or 2 for a half-turn symmetric relief) suffices. On a sphere
    u = axis x n (along the latitudes about the fit's polar axis) and v = n x u (along the
    meridians): no tangent field is without a singular point (the hairy ball theorem), this
    one's are the two poles, where u falls back to basis[0] projected on the tangent plane
    (issue 32: the paper's frames turn continuously against the latitudes over a sphere, so
    that no one of R rotations matches a directed relief there).

    Args:
        fit: a plane, cylinder or sphere :class:`SurfaceFit`.
        normals: (N, 3) unit normals of the fit.
        axis: a sphere's latitudes are taken about this unit (3,) axis (None: the fit's
            polar axis; :func:`latitude_axis` measures the one a striped relief runs around).

    Returns:
        (u, v): two (N, 3) float64 arrays, unit, orthogonal to n and to each other.
    """
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if fit.kind in ("cylinder", "sphere"):
        a = np.asarray(fit.axis if axis is None or fit.kind != "sphere" else axis, np.float64)
        u = np.cross(a[None, :], n)
        if fit.kind == "sphere":  # the poles: any tangent direction (a direction across the axis, projected)
            pole = norm3(u) < 1e-6
            if pole.any():
                e0 = _orthonormal(a)[0][None, :]
                u[pole] = e0 - dot3(n[pole], e0[0])[:, None] * n[pole]
    else:
        u = np.broadcast_to(np.asarray(fit.basis[0], np.float64), n.shape).copy()
        u = u - dot3(n, fit.basis[0])[:, None] * n
    u /= np.maximum(norm3(u)[:, None], 1e-300)
    v = np.cross(n, u)
    return u, v


def latitude_axis(fit: "SurfaceFit", points: np.ndarray, neighbours: int = 12) -> tuple[np.ndarray, float]:
    """The axis a sphere's relief runs around, measured from the points (issue 32: the
    latitude frames of :func:`fit_frames` follow stripes, or a knurl, only about their own
    axis, which a capture's file need not put along the fit's polar axis, world z).

    Stripes along the latitudes about an axis a have their height gradient along the
    meridians, so t = n x grad h (along the stripe) is orthogonal to a at every point: a is
    the eigenvector of the least eigenvalue of sum t t^T. The gradient is each point's
    least-squares slope of h over its ``neighbours`` nearest points in its tangent plane
    (the paper's frames), every sum in a fixed order: the same bits on every CPU.

    Args:
        fit: a sphere :class:`SurfaceFit`.
        points: (N, 3) float positions (N > neighbours).

    Returns:
        (axis (3,) float64 unit, its hemisphere that of the fit's axis; share: the least
        eigenvalue over their sum, 0 for perfect stripes about the axis, 1/3 for a relief
        with no such axis).
    """
    from geosynth.core.exact import eigh3_fixed, gram_fixed
    from geosynth.core.neighbours import nearest

    p = np.asarray(points, np.float64).reshape(-1, 3)
    d0 = p - np.asarray(fit.center, np.float64)[None, :]
    r = norm3(d0)
    n = d0 / np.maximum(r, 1e-300)[:, None]
    u, v = tangent_frames(n)
    k = min(int(neighbours), len(p) - 1)
    nb = nearest(p, k=k)[1]
    suu = np.zeros(len(p))
    suv, svv, sub, svb = suu.copy(), suu.copy(), suu.copy(), suu.copy()
    for j in range(k):  # the 2x2 normal equations of the slope, summed neighbour by neighbour
        d = p[nb[:, j]] - p
        du = (d[:, 0] * u[:, 0] + d[:, 1] * u[:, 1]) + d[:, 2] * u[:, 2]
        dv = (d[:, 0] * v[:, 0] + d[:, 1] * v[:, 1]) + d[:, 2] * v[:, 2]
        b = r[nb[:, j]] - r
        suu, suv, svv, sub, svb = suu + du * du, suv + du * dv, svv + dv * dv, sub + du * b, svb + dv * b
    det = suu * svv - suv * suv
    ok = det > 1e-300
    det = np.where(ok, det, 1.0)
    gu = np.where(ok, (svv * sub - suv * svb) / det, 0.0)
    gv = np.where(ok, (suu * svb - suv * sub) / det, 0.0)
    g = gu[:, None] * u + gv[:, None] * v
    t = np.cross(n, g)
    w, vec = eigh3_fixed(gram_fixed(t))
    a = vec[:, 0] / math.sqrt(float(vec[0, 0] ** 2 + vec[1, 0] ** 2 + vec[2, 0] ** 2))
    if (a[0] * fit.axis[0] + a[1] * fit.axis[1]) + a[2] * fit.axis[2] < 0:
        a = -a
    total = float(w[0] + w[1] + w[2])
    return a, (float(w[0]) / total if total > 0 else 1.0 / 3.0)


def relief_frame(fit: "SurfaceFit", points: np.ndarray, cut: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """The points' relief in the fit's own unrolled (u, v) frame, world units (issue 32: the
    relief's period and orientation are measured there, :mod:`geosynth.completion.spectrum`).

    plane: (u, v) along ``basis``; cylinder: u = radius x angle, v = height along the axis;
    sphere: a sinusoidal projection, u = radius x (azimuth - pi) x sin(polar), v = radius x
    polar. The angle is measured from ``cut`` (radians; None: the middle of the widest gap
    between the points' azimuths, so that a part of the surface is not split at 0 / 2 pi);
    the frame's x (u) is the fit's u frame direction (around a cylinder), y (v) its axis.

    Args:
        fit: the :class:`SurfaceFit`.
        points: (N, 3) float positions.
        cut: the azimuth where the unrolling starts, or None.

    Returns:
        (uv (N, 2) float64, h (N,) float64 signed heights over the fit, the cut used).
    """
    q = fit.to_param(points)
    h = fit.distance(points)
    if fit.kind == "plane":
        return q, h, 0.0
    if cut is None:
        az = np.sort(q[:, 0])
        gaps = np.diff(np.concatenate([az, [az[0] + 2 * math.pi]])) if len(az) else np.array([2 * math.pi])
        k = int(np.argmax(gaps))
        cut = float((az[k] + gaps[k] / 2) % (2 * math.pi)) if len(az) else 0.0
    a = np.mod(q[:, 0] - cut, 2 * math.pi)
    if fit.kind == "cylinder":
        return np.stack([fit.radius * a, q[:, 1]], 1), h, cut
    return np.stack([fit.radius * (a - math.pi) * np.sin(q[:, 1]), fit.radius * q[:, 1]], 1), h, cut


@dataclass(frozen=True)
class SurfaceFit:
    """A fitted plane, sphere or cylinder.

    Attributes:
        kind: "plane", "sphere" or "cylinder".
        center: (3,) float64: the plane's point nearest the world origin, the sphere's
            centre, or a point on the cylinder's axis (at height 0).
        axis: (3,) unit float64: the plane's normal, the cylinder's axis direction
            (the sphere's polar axis, for its angles).
        radius: the sphere's or cylinder's radius (inf for a plane).
        basis: (2, 3) float64: two unit vectors orthogonal to ``axis`` (the plane's u and
            v directions: u along world axis k+1 (cyclically) projected, where k is the
            normal's largest component, so that a plane z = c has u = x, v = y; the zero azimuth of a sphere or cylinder is basis[0]).
        rms: RMS geometric residual of the capture to the fit (the capture's units).
        extent: the capture's bounding-box diagonal.
    """

    kind: str
    center: np.ndarray
    axis: np.ndarray
    radius: float
    basis: np.ndarray
    rms: float
    extent: float

    # ------------------------------------------------------------------ geometry

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of (N, 3) points to the fit, positive on the normal's side (outside)."""
        p = np.asarray(points, dtype=np.float64) - self.center
        if self.kind == "plane":
            return dot3(p, self.axis)
        if self.kind == "sphere":
            return norm3(p) - self.radius
        radial = p - np.outer(dot3(p, self.axis), self.axis)
        return norm3(radial) - self.radius

    def normal(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float64 unit outward normals of the fit at the points' projections."""
        p = np.asarray(points, dtype=np.float64) - self.center
        if self.kind == "plane":
            return np.broadcast_to(self.axis, p.shape).copy()
        if self.kind == "cylinder":
            p = p - np.outer(dot3(p, self.axis), self.axis)
        r = norm3(p)[:, None]
        out = p / np.maximum(r, 1e-300)
        bad = r[:, 0] < 1e-12  # on the axis / at the centre: any direction orthogonal to the axis
        out[bad] = self.basis[0]
        return out

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) float64 closest points of the fit to (N, 3) points."""
        p = np.asarray(points, dtype=np.float64)
        return p - self.distance(p)[:, None] * self.normal(p)

    def to_param(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) float64 parameters of the points' projections.

        plane: (u, v) lengths along ``basis``; sphere: (azimuth in [0, 2 pi), polar angle in
        [0, pi] from ``axis``); cylinder: (angle in [0, 2 pi), height along ``axis``).
        """
        p = np.asarray(points, dtype=np.float64) - self.center
        a, b = dot3(p, self.basis[0]), dot3(p, self.basis[1])
        if self.kind == "plane":
            return np.stack([a, b], 1)
        az = np.mod(np.arctan2(b, a), 2 * np.pi)
        h = dot3(p, self.axis)
        if self.kind == "cylinder":
            return np.stack([az, h], 1)
        polar = np.arctan2(np.hypot(a, b), h)
        return np.stack([az, polar], 1)

    def from_param(self, param: np.ndarray) -> np.ndarray:
        """(N, 3) float64 points of the fit at (N, 2) parameters (the inverse of :meth:`to_param`)."""
        q = np.asarray(param, dtype=np.float64).reshape(-1, 2)
        e0, e1 = self.basis
        if self.kind == "plane":
            return self.center + q[:, :1] * e0 + q[:, 1:] * e1
        ca, sa = np.cos(q[:, :1]), np.sin(q[:, :1])
        if self.kind == "cylinder":
            return self.center + self.radius * (ca * e0 + sa * e1) + q[:, 1:] * self.axis
        sp, cp = np.sin(q[:, 1:]), np.cos(q[:, 1:])
        return self.center + self.radius * (sp * (ca * e0 + sa * e1) + cp * self.axis)

    def describe(self) -> str:
        """One line: the kind, its parameters and the residual."""
        c = ", ".join(f"{x:.4g}" for x in self.center)
        a = ", ".join(f"{x:.3f}" for x in self.axis)
        if self.kind == "plane":
            return f"plane through ({c}), normal ({a}), RMS residual {self.rms:.4g}"
        if self.kind == "sphere":
            return f"sphere centre ({c}), radius {self.radius:.4g}, RMS residual {self.rms:.4g}"
        return f"cylinder axis ({a}) through ({c}), radius {self.radius:.4g}, RMS residual {self.rms:.4g}"

    def default_region(self, param: np.ndarray) -> tuple[tuple[float, float], tuple[float, float]]:
        """The region completed by default, from the captured part's (N, 2) parameters:
        the plane's bounding box; the cylinder's full circle over the captured height
        range; the whole sphere."""
        if self.kind == "plane":
            return (float(param[:, 0].min()), float(param[:, 0].max())), (float(param[:, 1].min()),
                                                                          float(param[:, 1].max()))
        if self.kind == "cylinder":
            return (0.0, 2 * math.pi), (float(param[:, 1].min()), float(param[:, 1].max()))
        return (0.0, 2 * math.pi), (0.0, math.pi)


# ---------------------------------------------------------------------- fitting


def _canonical(d: np.ndarray) -> np.ndarray:
    """A unit direction with its largest-magnitude component positive (a sign convention)."""
    d = unit_fixed(d)
    return -d if d[np.argmax(np.abs(d))] < 0 else d


def _orthonormal(axis: np.ndarray) -> np.ndarray:
    u, v = tangent_frames(axis[None])
    return np.stack([u[0], v[0]])


def _principal_axes(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centroid, (3, 3) rows: the principal directions of the points, of decreasing
    variance), as the rows of the SVD's vt: the eigenvectors of their scatter matrix, its
    sums in a fixed order and the eigenvectors by Jacobi rotations, so that the fits are
    the same bits on every CPU (issue 40; LAPACK's svd and eigh round by the CPU's SIMD
    path and its last bits moved every fit, hence the base lattice, the triangulation and
    the written positions)."""
    c = p.mean(0)
    _, vecs = eigh3_fixed(gram_fixed(p - c))
    return c, vecs[:, ::-1].T


def _plane(p: np.ndarray, normals: np.ndarray | None, extent: float) -> SurfaceFit:
    c, vt = _principal_axes(p)
    n = _canonical(vt[2])
    if normals is not None and float(np.sum(dot3(normals, n))) < 0:
        n = -n  # the capture's normals say which side is outside
    # (u, v) in world terms: with the normal mostly along world axis k, u is world axis
    # k+1 (cyclically) projected into the plane and v = n x u, so that a plane z = c has
    # u = x, v = y; the origin is the plane's point nearest the world origin.
    k = (int(np.argmax(np.abs(n))) + 1) % 3
    e0 = np.eye(3)[k] - n[k] * n
    e0 = unit_fixed(e0)
    basis = np.stack([e0, np.cross(n, e0)])
    rms = float(np.sqrt(np.mean(dot3(p - c, n) ** 2)))
    return SurfaceFit("plane", n * vdot_fixed(c, n), n, math.inf, basis, rms, extent)


def _algebraic(q: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The algebraic sphere (3 columns) or circle (2) fit |q|^2 = 2 c . q + d by least
    squares: (centre, squared radius), or None. The points are centred and scaled to unit
    spread first (the normal equations square the condition), and solved in a fixed order
    (:func:`geosynth.core.exact.lstsq_fixed`: LAPACK's lstsq is not the same bits on every CPU)."""
    m = q.mean(0)
    w = q - m
    s = math.sqrt(float(np.mean(np.sum(w * w, 1)))) if len(w) else 0.0
    if not s > 0:
        return None
    w = w / s
    a = np.hstack([2 * w, np.ones((len(w), 1))])
    sol = lstsq_fixed(a, np.sum(w * w, 1))
    if sol is None:
        return None
    k = q.shape[1]
    r2 = (sol[k] + vdot_fixed(sol[:k], sol[:k])) * (s * s)
    return m + s * sol[:k], r2


def _sphere(p: np.ndarray, extent: float) -> SurfaceFit | str:
    from scipy.optimize import least_squares

    got = _algebraic(p)
    c0, r2 = got if got is not None else (None, math.nan)
    if not np.isfinite(r2) or r2 <= 0:
        return "the algebraic sphere fit has no real radius (the points may be coplanar)"
    x0 = np.concatenate([c0, [math.sqrt(r2)]])

    def res(x):
        return norm3(p - x[:3]) - x[3]  # fixed-order arithmetic: MINPACK's own steps are scalar

    out = least_squares(res, x0, method="lm", max_nfev=200, x_scale="jac")
    if not out.success or not np.all(np.isfinite(out.x)) or out.x[3] <= 0:
        return f"Gauss-Newton did not converge ({out.message})"
    c, r = out.x[:3], float(out.x[3])
    axis = np.array([0.0, 0.0, 1.0])
    rms = float(np.sqrt(np.mean(res(out.x) ** 2)))
    return SurfaceFit("sphere", c, axis, r, _orthonormal(axis), rms, extent)


def _circle(q: np.ndarray) -> tuple[np.ndarray, float] | None:
    got = _algebraic(q)
    if got is None or not np.isfinite(got[1]) or got[1] <= 0:
        return None
    return got[0], math.sqrt(got[1])


def _cylinder_from(p: np.ndarray, d: np.ndarray, extent: float):
    from scipy.optimize import least_squares

    d = unit_fixed(d)
    basis = _orthonormal(d)
    q = np.stack([dot3(p, basis[0]), dot3(p, basis[1])], 1)
    circ = _circle(q)
    if circ is None:
        return None, "the circle fit across the axis has no real radius"
    cq, r0 = circ
    c0 = cq[0] * basis[0] + cq[1] * basis[1]
    # Parameters: axis direction as d + a*b0 + b*b1 (normalized), centre as c0 + e*b0 + f*b1, radius.
    def unpack(x):
        dd = d + x[0] * basis[0] + x[1] * basis[1]
        dd = unit_fixed(dd)
        return dd, c0 + x[2] * basis[0] + x[3] * basis[1], x[4]

    def res(x):
        dd, cc, r = unpack(x)
        w = p - cc
        radial = w - np.outer(dot3(w, dd), dd)
        return norm3(radial) - r

    out = least_squares(res, np.array([0, 0, 0, 0, r0], dtype=np.float64), method="lm", max_nfev=400,
                        x_scale="jac")
    if not out.success or not np.all(np.isfinite(out.x)) or out.x[4] <= 0:
        return None, f"Gauss-Newton did not converge ({out.message})"
    dd, cc, r = unpack(out.x)
    dd = _canonical(dd)
    # centre: the axis point level with the capture's lowest point along the axis (height 0 there)
    cc = cc + dot3(p - cc, dd).min() * dd
    rms = float(np.sqrt(np.mean(res(out.x) ** 2)))
    return SurfaceFit("cylinder", cc, dd, float(r), _orthonormal(dd), rms, extent), None


def _cylinder(p: np.ndarray, normals: np.ndarray | None, extent: float) -> SurfaceFit | str:
    _, vt = _principal_axes(p)
    candidates = [vt[0], vt[1], vt[2]]
    if normals is not None:
        nn = normals / np.maximum(norm3(normals)[:, None], 1e-300)
        _, vecs = eigh3_fixed(gram_fixed(nn))
        candidates.insert(0, vecs[:, 0])
    best, why = None, "no axis candidate gave a cylinder"
    for d in candidates:
        fit, reason = _cylinder_from(p, d, extent)
        if fit is None:
            why = reason
        elif best is None or fit.rms < best.rms:
            best = fit
    return best if best is not None else why


def fit_surface(points: np.ndarray, kind: str | None = None, normals: np.ndarray | None = None) -> SurfaceFit:
    """Fit the underlying smooth surface to a capture by least squares (Sec. 3).

    Args:
        points: (N, 3) finite positions of the captured part, N >= 6.
        kind: "plane", "sphere", "cylinder", or None to choose by residual (the simplest
            model within 25% of the lowest RMS residual).
        normals: optional (N, 3) normals; they give the cylinder its first axis candidate.

    Returns:
        The :class:`SurfaceFit`.

    Raises:
        ValueError: an unknown kind; fewer than 6 points; a fit that does not converge
            (the reason); a named fit far from the data: RMS residual over 5% of the
            capture's extent and over 3x the best model's, with both residuals.
    """
    if kind is not None and kind not in FIT_KINDS:
        raise ValueError(f"fit must be one of {', '.join(FIT_KINDS)} or None (chosen by residual), got {kind!r}.")
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 6:
        raise ValueError(f"a surface fit needs at least 6 points of shape (N, 3), got shape {p.shape}.")
    if not np.isfinite(p).all():
        raise ValueError("the capture's positions have NaN or inf values; remove those points.")
    extent = math.sqrt(vdot_fixed(p.max(0) - p.min(0), p.max(0) - p.min(0)))
    if extent <= 0:
        raise ValueError("the capture's points all coincide; no surface can be fitted.")
    # LAPACK's svd here only for the error (its last bits decide nothing else)
    spread = np.linalg.svd(p - p.mean(0), compute_uv=False)
    if spread[1] <= 1e-9 * spread[0]:
        raise ValueError("the capture's points lie on a line; no surface can be fitted (give a surface patch).")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != p.shape or not np.isfinite(normals).all():
            normals = None
    fits: dict[str, SurfaceFit] = {"plane": _plane(p, normals, extent)}
    reasons: dict[str, str] = {}
    for name, make in (("sphere", lambda: _sphere(p, extent)), ("cylinder", lambda: _cylinder(p, normals, extent))):
        got = make()
        if isinstance(got, str):
            reasons[name] = got
        elif got.radius > _FLAT_RADIUS * extent:
            reasons[name] = f"radius {got.radius:.4g} is over {_FLAT_RADIUS:g}x the extent (a plane)"
        else:
            fits[name] = got
    if kind is not None and kind not in fits:
        raise ValueError(f"the {kind} fit did not converge: {reasons[kind]}; name another fit or leave it to the "
                         f"residual (fit=None).")
    best = min(fits.values(), key=lambda f: f.rms)
    if kind is None:
        for name in FIT_KINDS:
            if name in fits and fits[name].rms <= _CHOICE_SLACK * best.rms + 1e-12 * extent:
                return fits[name]
    chosen = fits[kind]
    if chosen.rms > _FAR_RELATIVE * extent and chosen.rms > _FAR_FACTOR * best.rms:
        raise ValueError(f"the named {kind} fit is far from the capture: RMS residual {chosen.rms:.4g} "
                         f"({chosen.rms / extent:.1%} of the capture's extent {extent:.4g}), while the {best.kind} "
                         f"fit has {best.rms:.4g}; name the {best.kind} fit or leave it to the residual (fit=None).")
    return chosen
