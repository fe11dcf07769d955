# stucco: everything a fresh Debian machine with Python 3.11 needs is behind `make setup`,
# which `quick`, `test` and `bench` depend on. Every target is safe to rerun.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
KSTAMP := $(VENV)/.kernels
KERNELS := $(wildcard pipeline/track/*.py pipeline/estimators/*/kernel.py pipeline/estimators/paper/icp_kernel.py pipeline/estimators/pushtrack/slice_pusher.py pipeline/grasp_rule.py pipeline/pairwise_sum.py)
ANCHORS ?= data/anchors

.PHONY: setup syslibs verify-venv lock quick reproduce reproduce-active test bench clean

setup: syslibs verify-venv $(STAMP) $(KSTAMP)

# open3d's shared library links against libusb-1.0 (Debian package libusb-1.0-0).
syslibs:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by open3d)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi

# Reinstall only when the package metadata or the lock changes. requirements.lock pins every distribution (the
# full transitive set), so every machine runs the same numpy/scipy/Open3D/numba and computes the same numbers.
# The venv's own pip (Python 3.11 ships 23.x) installs only uv, at the version pinned here; uv then installs the
# lock's distributions exactly as pinned (--no-deps: the lock is the resolution) and the project, editable. uv
# installs the same wheels (byte-identical files) as pip, without pip 23's slow matching of every file of each
# package's index page against this interpreter's tags (docs/experiments/ci-time.md). Like pip --no-compile, uv
# writes no .pyc files: the kernels' step below writes those of the modules the project imports. uv pip check
# then proves the environment consistent (every requirement met, every wheel for this platform), as pip check
# does. `make lock` still resolves with pip.
UV := uv==0.13.8
# What a working environment imports: every direct dependency and the project (a package folder deleted by hand
# passes uv pip check, whose records stay, but not this).
IMPORTS := import numpy, scipy, sklearn, open3d, pybullet, click, pyarrow, tqdm, numba, matplotlib, pipeline, stucco_cli
# A new environment is built beside the previous one (moved to .venv.old) and replaces it only when it passes its
# checks; otherwise the previous one is put back, untouched, and setup fails.
$(STAMP): pyproject.toml requirements.lock
	@rm -rf $(VENV).old; if [ -d $(VENV) ]; then mv $(VENV) $(VENV).old; fi
	@if $(PYTHON) -m venv $(VENV) \
	    && $(BIN)/pip install -q --no-compile --no-deps $(UV) \
	    && $(BIN)/uv pip install -q --python $(BIN)/python --no-deps -r requirements.lock -e '.[dev]' \
	    && $(BIN)/uv pip check -q --python $(BIN)/python \
	    && $(BIN)/python -c "$(IMPORTS)" 2>/dev/null; then \
	  rm -rf $(VENV).old; touch $(STAMP); \
	else \
	  rm -rf $(VENV); if [ -d $(VENV).old ]; then mv $(VENV).old $(VENV); fi; \
	  echo "make setup: the new environment failed its checks; the previous one is kept as it was" >&2; exit 1; \
	fi

# An environment installed before is checked on every setup (uv pip check, then the imports, about 3 s): a damaged
# one loses its stamp and is built again.
verify-venv:
	@if [ -f $(STAMP) ] && ! { $(BIN)/uv pip check -q --python $(BIN)/python >/dev/null 2>&1 \
	    && $(BIN)/python -c "$(IMPORTS)" >/dev/null 2>&1; }; then \
	  echo "make setup: $(VENV) fails its checks (a damaged install?): building it again"; rm -f $(STAMP); \
	fi

