# talkingface: `make replicate`, `make server` and `make test` do all set-up themselves
# (tools/setup.sh: base mode; `server` adds PostgreSQL, `test` adds it and a headless browser).
VENV ?= .venv
PY := $(VENV)/bin/python
NAME ?= paper
JOBS ?= 2

.PHONY: setup replicate test durations bench lock ui server clean

setup:
	@VENV=$(VENV) bash tools/setup.sh

replicate: setup
	$(PY) -m talkingface replicate --name $(NAME) --config configs/paper.yaml $(ARGS)

# pytest exits 5 when it collected no test: that is a failure here, with a message. The run ends
# with its 15 slowest tests (setup, call or teardown), so a change sees what it costs; the order
# and the spread over the workers come from tests/durations.json (tests/scheduling.py).
PYTEST_TIMES := --durations=15 --durations-min=1
test:
	@VENV=$(VENV) bash tools/setup.sh test
	@$(PY) -m pytest -n $(JOBS) -q $(PYTEST_TIMES) $(ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests" >&2; exit 1; fi; exit $$rc

# Measure every test again and keep the figures that order the suite (tests/durations.json).
durations:
	@VENV=$(VENV) bash tools/setup.sh test
	$(PY) -m pytest -n $(JOBS) -q $(PYTEST_TIMES) --save-durations tests/durations.json $(ARGS)

bench: setup
	$(PY) bench/bench_corpus.py
	$(PY) bench/bench_units.py
	$(PY) bench/bench_mapping.py
	$(PY) bench/bench_streaming.py
	$(PY) bench/bench_tracker.py
	$(PY) bench/bench_import.py
	$(PY) bench/bench_grid.py
	$(PY) bench/bench_profile.py
	$(PY) bench/bench_hearing.py
	$(PY) bench/bench_web_load.py

ui: setup
	$(PY) -m talkingface ui

# The lab's tracking server (PostgreSQL + MLflow, data in ./mlflow-server); ARGS="--host ..." etc.
server:
	@VENV=$(VENV) bash tools/setup.sh server
	$(PY) -m talkingface server $(ARGS)

# Refresh the pinned lock file from requirements/base.in (maintainers only).
lock:
	rm -rf /tmp/talkingface-lock && python3 -m venv /tmp/talkingface-lock
	/tmp/talkingface-lock/bin/pip install -q -c requirements/constraints.txt -r requirements/base.in
	/tmp/talkingface-lock/bin/pip freeze | sed 's/^torch==\(.*\)+cpu/torch==\1/' > requirements/lock.txt

clean:
	rm -rf runs cache reports/*.pdf mlartifacts mlflow.db .pytest_cache
