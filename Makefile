# cellcal: the two commands a user needs.
#   make demo   installs what is missing (apt), builds, runs the demo
#   make test   installs what is missing (apt), builds, runs every test
BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= $(shell nproc)

.PHONY: all deps configure build demo test bench clean

all: build

deps:
	bash tools/install_deps.sh

configure: deps
	cmake -S . -B $(BUILD_DIR) -DCMAKE_BUILD_TYPE=$(BUILD_TYPE)

build: configure
	cmake --build $(BUILD_DIR) -j $(JOBS)

# Until the DDS cell exists the demo is the paper experiment on the simulated Staubli TX60.
demo: build
	$(BUILD_DIR)/bin/cellcal experiment paper --plot $(BUILD_DIR)/demo --json $(BUILD_DIR)/demo/paper.json

test: build
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS)

bench: build
	$(BUILD_DIR)/bin/cellcal_bench

clean:
	rm -rf $(BUILD_DIR)
