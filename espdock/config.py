"""Settings, merged in one place: defaults, then espdock.toml, then the environment, then the CLI."""

from __future__ import annotations

import configparser
import difflib
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from espdock.errors import ConfigError

CONFIG_FILE = "espdock.toml"

CHIP_TARGETS = (
    "esp32",
    "esp32s2",
    "esp32s3",
    "esp32c2",
    "esp32c3",
    "esp32c5",
    "esp32c6",
    "esp32h2",
    "esp32p4",
)
ROS_DISTROS = ("jazzy",)


@dataclass(frozen=True)
class Config:
    """What decides a build, besides the workspace's own files."""

    ros_distro: str = "jazzy"
    target: str = "esp32"
    # None: the default named by the Dockerfile's BASE_IMAGE build arg.
    base_image: str | None = None
    # Extra CA bundle for pip/apt inside image builds; None: pip's configured cert, if any.
    ca_bundle: Path | None = None
    # Keep build containers after they exit, for debugging.
    keep_containers: bool = False
    # Debian mirror for building a base image with debootstrap; None: debootstrap's default.
    debian_mirror: str | None = None
    # None for each: the default pinned by Dockerfile.idf's build args.
    idf_image: str | None = None
    micro_ros_repo: str | None = None
    micro_ros_commit: str | None = None


_KEYS = {f.name for f in fields(Config)}
_ENV = {
    "ESPDOCK_ROS_DISTRO": "ros_distro",
    "ESPDOCK_TARGET": "target",
    "ESPDOCK_BASE_IMAGE": "base_image",
    "ESPDOCK_CA_BUNDLE": "ca_bundle",
    "ESPDOCK_KEEP_CONTAINERS": "keep_containers",
    "ESPDOCK_DEBIAN_MIRROR": "debian_mirror",
    "ESPDOCK_IDF_IMAGE": "idf_image",
    "ESPDOCK_MICRO_ROS_REPO": "micro_ros_repo",
    "ESPDOCK_MICRO_ROS_COMMIT": "micro_ros_commit",
}


def load_config(root: Path, env: Mapping[str, str], overrides: Mapping[str, Any] | None = None) -> Config:
    """Merge defaults, ROOT/espdock.toml, ESPDOCK_* variables and CLI overrides."""
    values: dict[str, Any] = {}
    path = root / CONFIG_FILE
    if path.is_file():
        values.update(_read_toml(path))
    for var, key in _ENV.items():
        if env.get(var):
            values[key] = env[var]
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    return _validate(values, root)


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from exc
    unknown_tables = set(data) - {"espdock"}
    if unknown_tables:
        raise ConfigError(f"{path}: unknown table [{min(unknown_tables)}]", "espdock.toml has one table, [espdock].")
    table = data.get("espdock", {})
    for key in table:
        if key not in _KEYS:
            close = difflib.get_close_matches(key, _KEYS, n=1)
            hint = f"Did you mean '{close[0]}'?" if close else f"Known keys: {', '.join(sorted(_KEYS))}."
            raise ConfigError(f"{path}: unknown key '{key}' in [espdock]", hint)
    return dict(table)


def _validate(values: dict[str, Any], root: Path) -> Config:
    config = replace(Config(), **values)
    if config.target not in CHIP_TARGETS:
        close = difflib.get_close_matches(config.target, CHIP_TARGETS, n=1)
        raise ConfigError(
            f"unknown chip target '{config.target}'",
            f"Did you mean '{close[0]}'?" if close else f"Targets: {', '.join(CHIP_TARGETS)}.",
        )
    if config.ros_distro not in ROS_DISTROS:
        raise ConfigError(f"unsupported ROS distro '{config.ros_distro}'", f"Supported: {', '.join(ROS_DISTROS)}.")
    if isinstance(config.keep_containers, str):
        config = replace(config, keep_containers=config.keep_containers.lower() in ("1", "true", "yes"))
    if config.ca_bundle is not None:
        ca = Path(config.ca_bundle).expanduser()
        ca = ca if ca.is_absolute() else root / ca
        if not ca.is_file():
            raise ConfigError(f"CA bundle {ca} does not exist", "Set ca_bundle (or ESPDOCK_CA_BUNDLE) to a PEM file.")
        config = replace(config, ca_bundle=ca)
    return config


def pip_configured_cert(env: Mapping[str, str]) -> Path | None:
    """The CA bundle pip on this machine is told to trust (PIP_CERT or pip.conf `cert`), if any."""
    if env.get("PIP_CERT"):
        return Path(env["PIP_CERT"])
    home = Path(env.get("HOME", "~")).expanduser()
    xdg = Path(env.get("XDG_CONFIG_HOME", home / ".config"))
    # pip's own order: global, user, site; later files win.
    candidates = [Path("/etc/xdg/pip/pip.conf"), Path("/etc/pip.conf"), home / ".pip/pip.conf", xdg / "pip/pip.conf"]
    if env.get("VIRTUAL_ENV"):
        candidates.append(Path(env["VIRTUAL_ENV"]) / "pip.conf")
    if env.get("PIP_CONFIG_FILE"):
        candidates.append(Path(env["PIP_CONFIG_FILE"]))
    cert = None
    for path in candidates:
        parser = configparser.ConfigParser()
        try:
            parser.read(path)
        except (configparser.Error, OSError):
            continue
        for section in ("global", "install"):
            if parser.has_option(section, "cert"):
                cert = parser.get(section, "cert")
    return Path(cert) if cert else None


def resolve_ca_bundle(config: Config, env: Mapping[str, str]) -> Path | None:
    """The extra CA bundle to hand to image builds: the configured one, else pip's."""
    if config.ca_bundle is not None:
        return config.ca_bundle
    cert = pip_configured_cert(env)
    return cert if cert is not None and cert.is_file() else None


def invoking_user(env: Mapping[str, str], root: Path) -> tuple[int, int]:
    """The uid/gid that should own what builds write into the workspace at ROOT.

    A normal user is that user. Root stands in for someone: the sudo caller, or
    else the workspace's owner, so a root build never leaves root-owned files
    in somebody's tree.
    """
    if os.geteuid() != 0:
        return os.getuid(), os.getgid()
    if env.get("SUDO_UID") and env.get("SUDO_GID"):
        return int(env["SUDO_UID"]), int(env["SUDO_GID"])
    owner = root.stat()
    return owner.st_uid, owner.st_gid
