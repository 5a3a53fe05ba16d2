"""How does an OpenCL device build and launch the kernels? Implements no paper section.

OpenCL backend: builds ``kernels/*.cl`` once per context and dtype, launches them.

Buffers are plain ``cl.Buffer`` objects with 64 spare bytes past the data, so that
the 16-wide kernels (``ssd_gather_x16``) may read a full vector at the last element.
"""

from __future__ import annotations

import hashlib
import re
import warnings
from importlib import resources

import numpy as np
import pyopencl as cl

from geosynth._backends.base import Backend
from geosynth._backends.opencl_cascade import OpenCLCascadeOps
from geosynth._backends.opencl_growth import OpenCLGrowthOps
from geosynth._backends.opencl_mesh import OpenCLMeshOps
from geosynth._backends.opencl_points import OpenCLPointsOps
from geosynth._backends.opencl_pyramid import OpenCLPyramidOps
from geosynth._backends.opencl_relief import OpenCLReliefOps
from geosynth._backends.opencl_texel import OpenCLTexelOps
from geosynth.core.arrays import DeviceArray
from geosynth.core.config import OPENCL_CONTEXTS, verbose

_SPARE_BYTES = 64  # >= 16 elements of the widest type read by a 16-wide load
# Work-group sizes are always given: with none, PoCL picks the largest divisor of the
# range up to 4096, which can put a whole launch in one group, on one core.
_LOCAL_1D = 64
# ssd_dense_rows: candidate rows per work-item, for uchar (True) and float (False) builds
# (measured on PoCL: float rows stream 45-75 GB/s two at a time, 35-46 eight at a time).
_DENSE_ROWS = {True: 8, False: 2}
_SMALL_UPLOAD = 1 << 16  # bytes; smaller arrays are uploaded in one call (per-call overhead)
# OpenCL scalar argument types -> NumPy. Kernels get their scalar types declared once
# (Kernel.set_scalar_arg_dtypes): an undeclared NumPy scalar costs pyopencl ~7 us per
# argument and launch (measured, PoCL), 60-70 us for the gather kernels' 10 scalars.
_SCALAR_TYPES = {"char": np.int8, "uchar": np.uint8, "short": np.int16, "ushort": np.uint16, "int": np.int32,
                 "uint": np.uint32, "long": np.int64, "ulong": np.uint64, "float": np.float32, "double": np.float64}


def _round_up(value: int, multiple: int) -> int:
    return -(-value // multiple) * multiple


def _scalar_arg_dtypes(kernel: cl.Kernel) -> list:
    """Per argument: the NumPy dtype of a scalar, None for a buffer (or anything else)."""
    types = []
    for i in range(kernel.num_args):
        name = kernel.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME)
        qualifier = kernel.get_arg_info(i, cl.kernel_arg_info.ADDRESS_QUALIFIER)
        scalar = qualifier == cl.kernel_arg_address_qualifier.PRIVATE and not name.endswith("*")
        types.append(_SCALAR_TYPES.get(name) if scalar else None)
    return types


# Extra build options per kernel family. sdf_mesh: the same float results as the Warp
# kernels (correctly rounded division and sqrt, as on every Warp device).
_FAMILY_OPTIONS = {"sdf_mesh": ["-cl-fp32-correctly-rounded-divide-sqrt"]}


def _kernel_dir() -> str:
    return str(resources.files("geosynth.kernels"))


def _read_source(name: str) -> str:
    return (resources.files("geosynth.kernels") / name).read_text()


# Every program the backend builds: (family, u8) is kernels/{family}.cl built with -DGS_U8
# (uint8 data, uint32 scores) or without it (float32; float64 for growth). A device is
# usable only if its compiler builds them all (see geosynth.compute.backend).
PROGRAMS: tuple[tuple[str, bool], ...] = (
    ("ssd", False), ("ssd", True), ("growth", False), ("sdf_mesh", False), ("sdf_points", False),
    ("pyramid", True), ("cascade", True), ("texel", True),
    ("relief", False),
)


def build_options(family: str, u8: bool) -> list[str]:
    """The compiler options of one program."""
    options = ["-I", _kernel_dir(), f"-DDENSE_ROWS={_DENSE_ROWS[u8]}", "-cl-kernel-arg-info"]
    return options + _FAMILY_OPTIONS.get(family, []) + (["-DGS_U8"] if u8 else [])


