# WireCraft: `make demo` and `make test` work on a fresh machine (they create .venv when missing).
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-dev

# Python 3.12 is required. Try, in order: $(PYTHON), python3.12 on PATH, pyenv's 3.12.x.
PYTHON ?= $(shell for c in python3.12 "$$(pyenv root 2>/dev/null)/versions/3.12.1/bin/python3.12" $$(ls -d "$$(pyenv root 2>/dev/null)"/versions/3.12*/bin/python3.12 2>/dev/null); do \
	  "$$c" -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1 && { echo "$$c"; break; }; done)

GL_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1
# Headless Chromium renders the evaluation's HTML report in a test (driven by playwright).
BROWSER_PACKAGES := chromium
# A virtual display and key sender for the teleoperation window test (tests/test_teleop.py).
WINDOW_PACKAGES := xvfb xdotool x11-apps

.PHONY: demo test bench lint venv install gpu sysdeps browser window clean

$(PY):
	@if [ -z "$(PYTHON)" ]; then \
	  echo "error: Python 3.12 not found. Install it (e.g. 'pyenv install 3.12' or your OS package 'python3.12')," >&2; \
	  echo "       or pass its path: make PYTHON=/path/to/python3.12" >&2; exit 1; fi
	"$(PYTHON)" -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

venv: $(PY)

# PyPI's PyTorch for Linux brings its CUDA libraries: the environment takes ~9 GB. Short of
# that, pip fails late with 'No space left on device'; say so up front. The second install is
# LeRobot's environment plug-in (lerobot-eval / lerobot-train --env.type=wirecraft_*).
$(STAMP): pyproject.toml plugins/lerobot_env_wirecraft/pyproject.toml | $(PY)
	@free_kb=$$(df -Pk "$(VENV)" | awk 'NR==2 {print $$4}'); \
	if [ "$${free_kb:-0}" -lt 10000000 ]; then \
	  echo "warning: installing needs about 10 GB of free disk; $$((free_kb / 1024)) MB free where $(VENV) lives" >&2; fi
	$(PY) -m pip install -q -e '.[dev,all]'
	$(PY) -m pip install -q -e plugins/lerobot_env_wirecraft
	@touch $@

install: $(STAMP)

# The GPU backend (MuJoCo Warp, ~390 MB), on request: the demo does not need it; the tests run
# its parity checks on Warp's CPU device.
GPU_STAMP := $(VENV)/.installed-gpu
$(GPU_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install -q -e '.[gpu]'
	@touch $@

gpu: $(GPU_STAMP)

# Off-screen rendering on the CPU needs Mesa's EGL. Installed with apt-get when missing (CI runs
# as root); otherwise the missing packages are named.
sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so.0' || ! ldconfig -p | grep -q 'libgbm.so.1'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing OpenGL libraries for headless rendering: $(GL_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(GL_PACKAGES) >/dev/null; \
	  else \
	    echo "error: headless rendering needs the system packages $(GL_PACKAGES) (Debian/Ubuntu names)" >&2; \
	    echo "       install them, e.g. 'sudo apt-get install $(GL_PACKAGES)'" >&2; exit 1; \
	  fi; \
	fi

browser:
	@if ! command -v chromium >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing a headless browser for the report test: $(BROWSER_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(BROWSER_PACKAGES) >/dev/null; \
	  else \
	    echo "warning: 'chromium' not found; the HTML report test will be skipped." >&2; \
	    echo "         install it, e.g. 'sudo apt-get install $(BROWSER_PACKAGES)'" >&2; \
	  fi; \
	fi

window:
	@if ! command -v Xvfb >/dev/null || ! command -v xdotool >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing a virtual display for the teleoperation test: $(WINDOW_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(WINDOW_PACKAGES) >/dev/null; \
	  else \
	    echo "warning: Xvfb or xdotool not found; the teleoperation window test will be skipped." >&2; \
	    echo "         install them, e.g. 'sudo apt-get install $(WINDOW_PACKAGES)'" >&2; \
	  fi; \
	fi

demo: install sysdeps
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/wirecraft demo --out out/demo

test: install gpu sysdeps browser window
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -n 2 -q

bench: install
	$(VENV)/bin/wirecraft bench --suite wires
	$(VENV)/bin/wirecraft bench --suite robots
	$(VENV)/bin/wirecraft bench --suite envs --task insertion --wire articulated --num-envs 1,16,256 --threads 1,2 --json out/bench/envs.json

lint: install
	$(VENV)/bin/ruff check src tests benchmarks research plugins
	$(VENV)/bin/ruff format --check src tests benchmarks research plugins

clean:
	rm -rf $(VENV) out build *.egg-info
