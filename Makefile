# forestslam: `make run` and `make test` are the whole set-up on a fresh Debian machine.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
APT_PACKAGES := g++ make python3-dev python3-venv libpcl-dev libceres-dev libeigen3-dev libgtest-dev libyaml-cpp-dev
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
BUILD_DIR := build/py
SOURCES := $(shell find cpp python -type f \( -name '*.cpp' -o -name '*.hpp' -o -name '*.py' \
	-o -name '*.yaml' -o -name 'CMakeLists.txt' -o -name '*.cmake' \) -not -path '*/__pycache__/*')
SAMPLE := data/cache/sample
OUT ?= out/sample

.PHONY: install run test lint format bench clean

install: $(VENV)/.installed

# System packages, only those missing (dpkg knows); through sudo when not root.
$(VENV)/.apt:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "Installing system packages: $$missing"; \
		$(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi
	@test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	@touch $@

$(VENV)/.deps: pyproject.toml $(VENV)/.apt
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q "scikit-build-core>=0.10" "pybind11>=2.12" cmake ninja
	$(VPY) -m pip install -q $$($(VPY) -c 'import tomllib;d=tomllib.load(open("pyproject.toml","rb"))["project"];print(" ".join(repr(x) for x in d["dependencies"]+d["optional-dependencies"]["test"]+d["optional-dependencies"]["bench"]))' | tr -d "'")
	@touch $@

# The package, built incrementally in build/py (C++ tests on, so ctest reuses this build).
$(VENV)/.installed: $(VENV)/.deps $(SOURCES) CMakeLists.txt pyproject.toml
	$(VPY) -m pip install -q --no-build-isolation --no-deps \
		-C cmake.define.FORESTSLAM_BUILD_TESTS=ON -C build.verbose=false .
	@touch $@

# The bundled default: data/sample.yaml simulated once (cached, git-ignored), then the main job
# on it and the evaluation against its ground truth.
# Re-simulated when the scenario or the simulator changes (a cached sample of an older model
# would hide what the new one shows).
SIM_SOURCES := $(shell find python/forestslam/sim cpp/forestslam/sim -type f -not -path '*/__pycache__/*')
$(SAMPLE)/sequence.bag: data/sample.yaml $(SIM_SOURCES) | $(VENV)/.installed
	$(VENV)/bin/forestslam simulate --scenario data/sample.yaml --out $(SAMPLE)

run: install $(SAMPLE)/sequence.bag
	$(VENV)/bin/forestslam run $(SAMPLE)/sequence.bag --sensor vlp16 --mode slam --out $(OUT)
	$(VENV)/bin/forestslam evaluate $(OUT) --truth $(SAMPLE)/truth

test: install
	$(VENV)/bin/ctest --test-dir $(BUILD_DIR)/cpp --output-on-failure -j2
	$(VPY) -m pytest -q
	$(VENV)/bin/ruff check python tests bench
	@echo "clang-format --dry-run -Werror on $(words $(CPP_FILES)) C++ files"
	@$(VENV)/bin/clang-format --dry-run -Werror $(CPP_FILES)

CPP_FILES = $(shell git ls-files 'cpp/*.cpp' 'cpp/*.hpp' 'python/forestslam/pybind/*.cpp' \
	'python/forestslam/pybind/*.hpp')

lint: install
	$(VENV)/bin/ruff check python tests bench
	$(VENV)/bin/ruff format --check python tests bench
	@echo "clang-format --dry-run -Werror on $(words $(CPP_FILES)) C++ files"
	@$(VENV)/bin/clang-format --dry-run -Werror $(CPP_FILES)

format: install
	$(VENV)/bin/ruff format python tests bench
	$(VENV)/bin/clang-format -i $(CPP_FILES)

clean:
	rm -rf build $(VENV) out
