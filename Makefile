.PHONY: setup run test lint bench services

VENV := .venv
PY := $(VENV)/bin/python

setup:
	@bash scripts/setup.sh

services:
	@bash scripts/services.sh

run: setup
	$(VENV)/bin/cmrt optimize examples/fast_bend.yaml --workers 2 --seed 1 --out results/fast_bend.json

test: setup services
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q

lint: setup
	$(VENV)/bin/ruff check .

bench: setup
	$(VENV)/bin/cmrt bench
