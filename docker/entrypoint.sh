#!/bin/sh
# The image's entry point: `fxswarm "$@"`. Faults arrive resolved: `fxswarm compose`, `stack` and
# `k8s` write the run's one plan into every service's environment as FXSWARM_FAULT_PLAN, which
# every role process reads.
#
# FXSWARM_ID, for `agent`, adds `--id $FXSWARM_ID`: an orchestrator that scales one agent service
# templates the environment, never the command (Swarm: FXSWARM_ID={{.Task.Slot}}; Kubernetes: the
# StatefulSet pod's ordinal, FXSWARM_ID_FROM_HOSTNAME=1 takes it from the pod name's last
# number plus 1, since ordinals start at 0 and robot ids at 1).
#
# Secure mode with one scaled agent service: every replica gets the same secrets, so
# FXSWARM_AGENT_KEYS names a folder holding every robot's pair. This robot's pair and ca.pem are
# copied from it into $FXSWARM_SECURE (a tmpfs), where `fxswarm agent` finds them:
#   - Swarm: the task starts as root (the secrets are root's, mode 0400), copies, and with
#     FXSWARM_RUN_AS=UID:GID drops to that user, no capabilities, no new privileges, before
#     fxswarm starts: the robot's process cannot read the other robots' keys.
#   - Kubernetes: an init container runs `take-agent-key` (copy, then exit) with the Secret
#     mounted; the agent container mounts only the copy.
set -eu

say() { echo "fxswarm-entrypoint: $*" >&2; }

if [ -n "${FXSWARM_ID_FROM_HOSTNAME:-}" ]; then
    ordinal="${HOSTNAME##*-}"
    FXSWARM_ID=$((ordinal + 1))
fi

take_agent_key() {
    : "${FXSWARM_ID:?fxswarm-entrypoint: FXSWARM_ID (the robot id) is unset: whose key to take?}"
    : "${FXSWARM_SECURE:?fxswarm-entrypoint: FXSWARM_SECURE (where to put the robot key) is unset}"
    owner=""
    if [ "$(id -u)" = 0 ] && [ -n "${FXSWARM_RUN_AS:-}" ]; then
        owner="$FXSWARM_RUN_AS"
    fi
    mkdir -p "$FXSWARM_SECURE"
    if [ -n "$owner" ]; then
        chown "$owner" "$FXSWARM_SECURE"
        chmod 0700 "$FXSWARM_SECURE"
    fi
    for name in ca.pem "agent-$FXSWARM_ID.pem" "agent-$FXSWARM_ID.key"; do
        if [ ! -r "$FXSWARM_AGENT_KEYS/$name" ]; then
            say "$FXSWARM_AGENT_KEYS/$name: missing or unreadable (robot $FXSWARM_ID's key; fxswarm keys makes them)"
            exit 2
        fi
        rm -f "$FXSWARM_SECURE/$name"  # a copy of an earlier start is mode 0400: not writable
        cp "$FXSWARM_AGENT_KEYS/$name" "$FXSWARM_SECURE/$name"
        chmod 0400 "$FXSWARM_SECURE/$name"
        if [ -n "$owner" ]; then chown "$owner" "$FXSWARM_SECURE/$name"; fi
    done
}

if [ "${1:-}" = take-agent-key ]; then
    : "${FXSWARM_AGENT_KEYS:?fxswarm-entrypoint: FXSWARM_AGENT_KEYS (the folder of every robot key) is unset}"
    take_agent_key
    exit 0
fi
if [ "${1:-}" = agent ]; then
    if [ -n "${FXSWARM_AGENT_KEYS:-}" ]; then
        take_agent_key
    fi
    if [ -n "${FXSWARM_ID:-}" ]; then
        set -- "$@" --id "$FXSWARM_ID"
    fi
fi
if [ "$(id -u)" = 0 ] && [ -n "${FXSWARM_RUN_AS:-}" ]; then
    exec setpriv --reuid="${FXSWARM_RUN_AS%%:*}" --regid="${FXSWARM_RUN_AS#*:}" --clear-groups \
        --inh-caps=-all --bounding-set=-all --no-new-privs fxswarm "$@"
fi
exec fxswarm "$@"
