"""Is this argument acceptable? Implements no paper section: the checks every method's API
shares.

Input checks shared by the public operations: each error names the argument,
what was expected and what was given."""

from __future__ import annotations

import math

import numpy as np

from geosynth.compute.backend import get_backend
from geosynth.core.arrays import DeviceArray, float_stats

# uint8 data is scored in uint32: the largest possible score must fit.
UINT32_MAX = np.iinfo(np.uint32).max


def resolve_backend(device: str | None, *arrays):
    """The backend to run on: the one that holds any DeviceArray input, else ``device``.

    Raises:
        RuntimeError: inputs on different devices, or ``device`` names another one.
    """
    held = [a.backend for a in arrays if isinstance(a, DeviceArray)]
    if held:
        backend = held[0]
        for other in held[1:]:
            if other is not backend:
                raise RuntimeError(f"inputs live on different devices ({backend.name} vs {other.name}).")
        if device is not None and device != "auto" and get_backend(device) is not backend:
            raise RuntimeError(
                f"inputs live on {backend.name} but device={device!r} was asked for; "
                "pass device=None or move the inputs with geosynth.to_device."
            )
        return backend
    return get_backend("auto" if device is None else device)


def as_data(name: str, array, ndims: tuple[int, ...]):
    """Check a data array (float32 or uint8); other float dtypes become float32.

    Returns the array (contiguous NumPy, or the DeviceArray as given).

    Raises:
        TypeError: not an array, or an unsupported dtype.
        ValueError: wrong number of dimensions.
    """
    if not isinstance(array, DeviceArray):
        if not isinstance(array, np.ndarray):
            array = np.asarray(array)
        if array.dtype == np.uint8 or array.dtype == np.float32:
            array = np.ascontiguousarray(array)
        elif np.issubdtype(array.dtype, np.floating):
            array = np.ascontiguousarray(array, dtype=np.float32)
        else:
            raise TypeError(
                f"{name} has unsupported dtype {array.dtype}: expected float32 (other floats are "
                "converted) or uint8 (scored exactly in integers)."
            )
    elif array.dtype not in (np.dtype(np.float32), np.dtype(np.uint8)):
        raise TypeError(f"{name} has unsupported dtype {array.dtype}: expected float32 or uint8.")
    if array.ndim not in ndims:
        want = " or ".join(str(n) for n in ndims)
        raise ValueError(f"{name} must have {want} dimensions, got shape {array.shape}.")
    return array


