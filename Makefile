PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

# test workers: one per CPU, at most 4 (idle workers take queued tests from busy ones)
WORKERS ?= $(shell $(PY) -c "import os; print(min(4, os.cpu_count() or 1))")

.PHONY: install train test test-quick lint bench clean

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q -c constraints.txt -e '.[dev]'
	# build the fused LIF kernel now (falls back to pure torch if the machine cannot compile)
	$(BIN)/python -c "from tactilesnn.models._lif_kernel import kernel; print('fused LIF kernel:', 'built' if kernel() else 'unavailable, using pure torch')"
	touch $(STAMP)

install: $(STAMP)

# Main job: default embedded task (hook vs loop), GWT -> latency -> tempotron, prints test accuracy.
train: $(STAMP)
	$(BIN)/tactilesnn train

test: $(STAMP)
	$(BIN)/ruff check tactilesnn tests train.py
	$(BIN)/ruff format --check tactilesnn tests train.py
	$(BIN)/pytest -n $(WORKERS) --dist worksteal --durations=15

# the suite without the slow, browser, real-data and GPU tests (4 min 47 s on 2 CPUs, 2026-11-28)
test-quick: $(STAMP)
	$(BIN)/ruff check tactilesnn tests train.py
	$(BIN)/pytest -n $(WORKERS) --dist worksteal -m "not slow and not browser and not data and not gpu"

# the benchmark peers (snnTorch, Norse, SpikingJelly, ssqueezepy, fCWT); fCWT loads Debian's
# libfftw3-single3 (apt-get install libfftw3-single3)
$(VENV)/.bench: $(STAMP)
	$(BIN)/pip install -q -c constraints.txt -e '.[dev,bench]'
	touch $(VENV)/.bench

bench: $(VENV)/.bench
	$(BIN)/tactilesnn bench snn --out bench_out/snn
	$(BIN)/tactilesnn bench encoders --out bench_out/encoders
	$(BIN)/tactilesnn bench pareto --out bench_out/pareto --overwrite
	$(BIN)/tactilesnn bench stability --out bench_out/stability --overwrite
	$(BIN)/tactilesnn bench skip --out bench_out/skip --overwrite
	$(BIN)/tactilesnn bench graphs --out bench_out/graphs
	$(BIN)/tactilesnn bench gwt-vs-stft --seeds 5 --out bench_out/gwt_vs_stft --overwrite

clean:
	rm -rf $(VENV) runs bench_out
