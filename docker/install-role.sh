#!/bin/sh
# Install fxswarm into /opt/venv for one role's image, and only that role (used by the role
# Dockerfiles: agents/, world/, leader/, logger/), in two steps:
#
#   install-role.sh --user                  the venv (if the base has none), the user, /app/runs
#   install-role.sh ROLE [EXTRAS]           e.g.  install-role.sh agents   install-role.sh logger logger
#
# --user needs nothing of the source, so its layer stays cached across code changes: it makes the
# unprivileged user `fxswarm` (uid/gid 10001) that runs the containers and the run folder it owns.
# ROLE installs from /tmp/src, holding pyproject.toml, README.md, the source folders and configs/.
# The wheel is built from the whole tree (setuptools maps every role folder), installed with the
# EXTRAS' dependencies (already in the local base images, so no index is asked there), then the
# role packages and runners this image never runs are removed: `fxswarm` lists only the commands
# whose module is installed, and the layers contract (pyproject.toml) guarantees a role imports no
# other role nor a runner. The router and `fxswarm health` live in fxswarm.runtime and stay in
# every image. The configs go to /app/configs; the source goes.
set -eu
if [ "$1" = --user ]; then
    [ -x /opt/venv/bin/python ] || python3 -m venv /opt/venv
    getent group fxswarm >/dev/null || groupadd --system --gid 10001 fxswarm
    getent passwd fxswarm >/dev/null ||
        useradd --system --uid 10001 --gid fxswarm --home-dir /app --no-create-home --shell /usr/sbin/nologin fxswarm
    mkdir -p /app/runs
    chown fxswarm:fxswarm /app /app/runs
    exit 0
fi
role="$1"
extras="${2:-}"
cd /tmp/src
pip wheel --quiet --no-cache-dir --no-deps --wheel-dir /tmp/dist .
pip install --quiet --no-cache-dir "$(ls /tmp/dist/fxswarm-*.whl)$( [ -z "$extras" ] || echo "[$extras]")"
site="$(python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
for pkg in agents world leader logger launch report study; do
    [ "$pkg" = "$role" ] || rm -rf "$site/fxswarm/$pkg"
done
rm -f "$site/fxswarm/testing.py"
find "$site/fxswarm" -name __pycache__ -type d -prune -exec rm -rf {} +
# Byte code for what is left, made here: the images set PYTHONDONTWRITEBYTECODE, so without it
# every container start compiles the package from source again (a quarter of its import CPU).
python -m compileall -q "$site/fxswarm"
mv /tmp/src/configs /app/configs
cd /
rm -rf /tmp/src /tmp/dist /root/.cache
