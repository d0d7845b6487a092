# The two commands: `make run` and `make test`. Both bootstrap .venv from nothing.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run test test-serial test-unit test-integration test-docker test-zenohd lint bench clean bytecode

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip "setuptools>=77" wheel
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

# The main job: the paper scenario (leader climbing 1 m/s) as a multi-process swarm.
run: $(STAMP) bytecode
	$(VENV)/bin/fxswarm run configs/paper-fast.toml --clock lockstep --out runs/paper-fast

# Layers (pyproject.toml [tool.importlinter]) are checked on the installed layout, where
# agents/ is fxswarm/agents: import-linter reads folders, not setuptools' package-dir.
lint: $(STAMP)
	rm -rf build/lint
	$(PY) -m pip install --quiet --no-deps --no-build-isolation --target build/lint .
	cd build/lint && ../../$(VENV)/bin/lint-imports ../../pyproject.toml

# Every layer, slow ones too, in one pytest run on WORKERS workers (tests/conftest.py hands the
# tests out: the docker layer on one worker, its compose projects and stacks one at a time; every
# other module with its fixtures on one; the longest first). Run one layer after the other, the
# swarms mostly wait and the two cores idle half the time: docs/testing.md, "Where the time goes".
# PYTEST_ARGS: more pytest options (.ci/run: --durations=10).
PYTEST_ARGS ?=
WORKERS ?= 3
test: lint bytecode
	$(PY) -m pytest tests/unit tests/integration tests/docker -n $(WORKERS) --dist loadscope --no-loadscope-reorder \
		$(PYTEST_ARGS)

# The same tests one layer after the other: tests/unit on two workers, then tests/integration and
# tests/docker in one process, no two swarms at once (slower: 16-19 minutes here).
test-serial: lint bytecode
	status=0; $(PY) -m pytest tests/unit -n 2 $(PYTEST_ARGS) || status=$$?; \
	$(PY) -m pytest tests/integration tests/docker $(PYTEST_ARGS) || status=$$?; exit $$status

# The quick layer: pure tests on two workers, without the ones marked slow (minutes of simulation, deep fuzzing).
test-unit: $(STAMP) bytecode
	$(PY) -m pytest tests/unit -m "not slow" -n 2

test-integration: $(STAMP) bytecode
	$(PY) -m pytest tests/integration

test-docker: $(STAMP) bytecode
	$(PY) -m pytest tests/docker

# The editable install's byte code, written once: with PYTHONDONTWRITEBYTECODE set (as on our CI
# machine) nothing else writes it, and every process (the suite starts hundreds of robots, worlds
# and routers) compiled the package from source again: paper-fast's nine processes took 3.5 s of
# CPU to start and stop a swarm, 2.9 s with the byte code.
bytecode: $(STAMP)
	$(PY) -m compileall -q fxswarm agents leader world logger

# The router tests with the official Zenoh router (docs/routers.md): zenohd 1.10.2, the version
# of eclipse-zenoh we pin, built --locked (a build with newer dependencies aborted under TLS
# load) into build/zenohd. Not part of `make test`: the build takes ~20 min on 2 cores.
ZENOHD_VERSION := 1.10.2
ZENOHD := build/zenohd/bin/zenohd

$(ZENOHD):
	cargo install zenohd --version $(ZENOHD_VERSION) --locked --root build/zenohd

test-zenohd: $(STAMP) $(ZENOHD)
	FXSWARM_ZENOHD=$(abspath $(ZENOHD)) $(PY) -m pytest tests/integration/test_router_restart.py

# The maintained benchmarks at their quick settings, in a few minutes; each writes its own
# benchmarks/results/<name>.json (benchmarks/README.md: each one's full command and what it
# measures; the ones that need Docker, perf or tens of minutes are run by hand).
bench: $(STAMP)
	$(PY) benchmarks/bench_sim.py --repeats 1
	$(PY) benchmarks/bench_hotloop.py --repeat 2
	$(PY) benchmarks/bench_runtime.py --quick
	$(PY) benchmarks/bench_shutdown.py --rounds 1
	$(PY) benchmarks/bench_liveliness.py --rounds 1 --lease-ms 2000
	$(PY) benchmarks/bench_campaign.py --repeats 1 --duration 5 --seeds 2
	$(PY) benchmarks/bench_floor.py --repeat 1 --ticks 1000
	$(PY) benchmarks/bench_topology.py --sizes 6,8 --rounds 1 --ticks 800
	$(PY) benchmarks/bench_logger.py --repeats 1 --duration 5

clean:
	rm -rf $(VENV) runs build dist .pytest_cache
