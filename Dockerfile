# One image for every role of the swarm: `fxswarm router|world|leader|agent|logger ...`, for
# development. Deployments use one slim image per role: agents/, world/, leader/ and logger/
# each hold their Dockerfile (docker/build-images.sh builds them; docs/deploy.md).
#
#   docker build -t fxswarm .                                              # base from a registry
#   docker/build-base-image.sh && \
#   docker build --build-arg BASE_IMAGE=fxswarm-base-logger:bookworm -t fxswarm .  # no registry at all
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
# The roles live at the top level, installed as fxswarm.<role> (pyproject.toml package-dir).
COPY agents ./agents
COPY leader ./leader
COPY world ./world
COPY logger ./logger
RUN pip install --quiet --no-cache-dir ".[logger]" && rm -rf build fxswarm.egg-info agents leader world logger
COPY configs ./configs
COPY docker/entrypoint.sh /usr/local/bin/fxswarm-entrypoint

# Every role runs as an unprivileged user (uid/gid 10001, no login, no home of its own): a
# process broken into gets no root in its container. A mounted ./runs must be writable by it,
# and in secure mode the key files (compose secrets, mode 0600) readable: chown them to
# 10001, or run as their owner (compose: FXSWARM_UID/FXSWARM_GID; docs/security.md).
RUN groupadd --system --gid 10001 fxswarm \
 && useradd --system --uid 10001 --gid 10001 --home-dir /app --no-create-home --shell /usr/sbin/nologin fxswarm \
 && mkdir -p /app/runs && chown 10001:10001 /app/runs
USER 10001:10001

# Runs (summary.json, trajectory.npz, recording.rrd) go to /app/runs: mount a folder there.
VOLUME ["/app/runs"]
# `fxswarm "$@"` (faults arrive resolved, in FXSWARM_FAULT_PLAN: see docs/fault-plan.md).
ENTRYPOINT ["fxswarm-entrypoint"]
CMD ["--help"]