def programs_digest() -> str:
    """A hash of every program's source, the shared headers and the options: what decides,
    with the device and its driver, whether the programs build."""
    h = hashlib.sha256()
    headers = sorted(f.name for f in resources.files("geosynth.kernels").iterdir() if f.name.endswith(".h"))
    for name in sorted({f"{family}.cl" for family, _ in PROGRAMS}) + headers:
        h.update(name.encode() + b"\0" + _read_source(name).encode() + b"\0")
    for family, u8 in PROGRAMS:
        h.update(" ".join([family, str(u8), *build_options(family, u8)[2:]]).encode() + b"\0")
    return h.hexdigest()[:32]


class ProgramBuildError(RuntimeError):
    """A program that the device's compiler does not build; ``str()`` is one line naming
    the program and the compiler's first error."""

    def __init__(self, family: str, u8: bool, message: str):
        self.family, self.u8, self.message = family, u8, message
        super().__init__(f"{family}.cl{' (GS_U8)' if u8 else ''}: {message}")


def _compiler_message(family: str, exc: Exception) -> str:
    """The compiler's first error line, with PoCL's temporary file name replaced by the source's."""
    text = re.sub(r"\S*tempfile_\w+\.cl", f"{family}.cl", str(exc))
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.lower().startswith("error")] or [ln for ln in lines if "error" in ln.lower()]
    return (errors[0] if errors else lines[0] if lines else type(exc).__name__)[:300]


def build_program(context: cl.Context, family: str, u8: bool) -> cl.Program:
    """Build one program of PROGRAMS for a context (PoCL serves a repeated build from its cache).

    Raises:
        ProgramBuildError: the compiler failed.
    """
    try:
        with warnings.catch_warnings():
            # A build that succeeds may still log (PoCL on CPUs without AVX-512 warns that
            # 16-wide vectors change the ABI of its internal calls): the user's run stays
            # silent unless GEOSYNTH_VERBOSE asks for the runtimes' messages.
            if not verbose():
                warnings.simplefilter("ignore", cl.CompilerWarning)
            program = cl.Program(context, _read_source(f"{family}.cl")).build(options=build_options(family, u8))
    except cl.Error as exc:
        raise ProgramBuildError(family, u8, _compiler_message(family, exc)) from None
    if not program.get_info(cl.program_info.KERNEL_NAMES):
        # PoCL serves a program whose first build died in code generation from its cache
        # as a build without kernels: every kernel would fail later with INVALID_KERNEL_NAME
        raise ProgramBuildError(family, u8, "the driver returned a program without kernels (a broken kernel cache "
                                "entry: remove PoCL's cache folder, ~/.cache/pocl or $POCL_CACHE_DIR, and retry)")
    return program


def device_context(platform_index: int, device_index: int) -> tuple[cl.Device, cl.Context, dict]:
    """(device, context, programs by (family, u8)) of one OpenCL device, made once: the one
    context geosynth uses on it and the programs built in it (kept in
    ``geosynth.core.config.OPENCL_CONTEXTS``), shared by the usability check (geosynth.compute.backend) and
    the backend, so that a program is built once per process."""
    key = (platform_index, device_index)
    if key not in OPENCL_CONTEXTS:
        dev = cl.get_platforms()[platform_index].get_devices()[device_index]
        OPENCL_CONTEXTS[key] = (dev, cl.Context([dev]), {})
    return OPENCL_CONTEXTS[key]


def build_all(platform_index: int, device_index: int) -> None:
    """Build every program of PROGRAMS for one device (those not yet built in its context).

    Raises:
        ProgramBuildError: the first program its compiler does not build.
    """
    _, context, programs = device_context(platform_index, device_index)
    for pkey in PROGRAMS:
        if pkey not in programs:
            programs[pkey] = build_program(context, *pkey)


