# The two set-up commands of the README, plus the benchmarks. Each creates .venv and
# installs geosynth into it (editable) when needed, so a fresh clone needs nothing else.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BENCH_STAMP := $(VENV)/.installed-bench
PIP := $(BIN)/python -m pip --disable-pip-version-check --quiet

.PHONY: demo test test-cpus bench gpu-check clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(PIP) install -e '.[test]'
	$(BIN)/python tools/ensure_opencl.py
	touch $@

$(BENCH_STAMP): pyproject.toml bench/install_peers.sh $(STAMP)
	$(PIP) install -e '.[test,bench]'
	bash bench/install_peers.sh $(VENV)
	touch $@

demo: $(STAMP)
	$(BIN)/geosynth devices
	$(BIN)/geosynth volume --example terrain -o demo_out/terrain.ply --png demo_out/terrain.png

# the viewer's browser tests need a headless Chromium: found, installed by apt-get when
# running as root (CI), or skipped with their reason (tools/ensure_chromium.py never fails)
test: $(STAMP)
	-$(BIN)/python tools/ensure_chromium.py
	$(BIN)/python -m pytest -q

# test-cpus: the tests of outputs that must not depend on the CPU (pinned hashes of M1, M2,
# M3; M2's and M4's tests) three times, with NumPy and OpenBLAS acting as this CPU, an AVX2
# and an SSE4 machine (tools/cpu_matrix.sh); CPU_TESTS= (empty) runs the whole suite so.
CPU_TESTS ?= tests/test_unchanged.py tests/test_point_texture.py tests/test_completion.py tests/test_warping.py
test-cpus: $(STAMP)
	bash tools/cpu_matrix.sh $(BIN)/python -m pytest -q $(CPU_TESTS)

bench: $(BENCH_STAMP)
	$(BIN)/python bench/bm_main.py

# gpu-check: on a machine with an NVIDIA GPU, the suite on cuda (with cpu) and every
# benchmark's --quick mode, in at most 8 minutes; summary in bench/out/gpu-check.md.
# It installs nothing and deliberately does not depend on $(STAMP): the GPU machine has no
# network, and the stamp rule reinstalls whenever pyproject.toml looks newer than the stamp,
# which a copied checkout's timestamps can make it. It needs only a Python that imports this
# checkout's geosynth: $(BIN)/python (from `make test`), or GPU_PYTHON=... on the command line.
GPU_PYTHON ?= $(BIN)/python
gpu-check:
	@test -x $(GPU_PYTHON) || { echo "gpu-check: $(GPU_PYTHON) is missing: run make test first (it builds $(VENV)), or give GPU_PYTHON=..."; exit 2; }
	@timeout -k 10 480 $(GPU_PYTHON) tools/gpu_check.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis demo_out
