# stucco: everything a fresh Debian machine with Python 3.11 needs is behind `make setup`,
# which `quick`, `test` and `bench` depend on. Every target is safe to rerun.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
KSTAMP := $(VENV)/.kernels
KERNELS := $(wildcard pipeline/track/*.py pipeline/retrieve/*_kernel.py pipeline/pairwise_sum.py)
ANCHORS ?= data/anchors

.PHONY: setup syslibs lock quick reproduce reproduce-active test bench clean

setup: syslibs $(STAMP) $(KSTAMP)

# open3d's shared library links against libusb-1.0 (Debian package libusb-1.0-0).
syslibs:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi

# Reinstall only when the package metadata or the lock changes. requirements.lock pins every distribution (the
# full transitive set), so every machine runs the same numpy/scipy/Open3D/numba and computes the same numbers.
# --no-compile: Python byte-compiles a module when it is first imported instead of pip compiling every module of
# every distribution (about 50 s of a fresh set-up on 2 cores; docs/evaluation.md, "Where CI's time goes").
# The venv's own pip (Python 3.11 ships 23.x, which installs a pyproject.toml project editable) is used as it is:
# upgrading it first cost 8 s and made the installer depend on the day of the set-up.
# The lock's distributions are installed exactly as pinned (--no-deps: the lock is the resolution) by two pips side
# by side, alternate lines each (about 240 MB of wheels apiece, each pip fetching and unpacking one at a time),
# with a third installing the project itself (its build backend in an isolated environment, about 8 s); pip check
# then proves the three made one consistent environment (docs/evaluation.md, "Where CI's time goes").
$(STAMP): pyproject.toml requirements.lock
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@grep -v '^#' requirements.lock | awk 'NR % 2 == 1' > $(VENV)/lock-odd.txt
	@grep -v '^#' requirements.lock | awk 'NR % 2 == 0' > $(VENV)/lock-even.txt
	$(BIN)/pip install -q --no-compile --no-deps -r $(VENV)/lock-odd.txt & odd=$$!; \
	  $(BIN)/pip install -q --no-compile --no-deps -e '.[dev]' & project=$$!; \
	  $(BIN)/pip install -q --no-compile --no-deps -r $(VENV)/lock-even.txt; even=$$?; \
	  wait $$odd && wait $$project && test $$even = 0
	$(BIN)/pip check
	@touch $(STAMP)

# Compile the numba kernels once (cached on disk), again whenever their sources change, so no stage books
# compilation as its own time (never inside a timed update or estimate). Two processes side by side (a 2-core EPYC:
# about 33 s, against 41 s for the tracker's alone before): the first replays a tracker log, compiling the contact
# step's kernel (about 26 s, the longest), loading the tracker's other kernels, which the second has compiled by
# then, and then writes the .pyc files of every module the project imports (pipeline/bytecode.py: pip installs with
# --no-compile, which is also why both write bytecode even where the environment sets PYTHONDONTWRITEBYTECODE); the
# second compiles the tracker's other kernels, then the estimators'.
$(KSTAMP): $(STAMP) $(KERNELS)
	@echo "compiling the tracker's and estimators' numba kernels once (cached on disk)"
	@export PYTHONDONTWRITEBYTECODE=; \
	  $(BIN)/python -c "from pipeline.track.stage import warm_up_kernels; warm_up_kernels(); \
	    from pipeline.bytecode import compile_imports; compile_imports()" & first=$$!; \
	  $(BIN)/python -c "from pipeline.track.stage import warm_up_kernels_but_contact; warm_up_kernels_but_contact(); \
	    from pipeline.retrieve.plausible_kernel import warm_up; warm_up(); \
	    from pipeline.retrieve.icp_kernel import warm_up as icp; icp(); \
	    from pipeline.retrieve.pushtrack_kernel import warm_up as pt; pt()"; second=$$?; \
	  wait $$first && test $$second = 0
	@touch $(KSTAMP)

# Refresh the lock: resolve pyproject.toml's ranges afresh in a throw-away venv and pin what was installed.
lock:
	rm -rf .lock-venv && $(PYTHON) -m venv .lock-venv
	.lock-venv/bin/pip install -q --upgrade pip && .lock-venv/bin/pip install -q -e '.[dev]'
	{ sed -n '1,3p' requirements.lock; .lock-venv/bin/pip freeze --exclude-editable; } > requirements.lock.new
	mv requirements.lock.new requirements.lock && rm -rf .lock-venv
	@echo "requirements.lock refreshed; 'make setup' installs it (review the diff, rerun make test)"

# FB seeds 0-1, every method, end to end: prints Table II, writes out/quick/report.md, figures/, summary.png.
quick: setup
	$(BIN)/stucco --seed 0 evaluate --quick --jobs 2

# The paper's Table II: 4 tasks x 20 seeds x 5 methods into out/reproduce (resumes if interrupted).
reproduce: setup
	$(BIN)/stucco --seed 0 evaluate --scenes FB,BC,IB,TC --seeds 0-19 --methods all --jobs 2 --out out/reproduce

# The active protocol (docs/retrieval.md, "Active retrieval"): STUCCO's Table II with probing and the set grasp, then
# grasp success against the probe budget.
reproduce-active: setup
	$(BIN)/stucco --seed 0 evaluate --policy scripted+probe --scenes FB,BC,IB,TC --seeds 0-19 --methods stucco \
	  --jobs 2 --out out/reproduce-active
	$(BIN)/stucco --seed 0 -j 2 bench probe --scenes FB,BC,IB,TC --seeds 0-19 --runs out/reproduce-active/runs \
	  --out out/bench/probe --png docs/img/probe_budget.png

# The test files run in PYTEST_WORKERS processes (pytest-xdist); each file stays in one process, so its module
# fixtures are built once. PYTEST_WORKERS=0 runs everything in this process.
PYTEST_WORKERS ?= 2
test: setup
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile

# REFERENCE_PYTHON=/path/to/venv/bin/python reruns the authors' tracker side by side (../shared/anchors/README.md).
bench: setup
	$(BIN)/stucco bench track --streams $(ANCHORS) --T 50,100,200,300,400 --methods stucco,birch,dbscan,kmeans,gmphd \
	  $(if $(REFERENCE_PYTHON),--reference-python $(REFERENCE_PYTHON)) --json out/bench/track.json
	$(BIN)/stucco bench sim --scene FB

clean:
	rm -rf out .pytest_cache
