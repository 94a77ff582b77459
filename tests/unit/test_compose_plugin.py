"""Installing Compose v2 as a CLI plugin: a copy that stands alone, written atomically."""

import os

import pytest

from espdock.errors import EngineUnavailable
from espdock.images.bootstrap import _install_plugin


def test_the_plugin_is_an_executable_copy_that_outlives_its_source(tmp_path):
    binary = tmp_path / "venv" / "docker-compose"
    binary.parent.mkdir()
    binary.write_bytes(b"#!/bin/sh\necho compose\n")
    binary.chmod(0o600)
    plugin = tmp_path / "cli-plugins" / "docker-compose"
    _install_plugin(binary, plugin, lambda text: None)
    binary.unlink()
    assert not plugin.is_symlink()
    assert plugin.read_bytes() == b"#!/bin/sh\necho compose\n"
    assert plugin.stat().st_mode & 0o777 == 0o755
    assert os.listdir(plugin.parent) == ["docker-compose"]


def test_an_unreadable_binary_is_a_clear_error_and_leaves_nothing(tmp_path):
    plugin = tmp_path / "cli-plugins" / "docker-compose"
    with pytest.raises(EngineUnavailable) as err:
        _install_plugin(tmp_path / "missing" / "docker-compose", plugin, lambda text: None)
    assert str(plugin) in err.value.message and err.value.hint
    assert os.listdir(plugin.parent) == []
