# photoar: `make demo` composites the bundled scene, `make test` runs the tests.
# Both set up .venv (and the apt libraries Open3D needs) on a fresh machine first.
PY      ?= python3
VENV    := .venv
VPY     := $(VENV)/bin/python
APT_PKGS := libusb-1.0-0 libgl1 libegl1 libgomp1 libx11-6 xvfb libvulkan1 mesa-vulkan-drivers
OUT     ?= out/demo

.PHONY: demo test bench deps clean

$(VENV)/.installed: pyproject.toml
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing apt packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing >/dev/null; \
	fi
	$(PY) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q -e '.[test]'
	touch $@

deps: $(VENV)/.installed

demo: deps
	$(VENV)/bin/photoar demo --out $(OUT)

test: deps
	$(VPY) -m pytest -q tests

bench: deps
	$(VPY) bench/bench_engine.py

clean:
	rm -rf $(VENV) out .pytest_cache
