# Everything starts here: `make test` and `make run` set the machine up themselves.
PY := .venv/bin/python
SCENE ?= scenes/paper_plane.xml
OUT ?= out

.PHONY: setup lint test test-fast run paper bench clean

setup:
	@bash tools/setup.sh

lint: setup
	$(PY) -m ruff check .

# the whole suite, the renders included, on two processes (about 8 minutes on 2 cores);
# --dist worksteal: each process takes a contiguous half of the tests and steals from the other
# only at the end, so a module's shared fixtures (renders, drawn photos, calibrations) are mostly
# made once; pytest-xdist's default hands out small batches to whichever process is free, and a
# module split over both made its fixtures twice (eval paper's 13-16 s run, for one)
test: lint
	$(PY) -m pytest -n 2 --dist worksteal

# everything that does not render with Mitsuba (the `slow` marker), on two processes
test-fast: lint
	$(PY) -m pytest -m "not slow" -n 2 --dist worksteal

run: setup
	$(PY) -m eval run $(SCENE) --out $(OUT)/run

paper: setup
	$(PY) -m eval paper --out $(OUT)/paper

bench: setup
	$(PY) -m eval bench

clean:
	rm -rf $(OUT) .pytest_cache
