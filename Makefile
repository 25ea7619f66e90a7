# Two commands on a fresh machine with python3 and make:  make demo  /  make test
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
PIP    := $(BIN)/python -m pip
PLUGINS := $(wildcard plugins/*/pyproject.toml)
STAMP  := $(VENV)/.installed
# Debian packages the tests use: Mesa's EGL/llvmpipe (moderngl backend), POV-Ray (oracle).
APT_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 povray

.PHONY: demo test bench sysdeps clean lock mutate
demo: $(STAMP)
	$(BIN)/graphkit run graphs/face_relight.yaml --out out
	@echo "results in out/ (open out/contact_sheet.png)"

test: $(STAMP) sysdeps
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q tests

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

# Mutation testing of graphkit's key, hashing and store code ([tool.mutmut] in pyproject.toml
# lists the modules and the tests that guard them).  Slow; not part of `make test`.
mutate: $(STAMP)
	$(PIP) install -q --disable-pip-version-check -c constraints.txt -e '.[mutate]'
	rm -rf mutants
	$(BIN)/mutmut run --max-children 2 || true
	$(BIN)/mutmut results

$(STAMP): pyproject.toml constraints.txt $(PLUGINS)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --disable-pip-version-check --upgrade pip
	$(PIP) install -q --disable-pip-version-check -c constraints.txt -e '.[test,dask,gl]' $(foreach p,$(PLUGINS),-e $(dir $(p)))
	$(if $(wildcard plugins/graphkit-mediapipe),$(PIP) install -q --disable-pip-version-check --no-deps -c constraints.txt mediapipe==0.10.14)
	$(BIN)/graphkit schema -o graph.schema.json   # editors: `# yaml-language-server: $$schema=../graph.schema.json`
	touch $@

# Installs the Debian packages some tests need when they are missing (root or sudo).
sysdeps:
	@missing=""; for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

# Re-pin constraints.txt from the current environment (after changing dependencies).
lock: $(STAMP)
	$(PIP) freeze --exclude-editable | grep -v -i -E '^(relightkit|graphkit)' > constraints.txt

clean:
	rm -rf $(VENV) out .graphkit-cache mutants
