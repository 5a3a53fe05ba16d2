# The two set-up commands of the README, plus the benchmarks. Each creates .venv and
# installs geosynth into it (editable) when needed, so a fresh clone needs nothing else.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BENCH_STAMP := $(VENV)/.installed-bench
PIP := $(BIN)/python -m pip --disable-pip-version-check --quiet

.PHONY: demo test bench clean

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

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(BENCH_STAMP)
	$(BIN)/python bench/bm_main.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis demo_out
