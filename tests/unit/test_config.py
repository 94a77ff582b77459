from pathlib import Path

import pytest

from espdock.config import Config, check_target, in_ci, load_config, pip_configured_cert, resolve_ca_bundle
from espdock.errors import ConfigError


def write(root: Path, text: str) -> Path:
    (root / "espdock.toml").write_text(text)
    return root


def test_defaults_without_a_config_file(tmp_path):
    assert load_config(tmp_path, {}) == Config()


def test_file_then_environment_then_cli(tmp_path):
    write(tmp_path, '[espdock]\ntarget = "esp32s3"\nbase_image = "debian:bookworm"\n')
    assert load_config(tmp_path, {}).target == "esp32s3"
    assert load_config(tmp_path, {"ESPDOCK_TARGET": "esp32c3"}).target == "esp32c3"
    config = load_config(tmp_path, {"ESPDOCK_TARGET": "esp32c3"}, {"target": "esp32"})
    assert config.target == "esp32"
    assert config.base_image == "debian:bookworm"


def test_unknown_key_suggests_the_close_one(tmp_path):
    write(tmp_path, '[espdock]\ntraget = "esp32"\n')
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    assert "traget" in err.value.message
    assert "target" in err.value.hint


def test_unknown_chip_target_is_refused_with_a_suggestion(tmp_path):
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {}, {"target": "esp32s4"})
    assert "esp32s4" in err.value.message
    assert "esp32s3" in err.value.hint or "esp32s2" in err.value.hint


def test_an_unknown_chip_target_names_where_it_was_set(tmp_path):
    """`target = "esp33"` in espdock.toml said only "unknown chip target 'esp33'", where the
    same typo in a package's sdkconfig.defaults named the file."""
    write(tmp_path, '[espdock]\ntarget = "esp33"\n')
    for env, overrides, where in (
        ({}, None, f"{tmp_path / 'espdock.toml'}: key 'target'"),
        ({"ESPDOCK_TARGET": "esp34"}, None, "environment variable ESPDOCK_TARGET"),
        ({"ESPDOCK_TARGET": "esp34"}, {"target": "esp35"}, "option --target"),
    ):
        with pytest.raises(ConfigError) as err:
            load_config(tmp_path, env, overrides)
        assert where in err.value.message, err.value.message


def test_broken_toml_names_the_file(tmp_path):
    write(tmp_path, "[espdock\n")
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    assert str(tmp_path / "espdock.toml") in err.value.message


def test_toml_that_is_not_utf8_is_bad_input_naming_the_file(tmp_path):
    """`name = "r\\xf6bot"` saved by a Latin-1 editor: exit 70, "a bug in espdock" (UnicodeDecodeError)."""
    (tmp_path / "espdock.toml").write_bytes(b'[espdock]\nname = "r\xf6bot"\n')
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    assert err.value.exit_code == 2
    assert err.value.message == f"{tmp_path / 'espdock.toml'} is not UTF-8 (byte 0xf6 at offset 19)"


def test_an_espdock_variable_close_to_a_setting_is_warned_of_with_it():
    """ESPDOCK_KEEP_CONTAINER=1 in a CI job was ignored without a word."""
    from espdock.config import misspelt_variables

    env = {"ESPDOCK_KEEP_CONTAINER": "1", "ESPDOCK_STATE_DIR": "/s", "ESPDOCK_USER": "ros", "ESPDOCK_TARGET": "esp32"}
    assert misspelt_variables(env) == [
        "warning: ESPDOCK_KEEP_CONTAINER is no espdock setting (ignored): did you mean ESPDOCK_KEEP_CONTAINERS?"
    ]


def test_a_setting_above_the_espdock_table_is_said_as_one_and_another_table_as_a_table(tmp_path):
    """`name = "x"` on a line above [espdock] was "unknown table [name]": it is a key, not a table."""
    write(tmp_path, 'name = "robot"\n[espdock]\npackage_paths = ["src"]\n')
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    assert err.value.message == f"{tmp_path / 'espdock.toml'}: name is set outside the [espdock] table"
    assert err.value.hint == "espdock's settings go under the [espdock] line: move `name = ...` below it."
    write(tmp_path, 'target = "esp32"\n')  # no [espdock] line at all: none to move it below
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    assert err.value.hint == "espdock's settings go under an [espdock] line: put one above them."
    write(tmp_path, "[espdock]\n[tool.other]\nx = 1\n")
    with pytest.raises(ConfigError, match=r"unknown table \[tool\]"):
        load_config(tmp_path, {})


