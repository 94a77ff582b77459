#!/usr/bin/env bash
# System packages the tests use beyond the Docker engine (which `espdock setup`
# provides): Debian's Chromium for the browser tests, cmake and g++ for the
# firmware host tests, libzbar0 for pyzbar, the distribution registry and
# htpasswd for the cache registry tests, and the other engines the engine tests
# run (Podman; rootless Docker: rootlesskit, newuidmap, slirp4netns; OpenSSH), and Debian's own colcon
# (a colcon outside any venv, as a user of apt's colcon and a pipx espdock has it; with the
# extensions its `colcon` package recommends, which apt installs by default). Installed only when
# missing, and only where we can (root on Debian); elsewhere the tests that
# need them say what is missing.
set -euo pipefail
missing=()
command -v chromium >/dev/null || missing+=(chromium)
command -v cmake >/dev/null || missing+=(cmake)
command -v g++ >/dev/null || missing+=(g++)
# pyzbar, for the demo's unit tests. ldconfig is in /sbin, on no plain user's PATH on Debian (a
# user's `make setup` said libzbar0 was missing); grep reads all it is given (-q's early exit
# is a SIGPIPE to ldconfig, a failure under pipefail).
PATH="$PATH:/usr/sbin:/sbin" ldconfig -p 2>/dev/null | grep libzbar.so.0 >/dev/null || missing+=(libzbar0)
command -v docker-registry >/dev/null || missing+=(docker-registry)
command -v htpasswd >/dev/null || missing+=(apache2-utils)
command -v podman >/dev/null || missing+=(podman)
command -v rootlesskit >/dev/null || missing+=(rootlesskit)
command -v newuidmap >/dev/null || missing+=(uidmap)
command -v slirp4netns >/dev/null || missing+=(slirp4netns)
# An ssh:// engine (tests/integration/test_ssh_engine.py runs an sshd of its own on a loopback
# port). Where systemd runs, Debian's package also enables and starts its ssh service.
[ -x /usr/sbin/sshd ] || missing+=(openssh-server)
command -v ssh >/dev/null || missing+=(openssh-client)
[ -x /usr/bin/colcon ] || missing+=(colcon python3-colcon-ros python3-colcon-recursive-crawl
  python3-colcon-package-selection python3-colcon-parallel-executor python3-colcon-output
  python3-colcon-defaults python3-colcon-bash python3-colcon-library-path python3-colcon-metadata
  python3-colcon-package-information)
if [ ${#missing[@]} -eq 0 ]; then exit 0; fi
if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null; then
  echo "missing system packages: ${missing[*]} (install them, or run as root on Debian)" >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -q
apt-get install -y -q --no-install-recommends "${missing[@]}"
