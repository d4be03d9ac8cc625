# One image for every coplane Python service (vehicle agent, fusion server, API).
FROM python:3.11-slim
WORKDIR /app
ENV PIP_NO_CACHE_DIR=1 PYTHONUNBUFFERED=1
# jemalloc for every service: GTSAM's many small allocations cost the fusion server about a quarter
# more CPU on glibc's malloc (coplane/allocator.py, docs/performance-scale.md "Memory allocator")
RUN apt-get update && apt-get install -y --no-install-recommends libjemalloc2 && rm -rf /var/lib/apt/lists/*
ENV LD_PRELOAD=libjemalloc.so.2
COPY pyproject.toml README.md ./
COPY shared shared
COPY services services
RUN pip install .
# the bundled recording ships inside the package data (shared/coplane/data/recordings/default)
# the services' solution logs (COPLANE_STATE_DIR): a named volume mounted here starts as a copy of
# this empty folder, owned by the services' user
RUN mkdir -p /state && chown 65534:65534 /state
ENV COPLANE_STATE_DIR=/state
USER nobody