def test_ca_bundle_relative_to_the_workspace_and_must_exist(tmp_path):
    (tmp_path / "corp.pem").write_text("-----BEGIN CERTIFICATE-----\n")
    write(tmp_path, '[espdock]\nca_bundle = "corp.pem"\n')
    assert load_config(tmp_path, {}).ca_bundle == tmp_path / "corp.pem"
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path, {"ESPDOCK_CA_BUNDLE": str(tmp_path / "missing.pem")})


def test_a_ca_bundle_that_is_no_certificate_or_holds_a_private_key_is_refused(tmp_path):
    """The bundle goes into build containers, where the workspace's own code runs: a cloned
    workspace's espdock.toml naming an SSH key had it mounted there, with no word."""
    key = tmp_path / "home/.ssh/id_ed25519"
    key.parent.mkdir(parents=True)
    key.write_text("-----BEGIN OPENSSH PRIVATE KEY-----\nb3BlbnNzaC1rZXktdjEAAAA\n-----END OPENSSH PRIVATE KEY-----\n")
    workspace = tmp_path / "cloned"
    workspace.mkdir()
    write(workspace, '[espdock]\nca_bundle = "../home/.ssh/id_ed25519"\n')
    with pytest.raises(ConfigError, match="holds a private key"):
        load_config(workspace, {})
    both = tmp_path / "cert-and-key.pem"
    both.write_text("-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n-----BEGIN PRIVATE KEY-----\nMIIE\n")
    with pytest.raises(ConfigError, match="holds a private key"):
        load_config(workspace, {"ESPDOCK_CA_BUNDLE": str(both)})
    # OpenSSL's trust format, which Fedora's and RHEL's bundles use: certificates all the same.
    trusted = tmp_path / "tls-ca-bundle.pem"
    trusted.write_text("-----BEGIN TRUSTED CERTIFICATE-----\nMIIB\n-----END TRUSTED CERTIFICATE-----\n")
    assert load_config(workspace, {"ESPDOCK_CA_BUNDLE": str(trusted)}).ca_bundle == trusted
    (tmp_path / "notes.txt").write_text("proxy: 10.0.0.1\n")
    with pytest.raises(ConfigError, match="holds no PEM certificate"):
        load_config(workspace, {"ESPDOCK_CA_BUNDLE": str(tmp_path / "notes.txt")})


def test_the_runtime_image_with_every_build_only_when_asked(tmp_path):
    assert load_config(tmp_path, {}).runtime_image is False
    write(tmp_path, "[espdock]\nruntime_image = true\n")
    assert load_config(tmp_path, {}).runtime_image is True
    assert load_config(tmp_path, {"ESPDOCK_RUNTIME_IMAGE": "false"}).runtime_image is False
    assert load_config(tmp_path, {}, {"runtime_image": False}).runtime_image is False


def test_keep_containers_from_the_environment(tmp_path):
    assert load_config(tmp_path, {"ESPDOCK_KEEP_CONTAINERS": "1"}).keep_containers is True
    assert load_config(tmp_path, {"ESPDOCK_KEEP_CONTAINERS": "0"}).keep_containers is False


def test_pip_cert_is_picked_up_from_pip_config_files(tmp_path):
    cert = tmp_path / "proxy-ca.pem"
    cert.write_text("pem")
    conf = tmp_path / "pip.conf"
    conf.write_text(f"[global]\ncert = {cert}\n")
    env = {"HOME": str(tmp_path / "home"), "PIP_CONFIG_FILE": str(conf)}
    assert pip_configured_cert(env) == cert
    assert resolve_ca_bundle(Config(), env) == cert
    # The environment variable wins over files, and an explicit setting over both.
    assert pip_configured_cert({**env, "PIP_CERT": "/x.pem"}) == Path("/x.pem")
    assert resolve_ca_bundle(Config(ca_bundle=tmp_path / "own.pem"), env) == tmp_path / "own.pem"


@pytest.mark.parametrize(
    ("line", "key", "expected"),
    [
        ("target = 5", "target", "got int 5"),
        ("ca_bundle = 5", "ca_bundle", "got int 5"),
        ("base_image = 5", "base_image", "got int 5"),
        ('idf_image = ["a"]', "idf_image", "got list ['a']"),
        ("micro_ros_commit = 12345", "micro_ros_commit", "got int 12345"),
        ('keep_containers = "maybe"', "keep_containers", "got str 'maybe'"),
        ("debian_mirror = true", "debian_mirror", "got bool True"),
        ('debian_mirror = "deb.debian.org"', "debian_mirror", "got str 'deb.debian.org'"),
        ('ros_distro = "humble"', "ros_distro", "got str 'humble'"),
    ],
)
def test_a_wrongly_typed_value_names_the_file_the_key_and_what_it_must_be(tmp_path, line, key, expected):
    (tmp_path / "espdock.toml").write_text(f"[espdock]\n{line}\n")
    with pytest.raises(ConfigError) as err:
        load_config(tmp_path, {})
    message = err.value.message
    assert f"{tmp_path / 'espdock.toml'}: key '{key}' in [espdock] must be" in message and expected in message


