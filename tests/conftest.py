"""Per-device test generation: every test that takes ``device`` runs on each present
device (Warp ``cpu``, every OpenCL device, every ``cuda:N``), narrowed by the
environment variable GEOSYNTH_TEST_DEVICES (comma-separated device strings).

The test devices, and only they, reach tests through these fixtures:

- ``device``: each test device in turn.
- ``device_pair``: ``(a, b)`` for each pair of distinct test devices, ``a`` before ``b``
  in the list (each pair once: the comparisons are symmetric); skipped, saying so, when
  there is only one test device. A device is never compared with itself.
- ``one_device``: one test device, for tests whose subject is not the device (input
  checks, properties of an algorithm): the first CUDA device, else the first OpenCL one
  (the fastest kinds), else the first.
- ``warp_cpu``: ``"cpu"`` for a test that needs Warp's CPU backend itself; skipped when
  ``"cpu"`` is not a test device.
"""

from __future__ import annotations

import itertools
import os

import geosynth  # first: it keeps NumPy off its AVX-512 code, as for a user (core.config)

import numpy as np  # noqa: E402
import pytest  # noqa: E402


def _test_devices() -> list[str]:
    wanted = os.environ.get("GEOSYNTH_TEST_DEVICES", "").strip()
    present = geosynth.devices()
    if not wanted:
        return present
    chosen = [d.strip() for d in wanted.split(",") if d.strip()]
    for d in chosen:  # an absent device asked for is an error, not a skip
        geosynth.get_backend(d)
    return chosen


TEST_DEVICES = _test_devices()
DEVICE_PAIRS = list(itertools.combinations(TEST_DEVICES, 2))
ONE_DEVICE = next((d for kind in ("cuda", "opencl") for d in TEST_DEVICES if d.startswith(kind)), TEST_DEVICES[0])


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", TEST_DEVICES)
    if "device_pair" in metafunc.fixturenames:
        if DEVICE_PAIRS:
            metafunc.parametrize("device_pair", DEVICE_PAIRS, ids=[f"{a}-vs-{b}" for a, b in DEVICE_PAIRS])
        else:
            reason = f"compares two devices; the test devices are only {TEST_DEVICES} (GEOSYNTH_TEST_DEVICES)"
            metafunc.parametrize("device_pair", [pytest.param(None, marks=pytest.mark.skip(reason=reason))],
                                 ids=["one-device"])


@pytest.fixture
def one_device() -> str:
    return ONE_DEVICE


@pytest.fixture
def warp_cpu() -> str:
    if "cpu" not in TEST_DEVICES:
        pytest.skip(f"needs Warp's cpu backend, which is not a test device ({TEST_DEVICES})")
    return "cpu"


def pytest_report_header(config):
    from geosynth.compute.backend import unusable_devices

    unusable = "".join(f"; left out, unusable: {name} ({why})" for name, why in unusable_devices().items())
    return f"geosynth test devices: {', '.join(TEST_DEVICES)}{unusable}"


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
