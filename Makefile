# Thin driver over CMake for the README's two commands.
#   make demo   install what is missing, build, render the USD sand castle to out/ (denoised PNG)
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

.PHONY: demo demo-json gallery test deps venv build schemas bench clean sanitize fuzz fuzz-usd

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
	$(VENV)/bin/granular render examples/sandcastle_paper.usda --spp 32 --denoise -o out/demo.exr --png out/demo.png

# Every USD example at presentation quality into out/gallery/, with a contact sheet
# (scripts/gallery.py; GALLERY_ARGS="--width 640 --spp 256 --docs" and so on).
GALLERY_ARGS ?=
gallery: build
	$(PY) scripts/gallery.py $(GALLERY_ARGS)

# The JSON front end of the C++ command line, for comparison.
demo-json: build
	@mkdir -p out
	$(BUILD)/core/granular-render examples/demo.json -o out/demo-json.exr --png out/demo-json.png

# ctest, then pytest; pytest's "no tests collected" (exit 5) is an error here, not a pass.
test: build
	@cd $(BUILD) && ctest --output-on-failure --no-tests=error -j $(JOBS)
	@GRANULAR_BUILD_DIR=$(abspath $(BUILD)) $(PY) -m pytest -q -p no:cacheprovider tests/python; rc=$$?; \
	  if [ $$rc -eq 5 ]; then echo "pytest: no tests were collected" >&2; fi; exit $$rc

# The C++ core, the Hydra delegate (when OpenUSD is found, as for `make build`) and their
# tests under AddressSanitizer + UndefinedBehaviorSanitizer (GRANULAR_SANITIZE) in
# $(ASAN_BUILD), then ctest there: any report fails the run (UBSan does not recover, ASan
# stops at the first error, LeakSanitizer checks at exit). OpenUSD itself is not
# instrumented; the delegate's tests run in our instrumented test program with leak
# checks off (tests/CMakeLists.txt: OpenUSD keeps process-lifetime allocations whose
# stacks LeakSanitizer cannot unwind). Building lists the tests with leak checks off too.
# The Python bindings are not built there (the interpreter is not instrumented).
ASAN_BUILD ?= build-asan
SANITIZER_ENV = ASAN_OPTIONS=detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1 \
  UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
sanitize: deps
	@cmake -S . -B $(ASAN_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGRANULAR_SANITIZE=ON -DGRANULAR_PYTHON=OFF $(PXR_ARGS) $(CMAKE_ARGS) > $(ASAN_BUILD).configure.log 2>&1 || { cat $(ASAN_BUILD).configure.log; exit 1; }
	@grep -E "hdGranular" $(ASAN_BUILD).configure.log || true
	@ASAN_OPTIONS=detect_leaks=0 cmake --build $(ASAN_BUILD) -j $(JOBS)
	@cd $(ASAN_BUILD) && $(SANITIZER_ENV) ctest --output-on-failure --no-tests=error -j $(JOBS)

# libFuzzer targets (fuzz/README.md), built with clang in $(FUZZ_BUILD), each run for
# FUZZ_SECONDS on a corpus seeded from examples/, bench/scenes/ and the tests; crashes,
# leaks, timeouts and out-of-memory inputs land in $(FUZZ_BUILD)/artifacts/.
FUZZ_BUILD ?= build-fuzz
FUZZ_SECONDS ?= 60
FUZZ_CXX ?= $(shell command -v clang++-14 || command -v clang++)
FUZZ_CC ?= $(shell command -v clang-14 || command -v clang)
fuzz: deps
	@test -n "$(FUZZ_CXX)" || { echo "fuzz: needs clang (apt-get install clang-14 libclang-rt-14-dev)" >&2; exit 1; }
	@CC=$(FUZZ_CC) CXX=$(FUZZ_CXX) cmake -S . -B $(FUZZ_BUILD) -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DGRANULAR_FUZZ=ON -DGRANULAR_BUILD_TESTS=OFF -DGRANULAR_PYTHON=OFF > $(FUZZ_BUILD).configure.log 2>&1 || { cat $(FUZZ_BUILD).configure.log; exit 1; }
	@cmake --build $(FUZZ_BUILD) -j $(JOBS) --target fuzz_scene_json fuzz_usd_attributes fuzz_usd_prims fuzz_ies
	@python3 fuzz/seed_corpus.py $(FUZZ_BUILD)/corpus
	@mkdir -p $(FUZZ_BUILD)/artifacts
	@for t in fuzz_scene_json fuzz_usd_attributes fuzz_usd_prims fuzz_ies; do \
	  echo "== $$t, $(FUZZ_SECONDS) s"; \
	  mkdir -p $(FUZZ_BUILD)/corpus/$$t.run && cd $(FUZZ_BUILD) && \
	  GRANULAR_CACHE_DIR=$(abspath $(FUZZ_BUILD))/cache ./fuzz/$$t -max_total_time=$(FUZZ_SECONDS) -timeout=30 -rss_limit_mb=3072 \
	    -max_len=16384 -print_final_stats=1 -artifact_prefix=artifacts/$$t- corpus/$$t.run corpus/$$t || exit 1; \
	  cd - > /dev/null; \
	done

# Atheris (libFuzzer for Python, installed into the venv here only) on whole USD stages
# through `granular render`'s own code (fuzz/fuzz_usd_stage.py), for FUZZ_SECONDS, one
# process; the corpus grows in $(FUZZ_BUILD)/corpus/fuzz_usd_stage.run, seeded with
# fuzz/regressions/usd_stage_*.usda; findings land in $(FUZZ_BUILD)/artifacts/.
fuzz-usd: build
	@scripts/setup-venv.sh $(VENV) $(BUILD) --fuzz
	@mkdir -p $(FUZZ_BUILD)/corpus/fuzz_usd_stage $(FUZZ_BUILD)/corpus/fuzz_usd_stage.run $(FUZZ_BUILD)/artifacts
	@cp fuzz/regressions/usd_stage_*.usda $(FUZZ_BUILD)/corpus/fuzz_usd_stage/
	@cd $(FUZZ_BUILD) && GRANULAR_BUILD_DIR=$(abspath $(BUILD)) GRANULAR_CACHE_DIR=$(abspath $(FUZZ_BUILD))/cache-usd \
	  $(abspath $(PY)) $(CURDIR)/fuzz/fuzz_usd_stage.py -max_total_time=$(FUZZ_SECONDS) -timeout=30 -rss_limit_mb=3072 \
	    -max_len=4096 -len_control=0 -print_final_stats=1 -artifact_prefix=artifacts/fuzz_usd_stage- \
	    corpus/fuzz_usd_stage.run corpus/fuzz_usd_stage

# Regenerates schemas/generatedSchema.usda and plugInfo.json from schemas/schema.usda.
schemas: venv
	@scripts/gen-schema.sh $(PY)

bench: build
	@python3 bench/ept_throughput.py --build $(BUILD)

clean:
	rm -rf $(BUILD) $(BUILD).configure.log out
