#!/bin/sh
# with-ca.sh COMMAND [ARG...]: run COMMAND trusting the extra CA bundle as well as the
# system's, for everything in the IDF world that goes over HTTPS: git (the micro-ROS
# checkouts, libmicroros.mk's clones), pip, and the IDF component manager (Python
# requests). The bundle is a BuildKit secret in image builds (/run/secrets/ca_bundle) or a
# read-only mount named by ESPDOCK_EXTRA_CA in build containers; the combined copy lives
# in a private temporary file that is removed afterwards, so no layer or artefact holds it.
set -eu
extra="${ESPDOCK_EXTRA_CA:-/run/secrets/ca_bundle}"
if [ ! -s "$extra" ]; then
    exec "$@"
fi
combined=$(mktemp "${TMPDIR:-/tmp}/espdock-ca.XXXXXX")
trap 'rm -f "$combined"' EXIT
trap 'exit 130' INT TERM
cat /etc/ssl/certs/ca-certificates.crt "$extra" > "$combined" 2>/dev/null || cat "$extra" > "$combined"
export GIT_SSL_CAINFO="$combined" PIP_CERT="$combined" REQUESTS_CA_BUNDLE="$combined"
"$@"
