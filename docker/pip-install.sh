#!/bin/sh
# pip-install LOCK: install LOCK (every requirement pinned and hashed) into the venv on PATH.
# The files come from /var/cache/espdock-pip/wheels, a BuildKit cache mount that
# Dockerfile.ros keeps across builds (never in a layer). When every file is there the
# install asks no index at all; else pip downloads what is missing (and only that) and
# installs. --require-hashes checks every file, cached or not. (pip's own HTTP cache is
# no help behind proxies that drop the caching headers.)
# The extra CA bundle, if any, is the BuildKit secret ca_bundle.
set -eu
lock=$1
wheels=/var/cache/espdock-pip/wheels
if [ -s /run/secrets/ca_bundle ]; then
    cat /etc/ssl/certs/ca-certificates.crt /run/secrets/ca_bundle > /tmp/ca.pem
    export PIP_CERT=/tmp/ca.pem
    trap 'rm -f /tmp/ca.pem' EXIT
fi
mkdir -p "$wheels"
install() { python3 -m pip install --require-hashes --no-index --find-links "$wheels" -r "$lock"; }
# pip resolves the whole lock before it installs anything, so a missing file fails
# here with nothing installed.
if ! install 2> /tmp/pip-offline.log; then
    echo "pip-install: not every file of $lock is cached; downloading the missing ones"
    python3 -m pip download --require-hashes -r "$lock" -d "$wheels"
    install
fi
rm -f /tmp/pip-offline.log
