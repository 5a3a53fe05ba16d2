"""Each kernel family's backend operations are declared once (geosynth/_backends/interfaces.py,
and the SSD primitives on base.Backend); the Warp and OpenCL mixins implement them with the
same parameters, and the array groups' field order is the kernels' argument order."""

from __future__ import annotations

import dataclasses
import importlib
import inspect

import numpy as np
import pytest

from geosynth._backends import interfaces as ifc
from geosynth._backends.base import Backend
from geosynth._backends.opencl_backend import OpenCLBackend
from geosynth._backends.opencl_cascade import OpenCLCascadeOps
from geosynth._backends.opencl_growth import OpenCLGrowthOps
from geosynth._backends.opencl_mesh import OpenCLMeshOps
from geosynth._backends.opencl_points import OpenCLPointsOps
from geosynth._backends.opencl_pyramid import OpenCLPyramidOps
from geosynth._backends.opencl_relief import OpenCLReliefOps
from geosynth._backends.opencl_texel import OpenCLTexelOps
from geosynth._backends.warp_backend import WarpBackend
from geosynth._backends.warp_cascade import WarpCascadeOps
from geosynth._backends.warp_growth import WarpGrowthOps
from geosynth._backends.warp_mesh import WarpMeshOps
from geosynth._backends.warp_points import WarpPointsOps
from geosynth._backends.warp_pyramid import WarpPyramidOps
from geosynth._backends.warp_relief import WarpReliefOps
from geosynth._backends.warp_texel import WarpTexelOps

# (interface, Warp implementation, OpenCL implementation)
FAMILIES = [
    (Backend, WarpBackend, OpenCLBackend),  # the SSD primitives and memory
    (ifc.MeshOps, WarpMeshOps, OpenCLMeshOps),
    (ifc.PointsOps, WarpPointsOps, OpenCLPointsOps),
    (ifc.TexelOps, WarpTexelOps, OpenCLTexelOps),
    (ifc.GrowthOps, WarpGrowthOps, OpenCLGrowthOps),
    (ifc.PyramidOps, WarpPyramidOps, OpenCLPyramidOps),
    (ifc.CascadeOps, WarpCascadeOps, OpenCLCascadeOps),
    (ifc.ReliefOps, WarpReliefOps, OpenCLReliefOps),
]
IDS = [f[0].__name__ for f in FAMILIES]


def _params(fn) -> list[tuple[str, object]]:
    """(name, default) of every parameter after self."""
    return [(p.name, p.default) for p in list(inspect.signature(fn).parameters.values())[1:]]


@pytest.mark.parametrize("family", FAMILIES, ids=IDS)
def test_interface_declares_every_operation_typed_and_documented(family):
    interface = family[0]
    assert interface.__abstractmethods__, interface
    for name in interface.__abstractmethods__:
        fn = getattr(interface, name)
        assert inspect.getdoc(fn), f"{interface.__name__}.{name} has no docstring"
        sig = inspect.signature(fn)
        missing = [p.name for p in list(sig.parameters.values())[1:] if p.annotation is inspect.Parameter.empty]
        assert not missing, f"{interface.__name__}.{name}: parameters without a type: {missing}"
        assert sig.return_annotation is not inspect.Signature.empty


@pytest.mark.parametrize("family", FAMILIES, ids=IDS)
def test_both_backends_implement_the_interface_with_its_signatures(family):
    interface, warp_impl, opencl_impl = family
    for impl in (warp_impl, opencl_impl):
        assert issubclass(impl, interface)
        assert not getattr(impl, "__abstractmethods__", frozenset()), f"{impl.__name__} leaves abstract methods"
        for name in interface.__abstractmethods__:
            mine = getattr(impl, name)
            assert mine is not getattr(interface, name), f"{impl.__name__}.{name} is not implemented"
            assert _params(mine) == _params(getattr(interface, name)), f"{impl.__name__}.{name}"
    for name in interface.__abstractmethods__:  # and so the same names, in the same order, on both
        assert _params(getattr(warp_impl, name)) == _params(getattr(opencl_impl, name)), name
    for backend in (WarpBackend, OpenCLBackend):
        assert issubclass(backend, interface)


def test_no_backend_operation_outside_an_interface():
    """Every public method of a family mixin is one its interface declares (or provides)."""
    for interface, warp_impl, opencl_impl in FAMILIES[1:]:
        for impl in (warp_impl, opencl_impl):
            public = {n for n, v in vars(impl).items() if callable(v) and not n.startswith("_")}
            assert public <= set(dir(interface)), (impl.__name__, public - set(dir(interface)))


# Kernel argument names per array group, for each kernel taking groups (Warp spells
# next/prev as nxt/prv).
KERNEL_GROUPS = [
    ("growth", "grow_patches", (ifc.GrowthInputs, ifc.GrowthOutputs, ifc.GrowthScratch)),
    ("growth", "blend_gaps", (ifc.BlendInputs, ifc.PatchFrames, ifc.BlendOutputs, ifc.BlendScratch)),
    ("growth", "match_coherent", (ifc.MatchInputs, ifc.MatchState, ifc.MatchScratch)),
    ("sdf_mesh", "mesh_distance_points", (ifc.MeshArrays,)),
    ("sdf_mesh", "mesh_distance_grid", (ifc.MeshArrays,)),
    ("relief", "relief_scores", (ifc.ReliefIndexArrays, ifc.ReliefQueryArrays)),
]
_WARP_NAMES = {"nxt": "next", "prv": "prev"}


def _kernel_arg_names(device: str, family: str, name: str) -> list[str]:
    import geosynth

    backend = geosynth.get_backend(device)
    if isinstance(backend, OpenCLBackend):
        import pyopencl as cl

        dtype = np.float32 if family == "sdf_mesh" else np.float64
        kernel = backend._kernel(family, name, dtype)
        return [kernel.get_arg_info(i, cl.kernel_arg_info.NAME) for i in range(kernel.num_args)]
    kernel = getattr(importlib.import_module(f"geosynth.kernels.{family}"), f"{name}_kernel")
    return [_WARP_NAMES.get(a.label, a.label) for a in kernel.adj.args]


@pytest.mark.parametrize("family, name, groups", KERNEL_GROUPS, ids=[k[1] for k in KERNEL_GROUPS])
def test_array_group_fields_are_the_kernels_argument_order(device, family, name, groups):
    args = _kernel_arg_names(device, family, name)
    last = -1
    for group in groups:
        names = [f.name for f in dataclasses.fields(group)]
        start = args.index(names[0])
        assert args[start:start + len(names)] == names, (group.__name__, args)
        assert start > last, f"{group.__name__} is passed out of order in {name}"
        last = start


def test_array_group_buffers_follow_field_order(device):
    import geosynth

    backend = geosynth.get_backend(device)
    group = ifc.BlendOutputs.allocate(backend, 5)
    assert [a.shape for a in group.arrays()] == [(5, 3), (5,)]
    assert group.buffers() == [group.colours.data, group.coloured.data]
    host = ifc.MatchState(*(backend.to_device(np.arange(3, dtype=np.int32) + i) for i in range(3))).to_host(backend)
    assert list(host) == ["coloured", "colours", "source"]
    np.testing.assert_array_equal(host["source"], [2, 3, 4])
    with pytest.raises(dataclasses.FrozenInstanceError):
        group.colours = None