def test_a_table_that_is_not_a_table_is_refused(tmp_path):
    (tmp_path / "espdock.toml").write_text("espdock = 5\n")
    with pytest.raises(ConfigError, match="'espdock' must be a table"):
        load_config(tmp_path, {})


def test_a_bad_environment_variable_is_named():
    with pytest.raises(ConfigError) as err:
        load_config(Path("/nonexistent"), {"ESPDOCK_KEEP_CONTAINERS": "maybe"})
    assert err.value.message == "environment variable ESPDOCK_KEEP_CONTAINERS must be true or false, got 'maybe'"


def test_the_cache_registry_is_a_registry_name_never_a_url_or_credentials(tmp_path):
    good = load_config(tmp_path, {"ESPDOCK_CACHE_REGISTRY": "127.0.0.1:5000/espdock"})
    assert good.cache_registry == "127.0.0.1:5000/espdock"
    for bad in ("https://registry.example.com", "user:pass@registry.example.com", "registry.example.com/Team"):
        with pytest.raises(ConfigError, match="ESPDOCK_CACHE_REGISTRY must be a registry host"):
            load_config(tmp_path, {"ESPDOCK_CACHE_REGISTRY": bad})


def test_an_empty_cache_registry_variable_turns_off_the_one_in_espdock_toml(tmp_path):
    """The CI examples empty ESPDOCK_CACHE_REGISTRY for a job without the registry's credentials (a fork's
    pull request): with the registry in espdock.toml, such a job failed on the registry's refusal."""
    (tmp_path / "espdock.toml").write_text('[espdock]\ncache_registry = "127.0.0.1:5000/team"\n')
    assert load_config(tmp_path, {}).cache_registry == "127.0.0.1:5000/team"
    assert load_config(tmp_path, {"ESPDOCK_CACHE_REGISTRY": ""}).cache_registry is None
    assert load_config(tmp_path, {"ESPDOCK_CACHE_REGISTRY": "other:5000"}).cache_registry == "other:5000"
    # --push-cache then says why it has none: the hint said to set what was set.
    import shutil

    from tests.conftest import REPO, espdock

    shutil.copytree(REPO / "tests/ros_packages/beacon_nodes", tmp_path / "src/beacon_nodes")
    no_engine = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    pushed = espdock("build", "--push-cache", cwd=tmp_path, env={"ESPDOCK_CACHE_REGISTRY": "", **no_engine})
    assert pushed.returncode == 2 and "ESPDOCK_CACHE_REGISTRY is set empty" in pushed.stderr, pushed.stderr


def test_a_ci_job_is_told_by_ci_as_ci_services_set_it():
    """CI=1 or a service's name (Woodpecker: CI=woodpecker) is a CI job as CI=true is: builds there
    rewrote a stale rosdep lock and built from it, where --locked refuses."""
    for value in ("true", "TRUE", "1", "yes", "woodpecker"):
        assert in_ci({"CI": value}), value
    for value in ("", "0", "false", "False", "no"):
        assert not in_ci({"CI": value}), value
    assert not in_ci({})


def test_a_relative_xdg_directory_is_ignored_as_the_spec_says(tmp_path):
    """XDG_CACHE_HOME=relative/cache made relative/ in whatever directory espdock ran in."""
    from espdock.images.prune import state_dir
    from espdock.layout import xdg_dir
    from espdock.ros.rosdeps import cache_dir

    env = {"HOME": str(tmp_path), "XDG_CACHE_HOME": "relative/cache", "XDG_STATE_HOME": "state"}
    assert xdg_dir(env, "XDG_CACHE_HOME", ".cache") == tmp_path / ".cache"
    assert cache_dir(env).is_relative_to(tmp_path / ".cache")
    assert state_dir(env) == tmp_path / ".local/state/espdock"
    assert xdg_dir({**env, "XDG_CACHE_HOME": "/var/cache/me"}, "XDG_CACHE_HOME", ".cache") == Path("/var/cache/me")


@pytest.mark.parametrize(("given", "meant"), [("ESP32C3", "esp32c3"), ("esp32-s3", "esp32s3"), ("Esp32", "esp32")])
def test_a_chip_in_another_case_or_hyphenated_is_told_its_idf_name(given, meant):
    """`--target ESP32C3` said "unknown" with no guess (difflib's is case-sensitive), where
    `esp32-s3` got one."""
    with pytest.raises(ConfigError) as refused:
        check_target(given, "--target")
    assert refused.value.message == f"unknown --target '{given}'" and refused.value.hint == f"Did you mean '{meant}'?"
