# gyrocal — the two commands a newcomer needs: `make run` and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip

.PHONY: run test install install-test system-deps bench lint clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -e '.[server,ble]'
	touch $@

# the test extras in one pass (one resolution, not two): a fresh clone's `make test` installs the run extras with them.
# --no-compile: pip would compile every module of every package to bytecode (half of the install's time); the tests
# compile the ones they import, once, as they first import them
$(VENV)/.installed-test: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --no-compile -e '.[server,ble,test]'
	touch $(VENV)/.installed $@

install: $(VENV)/.installed

## run: start gyrocal with simulated wearables and an embedded store
run: $(VENV)/.installed
	$(VENV)/bin/gyrocal serve --mock 2 --mock-scenario hand:careful,hand:bumps --demo-operator demo

## system-deps: Debian packages the tests drive for real (D-Bus daemon, Chromium, PostgreSQL)
system-deps:
	bash scripts/install-system-deps.sh

## lint: what review misses: ruff (errors, import order, bugbear, pyupgrade, line length), mypy on the numerics
## and the service, and the structure (no import cycles, the layering rules, module sizes)
lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check calib server mock_device wearable_protocol webui tests bench scripts
	$(VENV)/bin/mypy calib server wearable_protocol
	$(PY) scripts/check_structure.py
	$(PY) scripts/effects_tables.py --check

## test: install everything the tests need, then run them all (TEST_WORKERS parallel workers: three on two cores, as
## the tests wait on simulated hands at real speed, browsers and timeouts a third of their time: 540-622 s in three
## full runs against 724-783 s with two; the tests that follow a hand at real speed or time a wearable by when its
## packets arrive, once starved by a third worker, now pass with two busy loops beside them), with the lint checks
## beside them (a single core for under 20 s, while the first tests are numerics); either failing fails the target
TEST_WORKERS ?= 3
# the tests start some 400 Python processes (services, their compute workers, commands): each reads gyrocal's compiled
# modules from __pycache__ instead of compiling them again, even where the environment asks Python to write no bytecode
test: export PYTHONDONTWRITEBYTECODE =
test: $(VENV)/.installed-test system-deps
	@$(MAKE) --no-print-directory lint > .lint.log 2>&1 & lint=$$!; \
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist worksteal; tests=$$?; \
	wait $$lint; linted=$$?; cat .lint.log; rm -f .lint.log; \
	if [ $$linted -ne 0 ]; then echo "make test: the lint checks failed (above)" >&2; fi; \
	[ $$tests -eq 0 ] && [ $$linted -eq 0 ]

bench: $(VENV)/.installed
	$(VENV)/bin/gyrocal bench paper-sim

clean:
	rm -rf $(VENV) .pytest_cache artifacts
