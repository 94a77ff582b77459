#!/bin/sh
# Installs what the workspace's rosdep lock (rosdep.lock.json) names, as espdock stages it in
# DIR: apt.txt (Debian/Ubuntu packages, one a line) and pip.txt (pinned, with hashes). Both
# are empty when the workspace needs nothing beyond the image.
#   rosdep-install.sh DIR PYTHON [PIP_OPTION...]
# The extra CA bundle (BuildKit secret ca_bundle) reaches pip; it never lands in a layer.
set -eu
dir=$1
python=$2
shift 2
apt_packages=$(grep -v '^#' "$dir/apt.txt" || true)
pip_wanted=$(grep -v '^#' "$dir/pip.txt" || true)
# Only pip speaks TLS here (apt uses Debian's signed http archive). The runtime image has no
# system CA bundle: it never runs pip.
if [ -n "$pip_wanted" ] && [ -s /run/secrets/ca_bundle ]; then
  { cat /etc/ssl/certs/ca-certificates.crt 2>/dev/null || true; cat /run/secrets/ca_bundle; } > /tmp/ca.pem
  export PIP_CERT=/tmp/ca.pem
fi
if [ -n "$pip_wanted" ] && ! "$python" -m pip --version > /dev/null 2>&1; then
  apt_packages="$apt_packages python3-pip"
fi
if [ -n "$apt_packages" ]; then
  apt-get update
  # Word splitting is wanted: one package name per word (espdock checks the names).
  # --no-upgrade: what the image has already (the official image's ros-<distro>-* packages)
  # stays at its version, as the image was released; only what is missing is installed.
  # shellcheck disable=SC2086
  apt-get install -y --no-install-recommends --no-upgrade $apt_packages
  rm -rf /var/lib/apt/lists/*
fi
if [ -n "$pip_wanted" ]; then
  "$python" -m pip install --no-cache-dir --require-hashes "$@" -r "$dir/pip.txt"
fi
rm -f /tmp/ca.pem
