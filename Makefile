.PHONY: setup setup-test run test test-compose docker-engine images lint bench services

VENV := .venv
PY := $(VENV)/bin/python

# `make run` installs what the main job needs; `make test` adds the test extras and Chromium.
setup:
	@bash scripts/setup.sh

setup-test:
	@bash scripts/setup.sh --test

services:
	@bash scripts/services.sh

run: setup
	$(VENV)/bin/cmrt optimize examples/fast_bend.yaml --workers 2 --seed 1 --out results/fast_bend.json

test: setup-test services
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q

# The deployed topology on a Docker engine: the engine (installed and started if missing), the
# images built offline from Debian's packages and a wheelhouse (cached by content), then the
# topology tests and the README's docker lines with `docker compose` (or docker-compose v1).
# Official images instead: make test-compose CMRT_BASE_IMAGE=debian:bookworm-slim \
#   CMRT_REDIS_IMAGE=redis:7-bookworm CMRT_POSTGRES_IMAGE=postgres:16-bookworm
CMRT_BASE_IMAGE ?= cmrt-base:bookworm
CMRT_REDIS_IMAGE ?= cmrt-redis:bookworm
CMRT_POSTGRES_IMAGE ?= cmrt-postgres:bookworm
COMPOSE_ENV = CMRT_IT_MODE=compose CMRT_BASE_IMAGE=$(CMRT_BASE_IMAGE) \
	CMRT_REDIS_IMAGE=$(CMRT_REDIS_IMAGE) CMRT_POSTGRES_IMAGE=$(CMRT_POSTGRES_IMAGE)

docker-engine:
	@bash scripts/docker-engine.sh

images: setup-test docker-engine
	@bash scripts/docker-images.sh

OFFLINE_IMAGES = $(filter cmrt-%,$(CMRT_BASE_IMAGE) $(CMRT_REDIS_IMAGE) $(CMRT_POSTGRES_IMAGE))

test-compose: $(if $(OFFLINE_IMAGES),images,setup-test docker-engine)
	$(COMPOSE_ENV) $(PY) -m pytest -q tests/integration/test_topology.py \
		tests/integration/test_compose.py tests/cli/test_readme.py::test_docker_block

lint: setup-test
	$(VENV)/bin/ruff check .

bench: setup
	$(VENV)/bin/cmrt bench
