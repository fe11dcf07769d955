# stucco: everything a fresh Debian machine with Python 3.11 needs is behind `make setup`,
# which `quick`, `test` and `bench` depend on. Every target is safe to rerun.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
ANCHORS ?= data/anchors

.PHONY: setup syslibs quick test bench clean

setup: syslibs $(STAMP)

# open3d's shared library links against libusb-1.0 (Debian package libusb-1.0-0).
syslibs:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi

# Reinstall only when the package metadata changes.
$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	@touch $(STAMP)

# Until `stucco evaluate` exists: track and segment a stored contact log (FB seed 0, simulated and isolated).
quick: setup
	$(BIN)/stucco --seed 0 track --in data/contacts/FB-000.parquet --out out/quick/tracks.parquet
	$(BIN)/stucco segment --in out/quick/tracks.parquet --out out/quick/segments.parquet --plot out/quick/segments.png --print

test: setup
	$(BIN)/python -m pytest -q

# REFERENCE_PYTHON=/path/to/venv/bin/python reruns the authors' tracker side by side (../shared/anchors/README.md).
bench: setup
	$(BIN)/stucco bench track --streams $(ANCHORS) --methods stucco,birch,dbscan,kmeans,gmphd \
	  $(if $(REFERENCE_PYTHON),--reference-python $(REFERENCE_PYTHON)) --json out/bench/track.json
	$(BIN)/stucco bench sim --scene FB

clean:
	rm -rf out .pytest_cache
