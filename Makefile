# cellcal: the two commands a user needs.
#   make demo   installs what is missing (apt), builds, runs the demo
#   make test   installs what is missing (apt), builds, runs every test (each with a fixed seed: it repeats)
# For developers: make quick (the quick label, a few minutes), make sweep (the seeded tests over fresh seeds).
BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= $(shell nproc)

.PHONY: all deps configure build demo test quick sweep bench install clean fuzz

all: build

deps:
	bash tools/install_deps.sh
	bash tools/tune_host.sh

configure: deps
	cmake -S . -B $(BUILD_DIR) -DCMAKE_BUILD_TYPE=$(BUILD_TYPE)

build: configure
	cmake --build $(BUILD_DIR) -j $(JOBS)

# The four-process cell on localhost against the simulated Staubli TX60 (the paper's continuous scenario: 50 poses,
# then 15 fresh poses every 2 h of cell time, 720x compressed).
# A recorder runs beside it; the recording is then validated (the engine's logic in-process, compared with the
# recorded calibrations; docs/recording.md).
demo: build
	$(BUILD_DIR)/bin/cellcal cell --duration-s 32 --work-dir $(BUILD_DIR)/demo/cell \
	  --summary-json $(BUILD_DIR)/demo/cell-summary.json --record $(BUILD_DIR)/demo/demo.mcap
	$(BUILD_DIR)/bin/cellcal validate $(BUILD_DIR)/demo/demo.mcap --json $(BUILD_DIR)/demo/validate.json --require-match \
	  --figures $(BUILD_DIR)/demo/figures
	@echo "demo: figures in $(BUILD_DIR)/demo/figures: $$(ls $(BUILD_DIR)/demo/figures/*.png | tr '\n' ' ')"

# The libFuzzer targets are built first (clang, tools/fuzz.sh), so that the fuzz smoke's time in ctest is its own.
test: build
	bash tools/fuzz.sh --build-only $(BUILD_DIR)/fuzz
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) -LE bench

# The tests labelled quick: a developer's loop of a few minutes (docs/testing.md).
quick: build
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS) -L quick

# The seeded tests RUNS times, each run with fresh seeds: each test's failure rate and its failing seeds
# (docs/testing.md). FILTER is a ctest regex: make sweep RUNS=100 FILTER='^Campaign\.'
RUNS ?= 100
FILTER ?= .
sweep: build
	bash tools/sweep.sh -n $(RUNS) -R '$(FILTER)' $(BUILD_DIR)

# libFuzzer on every file parser, 300 s each (make test runs a 5 s smoke of the same).
fuzz: build
	tools/fuzz.sh 300 $(BUILD_DIR)/fuzz

bench: build
	cd $(BUILD_DIR) && ctest --output-on-failure -L bench
	$(BUILD_DIR)/bin/cellcal_bench
	$(BUILD_DIR)/bin/cellcal_ik_sweep --seeds 5000
	$(BUILD_DIR)/bin/cellcal_servo_rt_bench --json $(BUILD_DIR)/servo_rt_bench.json
	bash tools/bench/diagnose_speed.sh $(BUILD_DIR)
	bash tools/bench/hot_path.sh $(BUILD_DIR) 20
	$(BUILD_DIR)/bin/cellcal bench-cell --duration-s 20
	-$(BUILD_DIR)/bin/cellcal bench-servo --robots 8 --rate-hz 250 --duration-s 60 --hogs 2 --rt-priority 80 --json $(BUILD_DIR)/bench_servo_250.json
	-$(BUILD_DIR)/bin/cellcal bench-servo --robots 8 --rate-hz 500 --duration-s 60 --hogs 2 --rt-priority 80 --json $(BUILD_DIR)/bench_servo_500.json
	-$(BUILD_DIR)/bin/cellcal bench-servo --robots 8 --rate-hz 500 --duration-s 60 --hogs 2 --rt-priority 80 --pass-through --json $(BUILD_DIR)/bench_servo_500_floor.json
	bash tools/bench/foxglove_bench.sh $(BUILD_DIR) 20
	bash tools/bench/engine_saturation.sh $(BUILD_DIR) 10
	bash tools/bench/durability_bench.sh $(BUILD_DIR) 40 2

# Installs into PREFIX (default /usr/local) with the same script docker/Dockerfile runs (tools/build_install.sh).
PREFIX ?= /usr/local
install: deps
	bash tools/build_install.sh $(PREFIX)

clean:
	rm -rf $(BUILD_DIR)
