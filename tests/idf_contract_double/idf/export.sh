# contract double: stands in for ESP-IDF v5.3.5's export.sh, because ESP-IDF cannot be fetched
# here. Source it (`. $IDF_PATH/export.sh`): it activates IDF's Python venv and puts
# $IDF_PATH/tools (idf.py) on PATH, as the real one does. POSIX sh, like the real one.
# IDF_EXPORT_QUIET=1 silences the progress lines, as in the real script.

__double_verbose() {
    [ -n "${IDF_EXPORT_QUIET-}" ] && return
    echo "$@"
}

__double_export() {
    if [ -z "${IDF_PATH-}" ]; then
        echo "Could not detect IDF_PATH. Please set it before sourcing this script:"
        echo "  export IDF_PATH=(add path here)"
        return 1
    fi
    if [ ! -f "${IDF_PATH}/tools/idf.py" ]; then
        echo "IDF_PATH is set to '${IDF_PATH}', but it doesn't look like an ESP-IDF directory."
        return 1
    fi
    IDF_TOOLS_PATH="${IDF_TOOLS_PATH:-/opt/esp}"
    export IDF_TOOLS_PATH
    IDF_PYTHON_ENV_PATH="${IDF_TOOLS_PATH}/python_env/idf5.3_py3.11_env"
    if [ ! -x "${IDF_PYTHON_ENV_PATH}/bin/python" ]; then
        echo "ESP-IDF Python virtual environment \"${IDF_PYTHON_ENV_PATH}\" not found."
        return 1
    fi
    export IDF_PYTHON_ENV_PATH
    echo "Activating ESP-IDF 5.3 (espdock contract double)"
    __double_verbose "Setting IDF_PATH to '${IDF_PATH}'."
    __double_verbose "* Checking python version ... $("${IDF_PYTHON_ENV_PATH}/bin/python" -c 'import platform; print(platform.python_version())')"
    VIRTUAL_ENV="${IDF_PYTHON_ENV_PATH}"
    export VIRTUAL_ENV
    case ":${PATH}:" in
        *":${IDF_PATH}/tools:"*) ;;
        *) PATH="${IDF_PATH}/tools:${IDF_PYTHON_ENV_PATH}/bin:${PATH}" ;;
    esac
    export PATH
    ESP_IDF_VERSION="5.3"
    export ESP_IDF_VERSION
    __double_verbose "Added the following directories to PATH:"
    __double_verbose "  ${IDF_PATH}/tools"
    __double_verbose "  ${IDF_PYTHON_ENV_PATH}/bin"
    echo "Done! You can now compile ESP-IDF projects."
    echo "Go to the project directory and run:"
    echo ""
    echo "  idf.py build"
    echo ""
}

__double_export
__double_rc=$?
unset -f __double_verbose __double_export
# shellcheck disable=SC2317  # return when sourced, exit when (wrongly) executed
return $__double_rc 2>/dev/null || exit $__double_rc
