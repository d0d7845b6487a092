#!/usr/bin/env bash
# Build the role images offline (no registry), on the local bases of build-base-image.sh:
#
#   docker/build-images.sh               # fxswarm-agent, fxswarm-world, fxswarm-leader, fxswarm-logger :latest
#   FXSWARM_TAG=test docker/build-images.sh
#
# The router runs from the world image (see world/Dockerfile). Prints each image's size.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
tag="${FXSWARM_TAG:-latest}"
"$repo/docker/build-base-image.sh"
for pair in agent:agents world:world leader:leader logger:logger; do
    image="fxswarm-${pair%%:*}:$tag"
    old="$(docker image inspect -f '{{.Id}}' "$image" 2>/dev/null || true)"
    docker build --quiet -f "$repo/${pair#*:}/Dockerfile" -t "$image" "$repo" >/dev/null
    new="$(docker image inspect -f '{{.Id}}' "$image")"
    # The image this build replaced would linger untagged: remove it if nothing uses it.
    [[ -z "$old" || "$old" == "$new" ]] || docker rmi "$old" >/dev/null 2>&1 || true
    echo "$image $(docker image inspect -f '{{.Size}}' "$image" | awk '{printf "%.0f MB", $1 / 1e6}')"
done
