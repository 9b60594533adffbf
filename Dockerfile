# CMRT service image (API and workers): Debian bookworm, Debian's python3-pyode, project in a venv.
# BASE_IMAGE: the official debian:bookworm-slim, or where no image registry is reachable the
# equivalent that scripts/docker-images.sh makes with debootstrap (CMRT_BASE_IMAGE in
# docker-compose.yml). Python packages come from the package index, or with no network inside
# the build from the wheelhouse that script fills on the host (.wheelhouse/, see below).
ARG BASE_IMAGE=debian:bookworm-slim
FROM ${BASE_IMAGE}

ENV DEBIAN_FRONTEND=noninteractive PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 NUMBA_CACHE_DIR=/tmp/numba-cache
RUN apt-get update \
 && apt-get install -y --no-install-recommends python3 python3-venv python3-pyode ca-certificates \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /app
# The wheelhouse, if any (the glob lets the build go on without one): installs then use it alone.
COPY pyproject.toml .wheelhous[e] /wheelhouse/
COPY pyproject.toml README.md ./
COPY cmrt ./cmrt
COPY cli ./cli
COPY sim ./sim
COPY optim ./optim
COPY store ./store
COPY application ./application
COPY worker ./worker
COPY service ./service
COPY examples ./examples

# As scripts/setup.sh: a venv with the project, and only Debian's `ode` extension module made
# visible in it (through a folder holding a link to it, named in a .pth file).
RUN python3 -m venv /opt/venv \
 && if ls /wheelhouse/*.whl >/dev/null 2>&1; then \
        /opt/venv/bin/pip install --no-index --find-links /wheelhouse . ; \
    else \
        /opt/venv/bin/pip install --upgrade pip && /opt/venv/bin/pip install . ; \
    fi \
 && rm -rf /wheelhouse \
 && mkdir -p /opt/venv/pyode \
 && ln -s "$(ls /usr/lib/python3/dist-packages/ode.cpython-311-*.so | head -1)" /opt/venv/pyode/ \
 && echo /opt/venv/pyode > "$(/opt/venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/pyode.pth" \
 && /opt/venv/bin/python -c "import ode, sim, optim, store, application, worker, service, cli.main"

ENV PATH=/opt/venv/bin:$PATH
RUN useradd --system --create-home cmrt && mkdir -p /data && chown cmrt /data
USER cmrt
ENV CMRT_DATA_DIR=/data
EXPOSE 8000
CMD ["python", "-m", "service", "--host", "0.0.0.0", "--port", "8000"]
