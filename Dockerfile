# The track service and its clients (track-service, track-feed, track-display, ...):
#   docker build -t zenoh-track-service .
# docker-compose.yml runs two tracker shards, a feed and a display from this image
# next to the official Zenoh router image (deploy/README.md).
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY service ./service
COPY clients ./clients
RUN pip install . && rm -rf /src
# compile the IMM kernel once into the image (Numba's cache beside the installed
# package): each container starts in half a second instead of compiling for ~10 s
RUN python -c "from service.estimation import imm_jit; imm_jit.warm()"
WORKDIR /
# no default command: each compose service names its console script
CMD ["track-service", "--help"]