# Compile the numba kernels once (cached on disk), again whenever their sources change, so no stage books
# compilation as its own time (never inside a timed update or estimate). Two processes side by side, so that the
# longest compilation overlaps the others: the first replays a tracker log, compiling the contact step's kernel
# (the longest), loading the tracker's other kernels, which the second has compiled by then, and then writes the
# .pyc files of every module the project imports (pipeline/bytecode.py: the install writes none, which is also why
# both write bytecode even where the environment sets PYTHONDONTWRITEBYTECODE); the second compiles the tracker's
# other kernels, then the estimators'.
$(KSTAMP): $(STAMP) $(KERNELS)
	@echo "compiling the tracker's and estimators' numba kernels once (cached on disk)"
	@export PYTHONDONTWRITEBYTECODE=; \
	  $(BIN)/python -c "from pipeline.track.stage import warm_up_kernels; warm_up_kernels(); \
	    from pipeline.bytecode import compile_imports; compile_imports()" & first=$$!; \
	  $(BIN)/python -c "from pipeline.track.stage import warm_up_kernels_but_contact; warm_up_kernels_but_contact(); \
	    from pipeline.estimators.plausible.kernel import warm_up; warm_up(); \
	    from pipeline.estimators.paper.icp_kernel import warm_up as icp; icp(); \
	    from pipeline.estimators.pushtrack.kernel import warm_up as pt; pt(); \
	    from pipeline.estimators.pushtrack.slice_pusher import warm_up as sw; sw(); \
	    from pipeline.grasp_rule import warm_up as rule; rule()"; second=$$?; \
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
# JOBS worker processes (`make quick JOBS=1` on a busy machine).
JOBS ?= 2
quick: setup
	$(BIN)/stucco --seed 0 evaluate --quick --jobs $(JOBS)

# The paper's Table II: its 4 simulated tasks and the real row's stand-in (REAL) x 20 seeds x 5 methods into
# out/reproduce (resumes if interrupted).
reproduce: setup
	$(BIN)/stucco --seed 0 evaluate --scenes FB,BC,IB,TC,REAL --seeds 0-19 --methods all --jobs 2 --out out/reproduce

# The active protocol (docs/active.md): STUCCO's Table II with probing and the planned grasp, then grasp success
# against the probe budget. One estimator: the policy's own grasp ends every run whatever the estimator, so the
# others' columns would repeat it (docs/active.md, "Scoring").
reproduce-active: setup
	$(BIN)/stucco --seed 0 evaluate --policy scripted+probe --scenes FB,BC,IB,TC --seeds 0-19 --methods stucco \
	  --estimators plausible --jobs 2 --out out/reproduce-active
	$(BIN)/stucco --seed 0 -j 2 bench probe --scenes FB,BC,IB,TC --seeds 0-19 --runs out/reproduce-active/runs \
	  --out out/bench/probe --png docs/img/probe_budget.png

# ruff lints first (pyproject.toml, [tool.ruff]; about a second). The test files run in PYTEST_WORKERS processes
# (pytest-xdist); each file stays in one process, so its module fixtures are built once. PYTEST_WORKERS=0 runs
# everything in this process.
# --basetemp: the tests' temporary files go to this checkout's .pytest-tmp (emptied when the next run starts)
# instead of a numbered folder of the machine's /tmp/pytest-of-USER, where pytest, after the last test, deletes
# the folders beyond the newest three: often a whole earlier run's files, at the end of every run.
PYTEST_WORKERS ?= 2
test: setup
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile --basetemp .pytest-tmp

# REFERENCE_PYTHON=/path/to/venv/bin/python (a venv with the authors' stucco 1.2.1 and their benchmark harness)
# reruns the authors' tracker side by side (docs/tracking.md).
bench: setup
	$(BIN)/stucco bench track --streams $(ANCHORS) --T 50,100,200,300,400 --methods stucco,birch,dbscan,kmeans,gmphd \
	  $(if $(REFERENCE_PYTHON),--reference-python $(REFERENCE_PYTHON)) --json out/bench/track.json
	$(BIN)/stucco bench sim --scene FB

clean:
	rm -rf out .pytest_cache .pytest-tmp .ruff_cache
