# Two commands from a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The six distributions of this repository (docs/architecture.md): the core, the platform
# descriptions and one per role.
PARTS  := . platforms robots services clients deploy
# Everything editable, with the extras the tests and `kinesphere up` use (docs/deployment.md).
EDITABLE := -e '.[test,ros2]' -e platforms -e robots -e services -e clients -e 'deploy[up]'
SRC    := kinesphere platforms robots services clients deploy tests bench
export MUJOCO_GL ?= egl
export SDL_VIDEODRIVER ?= dummy
export SDL_AUDIODRIVER ?= dummy
# Bytecode is cached in __pycache__ (git ignores it; hatchling leaves it out of the wheels):
# without it every process the tests start compiles the tree again (~0.2 CPU-s for an agent's
# imports, measured 0.74 -> 0.56 CPU-s), and, as the install compiles nothing ahead, the
# libraries it imports too. A PYTHONDONTWRITEBYTECODE in the environment (this machine's has
# one) would forbid the cache, so make does not pass it on.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: install demo test lint typecheck layers browser xserver bench soak sweep lock clean

# The build backend goes in once and builds all six (pip would make a throwaway environment
# for each); nothing is compiled ahead: an import compiles the modules it uses into
# __pycache__, where pip would compile every installed file. A fresh clone's install took
# 70 s, now 36 s.
BUILD  := hatchling editables
PIP    := $(BIN)/python -m pip install --quiet --no-compile -c constraints.txt

$(STAMP): $(addsuffix /pyproject.toml,$(PARTS)) constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(PIP) $(BUILD)
	$(PIP) --no-build-isolation $(EDITABLE)
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/kinesphere up --headless

# The tests run on every core (pytest-xdist, a file's tests on one worker, so its fixtures are
# made once); those marked `realtime` (they judge robots against the clock, and a neighbour
# taking the other core makes them late) then run on two workers, file by file: the score played
# on eight robots at a tenth of its speed (a minute, the cores ~90 % idle; marked
# `realtime(longest=True)`, so tests/conftest.py hands its file out first) beside the other 15,
# which run one after another as before. One after another the 16 took 2 min, now 67-73 s in
# fresh clones' runs; the score's tally (cells as written, late keyframes) is the same as alone
# (6 December 2026). Each run ends with its ten slowest tests.
# WORKERS: one per core and one more. With one per core the cores stayed about a third idle
# (tests waiting on the processes they start and on robots moving in real time); on this 2-core
# machine a fresh clone's non-realtime part took 6 min 49 s with two workers, 4 min 43 s with
# three (6 December 2026, idle), and 4 min 54 s with four against 4 min 58 s with three in the
# same sitting (the cores are busy now). Earlier, a third worker under a neighbour's load (load
# average 8) made agents fall ~0.9 s behind real time; what judges that is marked `realtime` and
# runs apart. `make test WORKERS=2` on a shared machine.
PYTEST := $(BIN)/python -m pytest -q --durations=10
WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
test: lint typecheck layers browser xserver
	$(PYTEST) -m "not realtime" -n $(WORKERS) --dist loadfile
	$(PYTEST) -m realtime -n 2 --dist loadfile --no-loadscope-reorder

# Debian programs some tests drive: installed when missing and make runs as root, otherwise
# make stops with the install command. $(1): the command, $(2): the package, $(3): who needs it.
define debian_tool
	@if ! command -v $(1) >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = 0 ]; then echo "installing Debian's $(2) for $(3)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(2) >/dev/null; \
	  else echo "make test needs Debian's $(2) for $(3); install it with:" >&2; \
	    echo "  sudo sh -c 'apt-get update && apt-get install -y $(2)'" >&2; exit 1; fi; \
	fi
endef

# The view's test drives Debian's Chromium (Playwright's own browser download is not used).
browser:
	$(call debian_tool,chromium,chromium,the view test)

# The HUD's tests draw on a virtual X server and take screenshots from it.
xserver:
	$(call debian_tool,Xvfb,xvfb,the HUD screenshots)

lint: $(STAMP)
	$(BIN)/ruff check $(SRC)

# Strict mypy over every distribution's package, the tests and the benchmarks: the tests import
# their shared code as `support.*` (pytest's pythonpath), so mypy_path names tests/ too.
typecheck: $(STAMP)
	$(BIN)/mypy kinesphere $(addsuffix /kinesphere,$(filter-out .,$(PARTS))) tests bench

layers: $(STAMP)
	$(BIN)/lint-imports

bench: $(STAMP)
	$(BIN)/python -m bench

# The fuzz and flood tests at full size: KINESPHERE_SOAK_SCALE times what `make test` sends,
# each printing one "SOAK ..." line (sent, named errors, RSS before/after, motion after stop).
SOAK_SCALE ?= 20
SOAK_TESTS := $(wildcard tests/*/test_*_fuzz.py tests/*/test_*_flood.py tests/system/test_system_soak.py)
soak: $(STAMP)
	KINESPHERE_SOAK_SCALE=$(SOAK_SCALE) $(BIN)/python -m pytest -q -s $(SOAK_TESTS)

# Bring every URDF of the three public collections the tests install (example-robot-data,
# pybullet_data, rtb-data): platform new, describe, and ecl build of the first limb of each
# chain, once per robot; prints the coverage table of docs/byor.md (tens of minutes on two
# cores; make test imports every file and builds a sample of four). SWEEP_ARGS="--only talos".
sweep: $(STAMP)
	PYTHONPATH=tests $(BIN)/python -m support.sweep $(SWEEP_ARGS)

# Re-pin what CI tests with: resolve the newest allowed versions in a scratch venv, freeze them.
lock:
	rm -rf .venv-lock && $(PYTHON) -m venv .venv-lock
	.venv-lock/bin/python -m pip install --quiet --upgrade pip
	.venv-lock/bin/python -m pip install --quiet $(BUILD) $(EDITABLE)
	.venv-lock/bin/python -m pip freeze --exclude-editable | grep -v '^kinesphere' > constraints.txt
	rm -rf .venv-lock

clean:
	rm -rf $(VENV) build .pytest_cache .mypy_cache .ruff_cache
