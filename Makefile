# Thin driver over CMake for the README's two commands.
#   make demo   install what is missing, build, render the bundled example to out/
#   make test   install what is missing, build, run every test suite
BUILD ?= build
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
CMAKE_ARGS ?=

.PHONY: demo test deps build bench clean

deps:
	@scripts/install-deps.sh

build: deps
	@cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release $(CMAKE_ARGS) > $(BUILD).configure.log 2>&1 || { cat $(BUILD).configure.log; exit 1; }
	@grep -E "hdGranular" $(BUILD).configure.log || true
	@cmake --build $(BUILD) -j $(JOBS)

demo: build
	@mkdir -p out
	$(BUILD)/core/granular-render examples/demo.json -o out/demo.exr --png out/demo.png

test: build
	@cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

bench: build
	@python3 bench/ept_throughput.py --build $(BUILD)

clean:
	rm -rf $(BUILD) $(BUILD).configure.log out
