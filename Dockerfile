# One image for every role of the swarm: `fxswarm router|world|leader|agent|logger ...`.
#
#   docker build -t fxswarm .                                              # base from a registry
#   docker/build-base-image.sh && \
#   docker build --build-arg BASE_IMAGE=fxswarm-base:bookworm -t fxswarm .  # no registry at all
#
# BASE_IMAGE is any Debian-like image with Python 3.11. The local one made by
# docker/build-base-image.sh already holds the dependencies in /opt/venv and sets
# PIP_NO_INDEX/PIP_FIND_LINKS, so the install below runs offline on it.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1
RUN [ -x /opt/venv/bin/python ] || python3 -m venv /opt/venv

# Metadata first, the package after: editing code does not invalidate the dependency layer.
WORKDIR /app
COPY pyproject.toml README.md ./
COPY fxswarm ./fxswarm
RUN pip install --quiet --no-cache-dir . && rm -rf build fxswarm.egg-info
COPY configs ./configs
COPY docker/entrypoint.sh /usr/local/bin/fxswarm-entrypoint

# Runs (summary.json, trajectory.npz, recording.rrd) go to /app/runs: mount a folder there.
VOLUME ["/app/runs"]
# `fxswarm "$@"`, with the fault specs of $FXSWARM_FAULTS added to role commands.
ENTRYPOINT ["fxswarm-entrypoint"]
CMD ["--help"]
