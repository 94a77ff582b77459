"""Which PyPI project serves a rosdep key whose rule installs an apt `python3-*` package, for
the wheels image's venv (which cannot import apt's Python packages).

A key's own pip rules (rosdistro's pip rule for another platform, or its `-pip` sibling key)
come first (espdock.ros.rosdeps); this table is for the common keys that have none. Each entry was
checked against rosdistro's rosdep/python.yaml (the key and its Debian package) and PyPI (the
project, its import name and wheels). A key in neither is refused, naming it: a same-named
PyPI project is too often a stranger (PyPI's `serial` is a serialization framework, its `jwt`
and `usb` are not the modules Debian's python3-jwt and python3-usb install).
"""

from __future__ import annotations

# rosdep key -> PyPI project installing the module Debian's package of that key installs.
PYPI_PROJECT = {
    "python3-cryptography": "cryptography",
    "python3-can": "python-can",
    "python3-click": "click",
    "python3-defusedxml": "defusedxml",
    "python3-docker": "docker",
    # ament_flake8's docstring checks (its package.xml's exec_depend).
    "python3-flake8-docstrings": "flake8-docstrings",
    "python3-flask": "Flask",
    "python3-gnupg": "python-gnupg",
    "python3-jinja2": "Jinja2",
    "python3-jwt": "PyJWT",
    "python3-msgpack": "msgpack",
    "python3-networkx": "networkx",
    "python3-numpy": "numpy",
    # The images have no display: the headless build of the same cv2 module.
    "python3-opencv": "opencv-python-headless",
    "python3-packaging": "packaging",
    "python3-pandas": "pandas",
    "python3-paramiko": "paramiko",
    "python3-pexpect": "pexpect",
    "python3-pyproj": "pyproj",
    "python3-pyudev": "pyudev",
    "python3-requests": "requests",
    "python3-serial": "pyserial",
    # pkg_resources, which older nodes import, is setuptools' (Debian's package installs both).
    "python3-setuptools": "setuptools",
    "python3-simplejson": "simplejson",
    "python3-sympy": "sympy",
    "python3-tabulate": "tabulate",
    "python3-termcolor": "termcolor",
    "python3-toml": "toml",
    "python3-usb": "pyusb",
    "python3-websocket": "websocket-client",
    "python3-websockets": "websockets",
    "python3-xmltodict": "xmltodict",
    "python3-zmq": "pyzmq",
}

# Debian packages not named python3-* that are the Python module a key names (the venv cannot
# import them either): ament_pep257 imports pydocstyle (its exec_depend, Debian's `pydocstyle`).
APT_PYTHON = frozenset({"pydocstyle"})

# Debian packages named python3-* that are no Python module, kept as apt packages in the
# wheels image: the venv's Python is Debian's python3 (Dockerfile.ros), so its headers serve.
APT_KEPT = frozenset({"python3-dev"})

# Keys refused with a reason of their own, beyond "no reviewed PyPI project".
REFUSED = {
    "python3-gi": "PyGObject binds the system's GObject libraries; PyPI has only its source, which needs "
    "gobject-introspection's headers to build, and the venv cannot import apt's python3-gi",
}


def refusal(key: str) -> str:
    """Why the wheels venv has no PyPI project for KEY."""
    reason = REFUSED.get(key, "its rosdep rule installs apt's Python package, which the venv cannot import")
    return (
        f"{reason}, and espdock knows no reviewed PyPI project for it (a same-named one may be another "
        "project): give the key a pip rule in a rosdep source, or use the official image"
    )
