"""Per-device test generation: every test that takes ``device`` runs on each present
device (Warp ``cpu``, every OpenCL device, every ``cuda:N``), narrowed by the
environment variable GEOSYNTH_TEST_DEVICES (comma-separated device strings)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import geosynth


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


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", TEST_DEVICES)


def pytest_report_header(config):
    from geosynth.backend import unusable_devices

    unusable = "".join(f"; left out, unusable: {name} ({why})" for name, why in unusable_devices().items())
    return f"geosynth test devices: {', '.join(TEST_DEVICES)}{unusable}"


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