class OpenCLBackend(OpenCLCascadeOps, OpenCLGrowthOps, OpenCLMeshOps, OpenCLPointsOps, OpenCLPyramidOps, OpenCLTexelOps, OpenCLReliefOps, Backend):
    """PyOpenCL on ``"opencl:P:D"`` (platform P, device D)."""

    def __init__(self, platform_index: int, device_index: int):
        self.cl_device, self.context, self._programs = device_context(platform_index, device_index)
        self.name = f"opencl:{platform_index}:{device_index}"
        self.kind = "opencl"
        self.queue = cl.CommandQueue(self.context)
        self.is_cpu = bool(self.cl_device.type & cl.device_type.CPU)
        # Partial minima: a few contiguous chunks per core on a CPU, many strided shares on a GPU.
        self.partial_threads = 256 if self.is_cpu else 65536
        self.host_reduce_below = 1 << 16 if self.is_cpu else 0
        # PoCL on a CPU: ~0.3 ms per launch and round trip at ~12 G comparisons/s.
        self.launch_work = 4e6 if self.is_cpu else 1e6
        # bench/bm_volume.py on PoCL: one 4^3-cell stage beats 2^3 then 4^3 by 1.2-4x.
        self.bound_cells_per_side = (4,) if self.is_cpu else (2, 4)
        # Fused cascade: ~32 items per core (measured on 2 cores: one lattice plane each
        # beat three times as many by 1.3x; the shared best SSD prunes more in long items).
        self.search_items = 32 * self.cl_device.max_compute_units if self.is_cpu else 1 << 16
        self._kernels: dict[tuple, cl.Kernel] = {}
        self._dummies: dict[np.dtype, DeviceArray] = {}

    # -- programs -------------------------------------------------------------------
    def _kernel(self, family: str, name: str, data_dtype) -> cl.Kernel:
        """The kernel ``name`` of ``kernels/{family}.cl`` built for one data dtype
        (uint8 data and its uint32 scores share the GS_U8 build)."""
        u8 = np.dtype(data_dtype) in (np.dtype(np.uint8), np.dtype(np.uint32))
        key = (family, name, u8)
        kernel = self._kernels.get(key)
        if kernel is None:
            pkey = (family, u8)
            program = self._programs.get(pkey)
            if program is None:
                if pkey not in PROGRAMS:  # the usability check builds PROGRAMS: keep it complete
                    raise KeyError(f"{family}.cl {'with' if u8 else 'without'} GS_U8 is not in PROGRAMS")
                program = self._programs[pkey] = build_program(self.context, family, u8)
            kernel = self._kernels[key] = cl.Kernel(program, name)
            kernel.set_scalar_arg_dtypes(_scalar_arg_dtypes(kernel))
        return kernel

    # -- memory -------------------------------------------------------------------
    def to_device(self, array: np.ndarray) -> DeviceArray:
        host = np.ascontiguousarray(array)
        if host.nbytes <= _SMALL_UPLOAD:  # one call: allocate and copy, spare bytes zero
            staged = np.zeros(host.nbytes + _SPARE_BYTES, np.uint8)
            staged[:host.nbytes] = host.reshape(-1).view(np.uint8)
            buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=staged)
            return DeviceArray(buf, self, host.shape, host.dtype)
        buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, host.nbytes + _SPARE_BYTES)
        if host.nbytes:
            cl.enqueue_copy(self.queue, buf, host, is_blocking=False)
        # The spare bytes are zeroed so that a 16-wide read past the end is harmless.
        cl.enqueue_fill_buffer(self.queue, buf, np.uint8(0), host.nbytes, _SPARE_BYTES)
        return DeviceArray(buf, self, host.shape, host.dtype)

    def empty(self, shape, dtype) -> DeviceArray:
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        buf = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, nbytes + _SPARE_BYTES)
        return DeviceArray(buf, self, shape, dtype)

    def to_host(self, array: DeviceArray) -> np.ndarray:
        host = np.empty(array.shape, array.dtype)
        if host.size:
            # sync: a blocking copy waits for every kernel queued before it.
            cl.enqueue_copy(self.queue, host, array.data, is_blocking=True)
        return host

    def to_host_all(self, arrays) -> list[np.ndarray]:
        hosts = [np.empty(a.shape, a.dtype) for a in arrays]
        for host, array in zip(hosts, arrays):
            if host.size:
                cl.enqueue_copy(self.queue, host, array.data, is_blocking=False)
        self.queue.finish()  # sync: one wait for every copy (the queue is in order)
        return hosts

    def synchronize(self) -> None:
        self.queue.finish()

    def _dummy(self, dtype) -> cl.Buffer:
        dtype = np.dtype(dtype)
        if dtype not in self._dummies:
            self._dummies[dtype] = self.to_device(np.zeros(1, dtype))
        return self._dummies[dtype].data

    # -- kernels --------------------------------------------------------------------
    def ssd_dense(self, candidates, queries, weights, n, d, b, out) -> None:
        # Batches: 4 rows x 6 queries per work-item (float lanes, exact for unweighted
        # uint8); else _DENSE_ROWS rows, one query at a time. Both give the same results.
        tile = b > 1 and (candidates.dtype == np.float32 or weights is None)
        if tile:
            name, rows, local = "ssd_dense_tile", 4, 16
        else:
            u8 = candidates.dtype == np.uint8
            name, rows, local = "ssd_dense_rows", _DENSE_ROWS[u8], 16 if u8 else 32
        kernel = self._kernel("ssd", name, candidates.dtype)
        w = weights.data if weights is not None else self._dummy(out.dtype)
        kernel(
            self.queue, (_round_up(-(-n // rows), local),), (local,),
            candidates.data, queries.data, w, np.int32(weights is not None),
            np.int32(n), np.int32(d), np.int32(b), out.data,
        )

    def ssd_gather(self, grid, bases, lattice, steps, base0, offsets, values, weights, kc, threshold, out,
                   run: int = 0) -> None:
        nx, ny, nz = lattice
        if bases is not None and run and weights is None:  # 16-lane loads along each run of offsets
            n = nx
            self._kernel("ssd", "ssd_gather_runs", grid.dtype)(
                self.queue, (_round_up(n, 16),), (16,),
                grid.data, bases.data, np.int32(n), offsets.data, values.data, np.int32(kc), np.int32(run),
                threshold.data if threshold is not None else self._dummy(out.dtype), np.int32(threshold is not None),
                out.data,
            )
            return
        if bases is None and steps[0] == 1:
            name, gsize, lsize = "ssd_gather_x16", (-(-nx // 64), _round_up(ny, 7), nz), (1, 7, 1)
        else:
            name, gsize, lsize = "ssd_gather", (_round_up(nx, 16), ny, nz), (16, 1, 1)
        kernel = self._kernel("ssd", name, grid.dtype)
        b = bases.data if bases is not None else self._dummy(np.int32)
        w = weights.data if weights is not None else self._dummy(out.dtype)
        kernel(
            self.queue, gsize, lsize,
            grid.data, b, np.int32(bases is not None),
            np.int32(nx), np.int32(ny), np.int32(nz),
            *(np.int32(s) for s in steps), np.int32(base0),
            offsets.data, values.data, w, np.int32(weights is not None), np.int32(kc),
            threshold.data if threshold is not None else self._dummy(out.dtype), np.int32(threshold is not None),
            out.data,
        )

    def _launch_1d(self, name: str, dtype, g: int, *args) -> None:
        kernel = self._kernel("ssd", name, dtype)
        kernel(self.queue, (_round_up(g, _LOCAL_1D),), (_LOCAL_1D,), *args, np.int32(g))

    def argmin_partials(self, scores, n, part_val, part_idx) -> None:
        g = part_idx.size
        if self.is_cpu:  # contiguous 16-lane chunks: a strided share misses the cache on every read
            chunk = _round_up(-(-n // g), 16)
            self._launch_1d("argmin_chunks", scores.dtype, g, scores.data, np.int32(n), np.int32(chunk),
                            part_val.data, part_idx.data)
        else:
            self._launch_1d("argmin_partials", scores.dtype, g, scores.data, np.int32(n), part_val.data, part_idx.data)

    def count_selected(self, scores, n, chunk, thr, mode, counts) -> None:
        self._launch_1d(
            "count_selected", scores.dtype, counts.size,
            scores.data, np.int32(n), np.int32(chunk), thr.data, np.int32(mode), counts.data,
        )

    def compact_selected(self, scores, n, chunk, thr, mode, starts, out_idx) -> None:
        self._launch_1d(
            "compact_selected", scores.dtype, starts.size,
            scores.data, np.int32(n), np.int32(chunk), thr.data, np.int32(mode), starts.data, out_idx.data,
        )
