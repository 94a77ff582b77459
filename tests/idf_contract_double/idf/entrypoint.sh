#!/usr/bin/env bash
# contract double: stands in for the espressif/idf image's /opt/esp/entrypoint.sh, because the
# espressif/idf images cannot be pulled here. Same behaviour: optional git safe.directory
# entries from IDF_GIT_SAFE_DIR, then source export.sh and run the command.
set -e

if [ -n "${IDF_GIT_SAFE_DIR+x}" ]; then
    echo "Adding following directories into git's safe.directory"
    echo "$IDF_GIT_SAFE_DIR" | tr ':' '\n' | while read -r dir; do
        git config --global --add safe.directory "$dir"
        echo "  $dir"
    done
fi

. "$IDF_PATH/export.sh"

exec "$@"
