# RADICAL-RT developer entry points. `make demo` and `make test` work on a fresh machine:
# they create .venv, install the project, then run.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out

.PHONY: demo test venv lint bench bench-quick clean sysdeps jsdeps

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m mission.demo --out $(OUT)

# The browser test drives Debian's chromium; install it when missing (needs root, as in CI).
sysdeps:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian chromium for the dashboard browser test"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }

# Independent readers for the Foxglove tests (@mcap/core, @foxglove/ws-protocol, @foxglove/schemas,
# ajv): installed from tests/js/package-lock.json with npm (node >= 18).
JS_STAMP := tests/js/node_modules/.installed
$(JS_STAMP): tests/js/package.json tests/js/package-lock.json
	npm ci --prefix tests/js --no-audit --no-fund --ignore-scripts
	touch $(JS_STAMP)

jsdeps: $(JS_STAMP)

test: $(STAMP) sysdeps jsdeps
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check radical_rt replayer mission monitors perf studies tests
	$(BIN)/lint-imports
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/radical bench --profile full --out perf/results

# The quick profile (a few minutes; the live benches also run inside `make test`, tests/perf/test_perf_live.py).
bench-quick: $(STAMP)
	$(BIN)/radical bench --profile quick --out perf/results

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
