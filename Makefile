# Two commands on a fresh machine with python3 and make:  make demo  /  make test
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
PIP    := $(BIN)/python -m pip
PLUGINS := $(wildcard plugins/*/pyproject.toml)
STAMP  := $(VENV)/.installed
# Debian packages the tests use: Mesa's EGL/llvmpipe (moderngl backend), POV-Ray (oracle),
# Debian's pocl (an OpenCL platform that builds kernels on any x86-64 CPU: pip's
# pocl-binary-distribution cannot on some, e.g. AMD Zen 5; pyopencl's wheel brings the ICD
# loader, so ocl-icd-libopencl1 is not needed),
# Chromium (the studio's browser tests, driven by playwright with executable_path; no browser download),
# blender-data (CC0 HDR environments for the ProbeLight probes).
APT_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 povray pocl-opencl-icd chromium blender-data

.PHONY: demo test bench complexity sysdeps clean lock wheel-check mutate mutate-nodes vendor-studio
demo: $(STAMP)
	$(BIN)/graphkit run graphs/face_relight.yaml --out out
	@echo "results in out/ (open out/portraits.png: the photo relit; out/contact_sheet.png: the close-ups)"

test: $(STAMP) sysdeps
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q tests

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

# Every function in graphkit/ by cyclomatic complexity (radon) and length, those over the
# limits of tests/test_complexity.py flagged.
complexity: $(STAMP)
	$(BIN)/python tests/test_complexity.py

# Mutation testing of graphkit's key, hashing and store code ([tool.mutmut] in pyproject.toml
# lists the modules and the tests that guard them).  Slow; not part of `make test`.
mutate: $(STAMP)
	$(PIP) install -q --disable-pip-version-check -c constraints.txt -e '.[mutate]'
	rm -rf mutants
	$(BIN)/mutmut run --max-children 2 || true
	$(BIN)/mutmut results

# Mutation testing of the node maths (tests/mutate/nodes_mutmut.toml: nodes/common, KM, ratio,
# histogram matching), in a copy of the checkout so its [tool.mutmut] list stays apart from the
# engine's.  Slow (hours for every module); MUTANTS='nodes.huang.km.x_stack*' runs a subset.
MUTATE_DIR ?= /tmp/relightkit-mutate-nodes
mutate-nodes: $(STAMP)
	$(PIP) install -q --disable-pip-version-check -c constraints.txt mutmut==3.8.1
	rm -rf $(MUTATE_DIR) && mkdir -p $(MUTATE_DIR)
	git ls-files -z | xargs -0 cp --parents -t $(MUTATE_DIR)
	$(BIN)/python -c "import re,sys; p=sys.argv[1]+'/pyproject.toml'; s=open(p).read(); s=re.sub(r'(?ms)^\[tool\.mutmut\].*?(?=^\[|\Z)', '', s); open(p,'w').write(s+'\n'+open('tests/mutate/nodes_mutmut.toml').read())" $(MUTATE_DIR)
	cd $(MUTATE_DIR) && ($(abspath $(BIN))/mutmut run --max-children 2 $(MUTANTS) || true) && $(abspath $(BIN))/mutmut results

# The wheels built from this checkout, installed into a fresh venv outside it, run every graph
# in graphs/ whole (make test runs the same check with the slowest graphs cut to cheap outputs).
wheel-check: $(STAMP)
	GRAPHKIT_WHEEL_FULL=1 $(BIN)/python -m pytest -q tests/test_install.py

$(STAMP): pyproject.toml constraints.txt $(PLUGINS)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --disable-pip-version-check --upgrade pip
	$(PIP) install -q --disable-pip-version-check -c constraints.txt -e '.[test,dask,gl,studio]' $(foreach p,$(PLUGINS),-e $(dir $(p)))
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

# Refresh the studio's vendored node editor (litegraph) and layout (elkjs) from the npm registry,
# checked against graphkit/studio/static/vendor/SHA256SUMS (UPDATE=1 after a version change).
vendor-studio:
	sh tools/vendor_studio.sh

# Re-pin constraints.txt from the current environment (after changing dependencies).
lock: $(STAMP)
	$(PIP) freeze --exclude-editable | grep -v -i -E '^(relightkit|graphkit)' > constraints.txt

clean:
	rm -rf $(VENV) out .graphkit-cache mutants
