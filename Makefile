# make run   : set up .venv on first use, then fit + evaluate the built-in procedural scene on PoCL
# make test  : set up .venv on first use, then run the test suite (CPU only)
# make bench : kernel microbenchmarks on PoCL (see bench/README.md)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEVICE ?= pocl
OUT    ?= runs/procedural
# test workers: 2 by default (the CI machine has 2 cores; PoCL's kernels use every core of each)
TEST_JOBS ?= 2

.PHONY: run test bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[data,test,view,cluster]"
	scripts/ensure_pocl.sh $(PY)
	touch $@

# the LPIPS model: REINGS_LPIPS_MODEL if set, else the development layout's ../shared/models (the
# package itself looks only at explicit places: reings.metrics.find_lpips_model)
LPIPS_MODEL ?= $(or $(REINGS_LPIPS_MODEL),$(wildcard ../shared/models/lpips_vgg.onnx))

run: $(VENV)/.installed
	$(if $(LPIPS_MODEL),REINGS_LPIPS_MODEL=$(abspath $(LPIPS_MODEL)) )$(VENV)/bin/reings run --device $(DEVICE) --preset quick --out $(OUT) --overwrite

test: $(VENV)/.installed
	$(PY) -m pytest -q -ra -n $(TEST_JOBS) --dist worksteal

bench: $(VENV)/.installed
	$(VENV)/bin/reings bench --device $(DEVICE)

clean:
	rm -rf $(VENV) runs .pytest_cache
