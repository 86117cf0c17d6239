# Every target bootstraps .venv from nothing (python3 >= 3.11 and network access to PyPI).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Arguments passed through to the CLI, e.g. `make demo ARGS="--duration 10"`.
ARGS   ?=

.PHONY: all test lint format bench demo soak chaos schemas clean opencv-data

all: test

$(STAMP): pyproject.toml setup.py
	@$(PYTHON) -c 'import sys; sys.exit("followbot needs Python >= 3.11, found " + sys.version.split()[0]) if sys.version_info < (3, 11) else None'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
	@touch $@

test: $(STAMP)
	$(BIN)/python -m pytest -q $(ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

# Runtime, wire and whole-pipeline figures, then each stage's own benchmark.
bench: $(STAMP)
	$(BIN)/followbot bench $(ARGS)
	$(BIN)/python -m followbot.services.laser_legs.bench
	$(BIN)/python -m followbot.services.laser_odometry.bench
	$(BIN)/python -m followbot.services.tracker.bench
	$(BIN)/python -m followbot.services.controller.bench
	$(BIN)/python -m followbot.services.vision_verify.bench
	$(BIN)/python -m followbot.services.sim.bench
	$(BIN)/python -m followbot.services.camera_blobs.bench
	$(BIN)/python -m followbot.services.tracker.bench_hybrid

demo: $(STAMP)
	$(BIN)/followbot demo $(ARGS)

# Long run: FOLLOWBOT_SOAK_S (default 60) seconds at FOLLOWBOT_SOAK_RATE (default 200) scans/s.
soak: $(STAMP)
	$(BIN)/python -m pytest -q -s -m soak --run-soak --timeout=0 tests/test_soak.py $(ARGS)

# Fault injection and start-up checks (opt-in, several minutes each): tests/test_chaos.py runs the
# whole system under `followbot up` while each service is killed in turn and a rogue peer sends
# garbage and stamps from the wrong time; tests/test_up.py starts `followbot up compose/sim.yaml`
# FOLLOWBOT_CHAOS_STARTS (default 50) times, each service seeing every other within 5 s every
# time. Both print figures; pick one with ARGS="-k fifty" or ARGS="-k 'not fifty'".
chaos: $(STAMP)
	$(BIN)/python -m pytest -q -s -m chaos --run-chaos --timeout=0 tests/test_chaos.py tests/test_up.py $(ARGS)

# Real pedestrian footage for the vision tests: Debian's opencv-doc (examples/data/vtest.avi),
# unpacked once into a cache outside the clone. Needs apt-get (Debian/Ubuntu).
OPENCV_CACHE ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/followbot
opencv-data:
	@if [ -f "$(OPENCV_CACHE)/opencv-doc/usr/share/doc/opencv-doc/examples/data/vtest.avi" ]; then \
	  echo "opencv-doc data already in $(OPENCV_CACHE)"; \
	else \
	  mkdir -p "$(OPENCV_CACHE)/deb" && cd "$(OPENCV_CACHE)/deb" && \
	  (apt-get download opencv-doc || (apt-get update -qq && apt-get download opencv-doc)) && \
	  dpkg-deb -x opencv-doc_*.deb "$(OPENCV_CACHE)/opencv-doc" && rm -f opencv-doc_*.deb && \
	  echo "opencv-doc data in $(OPENCV_CACHE)/opencv-doc"; \
	fi

# Regenerate the JSON Schema contract and docs/messages.md after a deliberate change.
schemas: $(STAMP)
	$(BIN)/followbot schemas --output schemas/contract
	$(BIN)/followbot schemas --markdown docs/messages.md
	$(BIN)/followbot settings --markdown docs/settings.md

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis build *.egg-info
