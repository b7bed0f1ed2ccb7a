# Two commands from a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl
export SDL_VIDEODRIVER ?= dummy
export SDL_AUDIODRIVER ?= dummy
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: install demo test lint typecheck bench clean

$(STAMP): pyproject.toml setup.py
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/kinesphere up --headless

test: $(STAMP)
	$(BIN)/ruff check kinesphere services clients robots tests bench
	$(BIN)/mypy --strict kinesphere
	$(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff check kinesphere services clients robots tests bench

typecheck: $(STAMP)
	$(BIN)/mypy --strict kinesphere

bench: $(STAMP)
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
