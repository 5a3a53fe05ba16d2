"""Device arrays and the constants the API and the backends share (a leaf module).

:class:`DeviceArray` is what :func:`geosynth.compute.backend.to_device` and ``keep_on_device=True`` operations
return; the backends (``geosynth._backends``) construct them in their ``to_device`` and
``empty``. This module imports no other geosynth module, so the API modules and the
backends can both import it without a cycle (uploading, ``to_device``, is the device
switch's: :mod:`geosynth.compute.backend`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["NONFINITE_SCORES", "SELECT_EQ", "SELECT_LEQ", "SELECT_LT", "DeviceArray", "float_stats"]

# Selection modes, shared with the kernels (kernels/ssd.py and ssd.cl: SELECT_LEQ, SELECT_LT, SELECT_EQ).
SELECT_LEQ, SELECT_LT, SELECT_EQ = 0, 1, 2

# The one refusal of float scores that are not finite, from the host and the device paths.
NONFINITE_SCORES = (
    "scores contains NaN or inf; every score must be finite (float data whose squared differences "
    "overflow float32 score inf: scale the data down)."
)


class DeviceArray:
    """An array that lives on one device, with the backend that owns it.

    Made by :func:`geosynth.to_device` or returned by an operation called with
    ``keep_on_device=True``. Pass it back to operations on the same device to avoid
    copies; ``.numpy()`` copies it to the host.

    Attributes:
        data: the backend's own array (``warp.array``, or a ``pyopencl.Buffer`` with spare bytes past the data).
        backend: the backend that owns it.
        shape: the logical shape.
        dtype: the NumPy dtype.
    """

    def __init__(self, data: Any, backend: Any, shape: tuple[int, ...], dtype: np.dtype):
        self.data = data
        self.backend = backend
        self.shape = tuple(int(s) for s in shape)
        self.dtype = np.dtype(dtype)
        self._derived: dict[Any, DeviceArray] = {}
        self._stats: tuple[int, float, float] | None = None  # see value_stats

    def value_stats(self) -> tuple[int, float, float] | None:
        """For float data: (how many values are NaN or inf, min and max of the finite ones);
        None for other dtypes.

        Recorded from the host copy by :func:`geosynth.compute.backend.to_device`; for arrays made otherwise, read
        back once and kept (DeviceArrays are never modified in place). The public
        operations use it to refuse NaN/inf and data whose float32 scores could overflow.
        """
        if self.dtype.kind != "f":
            return None
        if self._stats is None:
            self._stats = float_stats(self.numpy())
        return self._stats

    def known_stats(self) -> tuple[int, float, float] | None:
        """:meth:`value_stats` if already known (no read back), else None."""
        return self._stats

    @property
    def device(self) -> str:
        return self.backend.name

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def numpy(self) -> np.ndarray:
        """Copy to a host NumPy array (a synchronization point)."""
        return self.backend.to_host(self)

    def derived(self, key: Any, make) -> "DeviceArray":
        """A device array computed from this one on the host, made once and cached.

        Used for views the kernels need in another layout (a periodically padded copy
        for ``wrap=True``). The first call reads this array back once; DeviceArrays
        are never modified in place, so the cache stays valid.

        Args:
            key: a hashable description of the derivation.
            make: function from this array's host copy (NumPy) to the derived one.
        """
        if key not in self._derived:
            self._derived[key] = self.backend.to_device(np.ascontiguousarray(make(self.numpy())))
        return self._derived[key]

    def __repr__(self) -> str:
        return f"DeviceArray(shape={self.shape}, dtype={self.dtype}, device={self.device!r})"


def float_stats(host: np.ndarray) -> tuple[int, float, float]:
    """(how many values are NaN or inf, min, max of the finite values) of a float array;
    min and max are 0 when no value is finite."""
    finite = np.isfinite(host)
    bad = int(host.size - np.count_nonzero(finite))
    values = host[finite] if bad else host
    if values.size == 0:
        return bad, 0.0, 0.0
    return bad, float(values.min()), float(values.max())