def check_bool(name: str, value) -> bool:
    """A flag must be a bool: a string such as "no" would otherwise count as True."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}.")
    return bool(value)


def check_finite(name: str, array) -> None:
    """Refuse NaN or inf in float data: a host array, or a DeviceArray (its recorded
    value stats, see :meth:`geosynth.DeviceArray.value_stats`)."""
    finite_range(name, array)


def finite_range(name: str, array) -> tuple[float, float] | None:
    """The (min, max) of float data after refusing NaN or inf; None for other dtypes.

    Raises:
        ValueError: some value is NaN or inf (the message says how many).
    """
    if isinstance(array, DeviceArray):
        stats = array.value_stats()
    elif isinstance(array, np.ndarray) and array.dtype.kind == "f":
        stats = float_stats(array)
    else:
        return None
    if stats is None:
        return None
    bad, lo, hi = stats
    if bad:
        raise ValueError(f"{name} contains {bad} NaN or inf value(s); every value must be finite.")
    return lo, hi


# float32 sums of squares stay below half of float32's largest value: room for rounding.
FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32_SCORE_LIMIT = FLOAT32_MAX / 2


def check_float_scores(names: str, data_range, query_range, total_weight: float) -> None:
    """Refuse float data whose scores could overflow float32 to inf.

    A score is ``sum_k w_k (x_k - q_k)^2``; with every value in [lo, hi] it is at most
    ``(hi - lo)^2 * sum_k w_k``, which must stay below half of float32's largest value.

    Args:
        names: the arguments, for the message ("candidates and queries").
        data_range, query_range: (min, max) of each, as :func:`finite_range` returns.
        total_weight: sum of the weights over one score's terms (the term count if unweighted).

    Raises:
        ValueError: naming the arguments, the largest possible score and how far to scale.
    """
    lo = min(data_range[0], query_range[0])
    hi = max(data_range[1], query_range[1])
    span, weight = float(hi) - float(lo), float(total_weight)
    worst = span * span * weight
    if worst <= _FLOAT32_SCORE_LIMIT:
        return
    limit = math.sqrt(_FLOAT32_SCORE_LIMIT / weight)
    factor = 10.0 ** math.ceil(math.log10(span / limit))
    raise ValueError(
        f"{names} span values from {lo:.6g} to {hi:.6g}: a score (a sum of squared differences with total "
        f"weight {weight:g}) could reach {worst:.3g}, beyond float32's largest value {FLOAT32_MAX:.3g}; "
        f"scale the data to span at most {limit:.3g} (e.g. divide it by {factor:.0e}), or use smaller weights."
    )


def same_kind(name: str, array, reference_name: str, reference) -> np.ndarray | DeviceArray:
    """Make ``array`` the dtype of ``reference`` (float32 or uint8), or refuse."""
    want = reference.dtype
    if isinstance(array, DeviceArray):
        if array.dtype != want:
            raise TypeError(f"{name} has dtype {array.dtype} but {reference_name} has {want}; they must match.")
        return array
    array = np.asarray(array)
    if want == np.uint8:
        if array.dtype != np.uint8:
            raise TypeError(
                f"{name} has dtype {array.dtype} but {reference_name} is uint8; pass uint8 {name} "
                f"(or convert {reference_name} to float32)."
            )
        return np.ascontiguousarray(array)
    if not np.issubdtype(array.dtype, np.floating) and not np.issubdtype(array.dtype, np.integer):
        raise TypeError(f"{name} has unsupported dtype {array.dtype}: expected a float array.")
    return np.ascontiguousarray(array, dtype=np.float32)


def as_weights(name: str, weights, length: int, data_dtype: np.dtype) -> np.ndarray:
    """Check weights: shape (length,), finite, >= 0; integers for uint8 data.

    Returns float32 weights for float data, uint32 weights for uint8 data.
    """
    w = np.asarray(weights)
    if w.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},), got {w.shape}.")
    if data_dtype == np.uint8:
        if w.dtype.kind not in "iu":
            raise TypeError(
                f"{name} has dtype {w.dtype}: uint8 data is scored exactly, so weights must be integers "
                "(or convert the data to float32 to use float weights)."
            )
        if (w < 0).any():
            raise ValueError(f"{name} must be non-negative, got a minimum of {w.min()}.")
        if w.size and int(w.max()) > UINT32_MAX:
            raise ValueError(f"{name} exceeds the uint32 range.")
        return w.astype(np.uint32)
    if w.dtype.kind not in "iuf":
        raise TypeError(f"{name} has unsupported dtype {w.dtype}: expected a float array.")
    w = w.astype(np.float32)
    if not np.isfinite(w).all():
        raise ValueError(f"{name} contains NaN or inf; every weight must be finite.")
    if (w < 0).any():
        raise ValueError(f"{name} must be non-negative, got a minimum of {w.min()}.")
    return w


def check_uint32_range(total_weight: int, what: str) -> None:
    """For uint8 data the largest score, total_weight * 255^2, must fit in uint32."""
    worst = int(total_weight) * 255 * 255
    if worst > UINT32_MAX:
        raise ValueError(
            f"uint8 scores of {what} could reach {worst}, beyond uint32 ({UINT32_MAX}): use fewer entries, "
            "smaller weights, or float32 data."
        )


def as_points3(name: str, a, n: int | None = None, *, dtype=np.float64, finite: bool = True) -> np.ndarray:
    """``a`` as a C-contiguous (N, 3) array of ``dtype`` (N = ``n`` when given), finite unless
    ``finite`` is False (the caller then reports bad rows its own way), or a one-line error:
    the one (N, 3) point check of the package."""
    arr = np.asarray(a)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a numeric (N, 3) array, got dtype {arr.dtype}.")
    arr = np.ascontiguousarray(arr, dtype=dtype)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}.")
    if n is not None and len(arr) != n:
        raise ValueError(f"{name} must have {n} rows to match the positions, got {len(arr)}.")
    if finite and not np.isfinite(arr).all():
        raise ValueError(f"{name} holds NaN or inf values; remove those points first.")
    return arr


def as_unit_vectors(name: str, n: np.ndarray) -> np.ndarray:
    """(N, 3) vectors scaled to length 1; zero-length ones are an error naming the first."""
    length = np.linalg.norm(n, axis=1)
    bad = length < 1e-12
    if bad.any():
        raise ValueError(f"{name} has zero-length normals (first at index {int(np.argmax(bad))}).")
    return n / length[:, None]


def check_positive(name: str, v) -> float:
    """A finite number > 0 as a float (bools refused), or a one-line error."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be a number, got {type(v).__name__}.")
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {v!r}.")
    return v
