# Two entry points (README): `make demo` and `make test`. Both create or refresh .venv idempotently.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Rerun and matplotlib write caches/analytics under HOME unless told otherwise.
export RERUN_ANALYTICS := 0
export MPLBACKEND := Agg

.PHONY: venv warm demo test lint bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,ray]'
	$(MAKE) --no-print-directory warm || echo "secure3d: warming the kernels failed; they compile on first use"
	touch $(STAMP)

venv: $(STAMP)

# Compile numba's kernels and the NLP's node kernels (C, if there is a compiler) once into the
# user's cache (~/.cache/secure3d), so that the first plan or flight does not pay for compilation
# (issue 17); a no-op once they are cached.
warm:
	$(PY) -c "from secure3d.warm import warm; print(f'secure3d: kernels ready ({warm():.1f} s)')"

demo: $(STAMP)
	$(PY) -m secure3d demo

# The suite pins numpy's SIMD kernels to the x86-64-v3 (AVX2) level: its AVX-512 sin, cos, exp
# and sorts give other last bits, which the diff-drive NLP and the closed loop amplify into other
# plans (the golden planar plan moved 2e-6 relative; warehouse_survey reached its goal at 21.3 s
# instead of 9.09 s). Elsewhere (and on CPUs without AVX-512) the variable changes nothing.
# `import secure3d` sets it too (secure3d/_numpy_kernels.py), but pytest imports numpy first.
test: export NPY_DISABLE_CPU_FEATURES := X86_V4 AVX512_ICL AVX512_SPR
# The suite runs on every core (pytest-xdist); `make test PYTEST_WORKERS=0` runs it in one process.
PYTEST_WORKERS ?= auto
test: $(STAMP)
	$(PY) -m pytest -q -n $(PYTEST_WORKERS)

lint: $(STAMP)
	$(PY) -m ruff check secure3d tests benchmarks examples

bench: $(STAMP)
	$(PY) benchmarks/bench_mapping.py
	$(PY) benchmarks/bench_planner.py --reps 2 --solvers ipopt
	$(PY) benchmarks/bench_closed_loop.py --reps 3
	$(PY) benchmarks/bench_planner.py
	$(PY) benchmarks/bench_closed_loop.py

clean:
	rm -rf $(VENV) build *.egg-info
