# The two commands of the README:  `make demo`  and  `make test`.
# Both create the virtual environment (.venv) and build the C++ core when missing.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.requirements-installed
BUILD_TYPE ?= Release

.PHONY: demo test build clean chromium docs wheel-smoke

demo: build
	$(BIN)/stiction demo

test: build chromium
	$(BIN)/python -m pytest -q

# The API reference (Sphinx; every warning is an error): build/docs/index.html
docs: build
	$(BIN)/python -m sphinx -E -W --keep-going -q -b html docs/api build/docs

# Build a wheel in isolation, install it into a fresh venv with no extras, use it from /tmp
wheel-smoke:
	PYTHON=$(PYTHON) .ci/wheel-smoke

# Headless Chromium checks the HTML recordings (tests/test_recording.py): Debian's
# chromium, installed when missing and we may (root + apt-get).
chromium:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium (apt-get)"; \
	    DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1 || \
	    { apt-get update -q >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null 2>&1; } || \
	    echo "could not install chromium: the headless recording tests will be skipped"; \
	  else echo "chromium not found and cannot be installed here: the recording test will be skipped"; fi; }

# Incremental: scikit-build-core keeps build/<wheel tag>/, so touching one .cpp
# recompiles one translation unit (ccache, when installed, caches across clones).
build: $(STAMP)
	$(BIN)/pip install --no-build-isolation --no-deps -q -e . -Ccmake.build-type=$(BUILD_TYPE)

$(STAMP): requirements.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -r requirements.txt
	touch $@

clean:
	rm -rf build $(VENV)
