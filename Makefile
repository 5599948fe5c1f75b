# The two commands of the README:  `make demo` (the main job)  and  `make test` (the test suite).
# Both create .venv with Python 3.12 on first use (LeRobot 0.6 needs Python >= 3.12).

VENV := .venv
PY := $(VENV)/bin/python
# First Python 3.12 that actually runs (a pyenv shim may exist without the version selected).
PYTHON312 ?= $(shell for c in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 \
	/usr/bin/python3.12; do $$c -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null \
	&& { echo $$c; break; }; done)

ROBOSUITE := robosuite==1.5.2
# robosuite pins mink==0.0.5 and with it numpy<2, which LeRobot cannot share; robosuite imports mink only inside
# a `try`, so it is installed without its pins, its other dependencies coming from our `robosuite` extra.

.PHONY: demo test lint bench bench-envs robosuite clean

$(VENV)/.installed: pyproject.toml
	@test -n "$(PYTHON312)" || { echo "Python 3.12 not found: install it or run 'make PYTHON312=/path/to/python3.12'"; exit 1; }
	test -x $(PY) || $(PYTHON312) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,robosuite,ray]"
	$(PY) -m pip install --quiet --no-deps "$(ROBOSUITE)"
	touch $@

robosuite: $(VENV)/.installed

demo: $(VENV)/.installed
	$(PY) -m lerobot_actionflow.tools.demo

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .

test: lint
	$(PY) -m pytest -q

bench: $(VENV)/.installed
	$(PY) -m eval.bench.latency

bench-envs: $(VENV)/.installed
	$(PY) -m eval.bench.envs

clean:
	rm -rf $(VENV) outputs
