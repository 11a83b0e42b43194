# Thin driver over CMake for the README's two commands.
#   make demo   install what is missing, build, render the USD sand castle to out/
#   make test   install what is missing, build, run every test suite (ctest, then pytest)
BUILD ?= build
VENV ?= .venv
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
CMAKE_ARGS ?=
PY := $(VENV)/bin/python
# The Hydra delegate builds (and its tests run) when an OpenUSD install with imaging is
# found: PXR_DIR, else /opt/openusd. pxrConfig.cmake wants the exact Python OpenUSD was
# built with (PXR_PYTHON, Debian's by default), which another Python on PATH would shadow.
PXR_DIR ?= $(if $(wildcard /opt/openusd/pxrConfig.cmake),/opt/openusd,)
PXR_PYTHON ?= /usr/bin/python3
PXR_ARGS := $(if $(PXR_DIR),-Dpxr_DIR=$(PXR_DIR) -DPython3_EXECUTABLE=$(PXR_PYTHON) \
  -DPython3_INCLUDE_DIR=$(shell $(PXR_PYTHON) -c 'import sysconfig; print(sysconfig.get_paths()["include"])' 2>/dev/null) \
  -DPython3_LIBRARY=$(shell $(PXR_PYTHON) -c 'import sysconfig as s; print(s.get_config_var("LIBDIR") + "/" + s.get_config_var("LDLIBRARY"))' 2>/dev/null),)

.PHONY: demo demo-json test deps venv build schemas bench clean

deps:
	@scripts/install-deps.sh

# Python virtual environment (usd-core, numpy, pytest, pybind11 from PyPI; only what is
# missing), wired to python/ and to the module built in $(BUILD)/python.
venv: deps
	@scripts/setup-venv.sh $(VENV) $(BUILD)

build: venv
	@cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release -DGRANULAR_PYTHON=$(abspath $(PY)) $(PXR_ARGS) $(CMAKE_ARGS) > $(BUILD).configure.log 2>&1 || { cat $(BUILD).configure.log; exit 1; }
	@grep -E "hdGranular|granular Python" $(BUILD).configure.log || true
	@cmake --build $(BUILD) -j $(JOBS)

demo: build
	@mkdir -p out
	$(VENV)/bin/granular render examples/sandcastle.usda -o out/demo.exr --png out/demo.png

# The JSON front end of the C++ command line, for comparison.
demo-json: build
	@mkdir -p out
	$(BUILD)/core/granular-render examples/demo.json -o out/demo-json.exr --png out/demo-json.png

# ctest, then pytest; pytest's "no tests collected" (exit 5) is an error here, not a pass.
test: build
	@cd $(BUILD) && ctest --output-on-failure --no-tests=error -j $(JOBS)
	@GRANULAR_BUILD_DIR=$(abspath $(BUILD)) $(PY) -m pytest -q -p no:cacheprovider tests/python; rc=$$?; \
	  if [ $$rc -eq 5 ]; then echo "pytest: no tests were collected" >&2; fi; exit $$rc

# Regenerates schemas/generatedSchema.usda and plugInfo.json from schemas/schema.usda.
schemas: venv
	@scripts/gen-schema.sh $(PY)

bench: build
	@python3 bench/ept_throughput.py --build $(BUILD)

clean:
	rm -rf $(BUILD) $(BUILD).configure.log out
