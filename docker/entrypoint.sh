#!/bin/sh
# The image's entry point: `fxswarm "$@"`, plus the fault overrides of $FXSWARM_FAULTS.
#
# FXSWARM_FAULTS holds fault specs separated by ';', each as `--fault` takes it, e.g.
#   FXSWARM_FAULTS='agent:*->agent:4 loss=0.2; partition 5-8 isolate=3'
# Every role process (world, leader, agent, logger) must get the same plan (each filters
# its own inbox by it), so compose hands the variable to all of them and this turns it
# into one `--fault SPEC` per spec. Other commands (router, health, sim, ...) run as given.
set -eu
case "${1:-}" in
    world|leader|agent|logger)
        if [ -n "${FXSWARM_FAULTS:-}" ]; then
            set -f  # a spec such as agent:*->agent:4 is not a file pattern
            old_ifs=$IFS
            IFS=';'
            specs=$FXSWARM_FAULTS
            for spec in $specs; do
                IFS=$old_ifs
                case "$spec" in *[!\ \	]*) set -- "$@" --fault "$spec" ;; esac  # skip blank specs
                IFS=';'
            done
            IFS=$old_ifs
        fi
        ;;
esac
exec fxswarm "$@"
