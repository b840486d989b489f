# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim: the two commands a new user needs are `make demo` and `make test`.
# Both install missing Debian packages when run as root (else print the apt-get line),
# configure the CMake build in build/, and build with every core.

BUILD     ?= build
JOBS      ?= $(shell nproc 2>/dev/null || echo 2)
PACKAGES  := cmake gcc make pkg-config liblcm-dev liblcm-bin libsuitesparse-dev libopenblas-dev \
             libcjson-dev libpng-dev libwebsockets-dev libjs-three chromium nodejs gnuplot-nox \
             iproute2 util-linux clang libclang-rt-14-dev python3-meshio libgmsh-dev
CMAKE_ARGS ?=

.PHONY: all deps configure build test test-asan test-tsan demo bench bench-quick accuracy stress soak fuzz clean

all: build

deps:
	@missing=""; for p in $(PACKAGES); do \
	  dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "hapsim: installing$$missing"; \
	    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$missing; \
	  else \
	    echo "hapsim: missing Debian packages; run as root:"; \
	    echo "  apt-get update && apt-get install -y$$missing"; exit 1; \
	  fi; \
	fi; \
	if ! command -v npm >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo "hapsim: installing npm (Debian's nodejs ships it separately)"; \
	    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q npm; \
	  else echo "hapsim: npm missing; run as root: apt-get install -y npm"; exit 1; fi; \
	fi

# build/Makefile appears only when a configure succeeds (the cache is written even when it
# fails, which would block every later make); the packages come first even under make -j.
$(BUILD)/Makefile: | deps
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=RelWithDebInfo $(CMAKE_ARGS)

configure: deps $(BUILD)/Makefile

build: configure
	cmake --build $(BUILD) -j $(JOBS)

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

# The same tests once more under AddressSanitizer + UndefinedBehaviorSanitizer.
test-asan: deps
	$(MAKE) test BUILD=build-asan CMAKE_ARGS="-DHS_SANITIZE=ON"

# Lock-free primitives and threads under ThreadSanitizer.
test-tsan: deps
	$(MAKE) build BUILD=build-tsan CMAKE_ARGS="-DHS_TSAN=ON"
	cd build-tsan && ctest --output-on-failure -L tsan

# The server on the bundled liver scene, driven by the simulated stylus; ends by itself
# (about 45 s) and leaves the trace, a force plot and the server log in out/demo/.
demo: build
	scripts/demo.sh $(BUILD)

bench: build
	$(BUILD)/bin/hapsim-bench all

bench-quick: build
	$(BUILD)/bin/hapsim-bench all --quick

# Run time against error (docs/accuracy.md): CSV in out/, plots in docs/plots/.
accuracy: build
	mkdir -p out docs/plots
	$(BUILD)/bin/hapsim-bench accuracy | tee out/accuracy.csv
	for s in cantilever10x cantilever liver-press vessel; do \
	  gnuplot -e "csv='out/accuracy.csv'; scene='$$s'" tests/bench/plot_accuracy.gp; \
	  gnuplot -e "csv='out/accuracy.csv'; scene='$$s'; metric='l2'" tests/bench/plot_accuracy.gp; done

# Numerical stress suite, long version (100,000-step soaks); `make test` runs the quick one.
stress: build
	mkdir -p out
	$(BUILD)/bin/hapsim-bench stress > out/stress.csv; rc=$$?; cat out/stress.csv; exit $$rc

# libFuzzer targets (tests/fuzz) for FUZZ_SECONDS each; any crash, leak or sanitizer report fails.
FUZZ_SECONDS ?= 30
fuzz: deps
	CC=clang cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHS_FUZZ=ON
	cmake --build build-fuzz --target hs_fuzzers -j $(JOBS)
	@set -e; for f in build-fuzz/bin/fuzz_*; do \
	  [ -f "$$f" ] && [ -x "$$f" ] || continue; n=$${f##*/fuzz_}; \
	  mkdir -p build-fuzz/corpus/$$n; seeds=""; dict=""; \
	  [ -d tests/fuzz/corpus/$$n ] && seeds=tests/fuzz/corpus/$$n; \
	  [ -f tests/fuzz/$$n.dict ] && dict=-dict=tests/fuzz/$$n.dict; \
	  echo "fuzz: $$n for $(FUZZ_SECONDS) s"; \
	  $$f -max_total_time=$(FUZZ_SECONDS) -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
	    -artifact_prefix=build-fuzz/ $$dict build-fuzz/corpus/$$n $$seeds; \
	done

clean:
	rm -rf build build-asan build-tsan build-fuzz out
