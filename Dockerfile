# CMRT service image (API and workers): Debian bookworm, Debian's python3-pyode, project in a venv.
FROM debian:bookworm-slim

ENV DEBIAN_FRONTEND=noninteractive PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 NUMBA_CACHE_DIR=/tmp/numba-cache
RUN apt-get update \
 && apt-get install -y --no-install-recommends python3 python3-venv python3-pyode ca-certificates \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md ./
COPY cmrt ./cmrt
COPY sim ./sim
COPY optim ./optim
COPY store ./store
COPY worker ./worker
COPY service ./service
COPY examples ./examples

# As scripts/setup.sh: a venv with the project, and only Debian's `ode` extension module made
# visible in it (through a folder holding a link to it, named in a .pth file).
RUN python3 -m venv /opt/venv \
 && /opt/venv/bin/pip install --upgrade pip \
 && /opt/venv/bin/pip install . \
 && mkdir -p /opt/venv/pyode \
 && ln -s "$(ls /usr/lib/python3/dist-packages/ode.cpython-311-*.so | head -1)" /opt/venv/pyode/ \
 && echo /opt/venv/pyode > "$(/opt/venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/pyode.pth" \
 && /opt/venv/bin/python -c "import ode, sim, optim, store, worker, service"

ENV PATH=/opt/venv/bin:$PATH
RUN useradd --system --create-home cmrt && mkdir -p /data && chown cmrt /data
USER cmrt
ENV CMRT_DATA_DIR=/data
EXPOSE 8000
CMD ["python", "-m", "service", "--host", "0.0.0.0", "--port", "8000"]
