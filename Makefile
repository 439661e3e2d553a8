# Everything starts here: `make test` and `make run` set the machine up themselves.
PY := .venv/bin/python
SCENE ?= scenes/paper_plane.xml
OUT ?= out

.PHONY: setup test run paper bench clean

setup:
	@bash tools/setup.sh

test: setup
	$(PY) -m pytest

run: setup
	$(PY) -m eval run $(SCENE) --out $(OUT)/run

paper: setup
	$(PY) -m eval paper --out $(OUT)/paper

bench: setup
	$(PY) -m eval bench

clean:
	rm -rf $(OUT) .pytest_cache
