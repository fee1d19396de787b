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
# compile the kernels once into the image (Numba's cache beside the installed package):
# each container's service takes them within a second instead of compiling them itself
RUN python -m zenoh_track.estimation.jit zenoh_track.estimation.imm_jit zenoh_track.tracking.frame
WORKDIR /
# no default command: each compose service names its console script
CMD ["track-service", "--help"]
