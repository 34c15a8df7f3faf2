# The two commands: `make up` (set up, start the default system) and `make test`.
# Only python3 (>= 3.11) and make are needed; everything else goes into .venv.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
# The install is a strict editable one (a tree of links that editors, mypy and pyright
# follow): it sees edits to existing files at once, and a new module after a re-install,
# which the stamp triggers, as it hashes the list of package files with pyproject.toml.
PACKAGES := schema robots services launcher kinematics client
STAMP  := $(VENV)/.installed-$(shell (cat pyproject.toml; find $(PACKAGES) -type f -not -path '*/__pycache__/*' 2>/dev/null | LC_ALL=C sort) | cksum | cut -d' ' -f1)
ARGS   ?=
PYTEST_ARGS ?=
# The test files on three pytest-xdist workers, each file whole on one, the longest first (README, "make test"):
# on 2 cores, live tests wait on real motions and clocks a third of the time, and a third worker fills that
# (quiet: 341.5 s against 401.0 s on two, same checkout, back to back); TEST_WORKERS=0: one process.
TEST_WORKERS ?= 3

.PHONY: setup up test typecheck bench soak schema browser clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# setuptools' notice that a strict editable install keeps build/__editable__* is silenced: that is the point of it.
	PYTHONWARNINGS=ignore::Warning:setuptools.command.editable_wheel \
		$(BIN)/python -m pip install --quiet --config-settings editable_mode=strict -e '.[test]'
	# Byte-compiled once, as pip does for every other package: each service process, CLI tool and test
	# worker imports the project's 50,000 lines, and where PYTHONDONTWRITEBYTECODE is set (this VM) each
	# compiled them again at every start.
	$(BIN)/python -m compileall -q build
	rm -f $(VENV)/.installed-*
	touch $@

setup: $(STAMP)

up: setup
	$(BIN)/jara-arm up --demo $(ARGS)

test: setup typecheck
	$(BIN)/python -m pytest $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile) $(PYTEST_ARGS)

# Strict on the wire contract and the service framework (pyproject.toml [tool.mypy]).
typecheck: setup
	$(BIN)/python -m mypy

bench: setup
	$(BIN)/python bench/servo_loop.py
	$(BIN)/python bench/query_rtt.py
	$(BIN)/python bench/alarm_latency.py --repeat 3
	$(BIN)/python bench/motion.py
	$(BIN)/python bench/ik.py
	$(BIN)/python bench/load.py --seconds 30
	$(BIN)/python bench/soak.py --arms 4 --minutes 2
	$(BIN)/python bench/starts.py --runs 5

# The proof of the "Fast and right" and "No client can hurt the cell" figures: every soak 10 minutes,
# quiet, with a CPU hog on every core, and with the hogs and both bad clients (slow, frozen).
soak: setup
	for n in 1 2 4; do $(BIN)/python bench/soak.py --arms $$n --minutes 10 || exit 1; \
	  $(BIN)/python bench/soak.py --arms $$n --minutes 10 --hog || exit 1; \
	  $(BIN)/python bench/soak.py --arms $$n --minutes 10 --hog --slow-client --frozen-client || exit 1; done

# Chromium for the browser tests of `jara-arm view` (tests/test_view.py), from the system's packages
# (Debian, as root); where it cannot be installed those tests are skipped, saying so. CI runs it (.ci/run).
browser:
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
	  echo "make browser: Chromium not installed (needs root and apt-get): the browser tests will be skipped"

schema: setup
	$(BIN)/python -m jara_arm.schema.generate

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
