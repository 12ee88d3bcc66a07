# The two commands of the README:  `make demo`  and  `make test`.
# Both create the virtual environment (.venv) and build the C++ core when missing.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.requirements-installed
BUILD_TYPE ?= Release

.PHONY: demo test build clean

demo: build
	$(BIN)/stiction demo

test: build
	$(BIN)/python -m pytest -q

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
