# bifid — make demo | make test | make bench | make docs | make lint
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export JAX_PLATFORMS ?= cpu
export JAX_ENABLE_X64 := 1

.PHONY: install demo demo-forced check-report test test-slow bench docs lint clean

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/bifid demo flutter --out out --resume

demo-forced: $(STAMP)
	$(BIN)/bifid demo forced --out out-forced --resume

# render the demo report in headless Chromium (Debian package `chromium`) and check that
# every figure shows; installs chromium with apt when it is missing and we may
check-report: $(STAMP)
	command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && apt-get install -y -qq chromium; } || true
	$(BIN)/python scripts/check_report.py out/report.html --screenshot out/report_screenshot.png

test: $(STAMP)
	$(BIN)/python -m pytest -q tests

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q tests --runslow

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[bench]"
	$(BIN)/python benchmarks/run_all.py

docs: $(STAMP)
	$(BIN)/mkdocs build --strict --site-dir site

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks docs/examples
	$(BIN)/ruff format --check src tests benchmarks docs/examples

clean:
	rm -rf out site .pytest_cache
