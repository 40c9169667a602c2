# The two commands: `make run` (the demo on the simulated machine) and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint typecheck check bench fuzz soak clean senders senders-test web

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,fast]'
	touch $(STAMP)

DEMO := src/usbmotion/data/demos/1-rounded-square.ngc

# The web dashboard's page (usbmotion web): three.js and uPlot from npm, pinned by
# src/usbmotion/web/frontend/package-lock.json, bundled by esbuild into
# src/usbmotion/web/static/dist (a build output, never committed). Needs Node.js 20 and npm;
# make run goes on without them (the dashboard's page then says it is not built).
WEB := src/usbmotion/web/frontend
WEB_BUNDLE := src/usbmotion/web/static/dist/app.js

$(WEB)/node_modules/.package-lock.json: $(WEB)/package-lock.json
	cd $(WEB) && npm ci --no-audit --no-fund --loglevel=error

$(WEB_BUNDLE): $(WEB)/node_modules/.package-lock.json $(WEB)/build.mjs $(wildcard $(WEB)/src/*.js)
	cd $(WEB) && node build.mjs

web: $(WEB_BUNDLE)

run: $(STAMP)
	@command -v npm > /dev/null && $(MAKE) --no-print-directory web \
	  || echo "make run: no npm, so the web dashboard's page is not built (usbmotion web)"
	@mkdir -p out
	$(BIN)/usbmotion run $(DEMO) --plot out/demo-1.png --report out/demo-1.json

# The firmware is built while the senders are installed and the web page is built; then
# three lanes at once, their output printed when they end, then lint and types:
# - the Python suite in virtual time (PYTHON_SUITE without its `realtime` tests), at a lower
#   priority (nice) than the others: its load takes every core they leave, but it does not
#   starve the simulated devices they serve in real time (a device served by a process that
#   gets no core stands still, and a wall-clock figure such as a stop's latency then
#   measures the simulation, not the product);
# - the real-time tests of the G-code senders, of reliability and of the dashboard
#   (tests/senders, tests/reliability, tests/web: mostly waiting on the machine's clock);
# - firmware-test (the firmware's build and the emulated chip's tests), then the Python
#   suite's `realtime` tests (devices on pseudo-terminals and sockets: waiting, mostly),
#   which the other two lanes' load surrounds.
# The real-time tests run while both cores are busy with the rest: they must pass on a
# loaded machine. A machine without the firmware's toolchain fails only firmware-test,
# after saying what to install; the rest still runs. The G-code senders the grbl front is
# tested with are installed first (senders); where they cannot be, their tests skip (fail
# under CI=true) and the rest still runs.
PYTHON_SUITE = $(EMULATED_IGNORE) --ignore=tests/senders --ignore=tests/reliability \
	--ignore=tests/web
test: $(STAMP)
	@mkdir -p build; status=0; \
	$(MAKE) --no-print-directory firmware-toolchain > build/firmware-build.log 2>&1; \
	( $(MAKE) --no-print-directory firmware >> build/firmware-build.log 2>&1 ) & build=$$!; \
	bash tests/senders/install.sh || status=1; \
	$(MAKE) --no-print-directory web || status=1; \
	wait $$build; \
	( $(MAKE) --no-print-directory firmware-test > build/firmware-test.log 2>&1; \
	  echo $$? > build/firmware-test.status; \
	  $(BIN)/python -m pytest -q -x -p no:cacheprovider --basetemp=build/realtime-tmp \
	  -m realtime $(PYTHON_SUITE) > build/realtime-test.log 2>&1; \
	  echo $$? > build/realtime-test.status ) & \
	( $(BIN)/python -m pytest -q -x -p no:cacheprovider --basetemp=build/senders-tmp \
	  tests/senders tests/reliability tests/web > build/senders-test.log 2>&1; \
	  echo $$? > build/senders-test.status ) & \
	nice -n 10 $(BIN)/python -m pytest -q -x -p no:cacheprovider -m "not realtime" \
	  $(PYTHON_SUITE) || status=1; \
	wait; echo "--- the senders', reliability and dashboard tests:"; cat build/senders-test.log; \
	[ "$$(cat build/senders-test.status)" = 0 ] || status=1; \
	echo "--- make firmware-test:"; cat build/firmware-build.log build/firmware-test.log; \
	[ "$$(cat build/firmware-test.status)" = 0 ] || status=1; \
	echo "--- the Python suite's real-time tests (devices on terminals and sockets):"; \
	cat build/realtime-test.log; [ "$$(cat build/realtime-test.status)" = 0 ] || status=1; \
	$(BIN)/ruff check src tests benchmarks || status=1; \
	$(BIN)/mypy || status=1; \
	exit $$status

# The G-code senders the grbl front is tested with (grbl-streamer, cncjs, Chromium for its
# web page): installed once, pinned (tests/senders/install.sh; apt needs root), and their
# tests alone (real time; make test runs them too).
senders: $(STAMP)
	bash tests/senders/install.sh

senders-test: senders
	$(BIN)/python -m pytest -q -p no:cacheprovider tests/senders

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy

# The long runs of the reliability tests: 100,000 examples per fuzz property (make test runs
# a few hundred of each), no per-test timeout; a hang fails its example after 10 s.
FUZZ_EXAMPLES ?= 100000

fuzz: $(STAMP)
	@status=0; \
	USBMOTION_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/python -m pytest tests/fuzz -q \
		-p no:cacheprovider -o timeout=0 --hypothesis-show-statistics || status=1; \
	$(MAKE) --no-print-directory firmware-fuzz || status=1; \
	exit $$status

# One hour of program on the default machine in virtual time: planned vs executed time and
# memory (tracemalloc). make test runs three minutes of it.
soak: $(STAMP)
	USBMOTION_SOAK_S=3600 $(BIN)/python -m pytest tests/reliability/test_soak.py -q -s \
		-p no:cacheprovider -o timeout=0

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .mypy_cache .ruff_cache

# The RP2040 firmware (firmware/): picotool once (without USB, only to write UF2 files), then
# the CMake build on the Pico SDK into build/firmware (.elf/.bin/.uf2), and the emulator's npm
# packages. Only these targets need the Arm toolchain; check-toolchain.sh installs it as root
# (CI) and otherwise says what is missing.
PICO_SDK_PATH ?= $(abspath ../shared/rp2040/pico-sdk)
PICOTOOL_SOURCE ?= $(abspath ../shared/rp2040/picotool)
PICOTOOL_PREFIX := $(CURDIR)/build/picotool
PICOTOOL_CONFIG := $(PICOTOOL_PREFIX)/lib/cmake/picotool/picotoolConfig.cmake
FIRMWARE_BUILD := build/firmware
EMULATOR := firmware/emulator

.PHONY: firmware firmware-toolchain firmware-test firmware-fuzz

firmware-toolchain:
	@bash firmware/tools/check-toolchain.sh
	@for source in $(PICO_SDK_PATH)/pico_sdk_init.cmake $(PICOTOOL_SOURCE)/CMakeLists.txt; do \
	  [ -f "$$source" ] || { echo "firmware: $$source is missing: the Pico SDK 2.2.0 and" \
	    "picotool 2.2.0 sources are expected beside the project (../shared/rp2040), or" \
	    "give PICO_SDK_PATH=... PICOTOOL_SOURCE=... to make" >&2; exit 1; }; done

$(PICOTOOL_CONFIG): | firmware-toolchain
	cmake -S $(PICOTOOL_SOURCE) -B build/picotool-build -DCMAKE_BUILD_TYPE=Release \
		-DPICO_SDK_PATH=$(PICO_SDK_PATH) -DPICOTOOL_NO_LIBUSB=1 -DCMAKE_INSTALL_PREFIX=$(PICOTOOL_PREFIX)
	cmake --build build/picotool-build -j2 --target install

$(EMULATOR)/node_modules/.package-lock.json: $(EMULATOR)/package-lock.json | firmware-toolchain
	cd $(EMULATOR) && npm ci --no-audit --no-fund

firmware: firmware-toolchain $(PICOTOOL_CONFIG) $(EMULATOR)/node_modules/.package-lock.json
	cmake -S firmware -B $(FIRMWARE_BUILD) -DCMAKE_BUILD_TYPE=Release \
		-DPICO_SDK_PATH=$(PICO_SDK_PATH) -Dpicotool_DIR=$(dir $(PICOTOOL_CONFIG))
	cmake --build $(FIRMWARE_BUILD) -j2
	@echo "firmware: $(FIRMWARE_BUILD)/usbmotion.uf2 is built. To flash a Pico with it:"
	@echo "  hold its BOOTSEL button while plugging it in: it shows a USB drive, RPI-RP2;"
	@echo "  copy the file there (cp $(FIRMWARE_BUILD)/usbmotion.uf2 /media/$$(id -un)/RPI-RP2/"
	@echo "  on most Linux desktops): the Pico reboots into the firmware. Or, with a picotool"
	@echo "  built with USB support (build/picotool has none): picotool load -x $(FIRMWARE_BUILD)/usbmotion.uf2"
	@echo "  Without a Pico: usbmotion sim --firmware $(FIRMWARE_BUILD)/usbmotion.uf2 --pty 3"

# The firmware's tests beyond the Python suite's native ones (tests/firmware/test_native_*):
# the emulator harness's own (node, on the test fixture firmware), then the product firmware
# on the emulated chip against the Python device (tests/firmware/test_emulated_*: every
# scripted session, a few hundred generated ones, demo 1 end to end).
EMULATED_TESTS := $(sort $(wildcard tests/firmware/test_emulated_*.py))
EMULATED_IGNORE := $(addprefix --ignore=,$(EMULATED_TESTS))

firmware-test: firmware $(STAMP)
	cd $(EMULATOR) && node --test test/
	$(BIN)/python -m pytest -q -p no:cacheprovider $(EMULATED_TESTS)

# The long run: FIRMWARE_FUZZ_EXAMPLES generated sessions of the full device fuzz strategy
# (silences of up to 60,001 ticks) on the emulated chip against the Python device, and the
# native build's generated sessions at FUZZ_EXAMPLES.
FIRMWARE_FUZZ_EXAMPLES ?= 10000

firmware-fuzz: firmware $(STAMP)
	USBMOTION_FUZZ_EXAMPLES=$(FIRMWARE_FUZZ_EXAMPLES) $(BIN)/python -m pytest -q \
		-p no:cacheprovider -o timeout=0 --hypothesis-show-statistics \
		tests/firmware/test_emulated_fuzz.py
	USBMOTION_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/python -m pytest -q \
		-p no:cacheprovider -o timeout=0 tests/firmware/test_native_device.py -k "fuzz or random"
