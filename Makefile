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

quick: setup
	$(BIN)/stucco --seed 0 track --in data/contacts/anchor_T100.parquet --out out/quick/tracks.parquet --robot disc:0.05
	$(BIN)/stucco segment --in out/quick/tracks.parquet --out out/quick/segments.parquet --plot out/quick/segments.png --print

test: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/stucco bench track --streams $(ANCHORS)

clean:
	rm -rf out .pytest_cache
