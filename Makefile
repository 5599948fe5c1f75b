# The two commands of the README:  `make demo` (the main job)  and  `make test` (the test suite).
# Both create .venv with Python 3.12 on first use (LeRobot 0.6 needs Python >= 3.12).

VENV := .venv
PY := $(VENV)/bin/python
# First Python 3.12 that actually runs (a pyenv shim may exist without the version selected).
PYTHON312 ?= $(shell for c in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 \
	/usr/bin/python3.12; do $$c -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null \
	&& { echo $$c; break; }; done)

.PHONY: demo test lint bench bench-envs clean

$(VENV)/.installed: pyproject.toml
	@test -n "$(PYTHON312)" || { echo "Python 3.12 not found: install it or run 'make PYTHON312=/path/to/python3.12'"; exit 1; }
	test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test]"
	touch $@

demo: $(VENV)/.installed
	$(PY) -m lerobot_actionflow.tools.demo

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .

test: lint
	$(PY) -m pytest -q

bench: $(VENV)/.installed
	$(PY) eval/bench_latency.py

bench-envs: $(VENV)/.installed
	$(PY) eval/bench_envs.py

clean:
	rm -rf $(VENV) outputs
