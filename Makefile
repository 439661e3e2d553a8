# Everything starts here: `make test` and `make run` set the machine up themselves.
PY := .venv/bin/python
SCENE ?= scenes/paper_plane.xml
OUT ?= out

.PHONY: setup lint test test-fast run paper bench clean

setup:
	@bash tools/setup.sh

lint: setup
	$(PY) -m ruff check .

# the whole suite, the renders included, on two processes (about 9 minutes on 2 cores)
test: lint
	$(PY) -m pytest -n 2

# everything that does not render with Mitsuba (the `slow` marker), on two processes
test-fast: lint
	$(PY) -m pytest -m "not slow" -n 2

run: setup
	$(PY) -m eval run $(SCENE) --out $(OUT)/run

paper: setup
	$(PY) -m eval paper --out $(OUT)/paper

bench: setup
	$(PY) -m eval bench

clean:
	rm -rf $(OUT) .pytest_cache
