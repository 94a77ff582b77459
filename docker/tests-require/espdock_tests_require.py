"""setup()'s `tests_require` keyword, kept for colcon's pytest step (see pyproject.toml)."""

from distutils.errors import DistutilsSetupError


def check(dist, attr, value):
    """Accept a list of requirement strings, as setuptools did before version 72."""
    if isinstance(value, str) or not all(isinstance(item, str) for item in value):
        raise DistutilsSetupError(f"{attr!r} must be a list of requirement strings (got {value!r})")
