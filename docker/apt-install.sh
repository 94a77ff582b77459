#!/bin/sh
# apt-install PKG...: `apt-get install --no-install-recommends` after an update, with the
# package lists and .deb files in the BuildKit cache mount at /var/cache/espdock-apt
# (Dockerfile.ros mounts it and this script; neither lands in a layer). A rebuilt stage
# then fetches only what changed upstream instead of every package again.
set -eu
cache=/var/cache/espdock-apt
mkdir -p "$cache/archives/partial" "$cache/lists/partial"
apt-get -o Dir::State::Lists="$cache/lists" update
apt-get -o Dir::State::Lists="$cache/lists" -o Dir::Cache::Archives="$cache/archives" \
    install -y --no-install-recommends "$@"
