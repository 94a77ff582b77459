"""Settings, merged in one place: defaults, then espdock.toml, then the environment, then the CLI."""

from __future__ import annotations

import configparser
import difflib
import os
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta, Struct

from espdock.errors import ConfigError
from espdock.layout import CONFIG_FILE, home_dir, xdg_dir

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
# How ROS gets into the build and runtime images: the PyPI wheels (Dockerfile.ros) or the
# official ros:<distro>-ros-base image (Dockerfile.ros-official).
ROS_IMAGES = ("wheels", "official")
WORKSPACE_MODES = ("auto", "mount", "volume")


@dataclass(frozen=True)
class Config:
    """What decides a build, besides the workspace's own files."""

    ros_distro: str = "jazzy"
    ros_image: str = "wheels"
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
    # The workspace layout, relative to espdock.toml's directory; None: detected (Workspace.with_layout).
    package_paths: tuple[str, ...] | None = None
    colcon_root: str | None = None
    # Registry (host[:port][/path]) that keyed images are pulled from before building, and
    # pushed to with --push-cache. Credentials are the engine's own (docker login), never here.
    cache_registry: str | None = None
    # The workspace's name: its runtime image is espdock/<name>; None: the directory's name.
    name: str | None = None
    # `espdock prune`: generations of each kind of keyed image kept besides the ones in use, and
    # whether every successful build prunes so (its BuildKit cache trimmed to build_cache_max_gb).
    prune_keep: int = 1
    prune_auto: bool = False
    build_cache_max_gb: float = 10.0
    # A build says so, once, when espdock's images on the engine take more than this.
    images_warn_gb: float = 30.0
    # Make the workspace's runtime image (espdock/<name>) with every build; otherwise it is made
    # when `espdock run` or `espdock compose` needs it (2 s a build, and a new tag each time).
    runtime_image: bool = False
    # Where build containers find the workspace: "mount" (bind mount: the engine sees this
    # machine's files), "volume" (a volume on the engine that espdock syncs: espdock.volume) or
    # "auto" (the volume only where a container does not see the mounted workspace).
    workspace_mode: str = "auto"


_Text = Annotated[str, Meta(min_length=1)]


class _Settings(Struct, forbid_unknown_fields=True):
    """The shape of every setting, checked once wherever settings come from (msgspec: a typed
    model that imports in a few milliseconds, which a no-change build notices)."""

    ros_distro: Literal["jazzy"] | None = None
    ros_image: Literal["wheels", "official"] | None = None
    target: _Text | None = None
    base_image: _Text | None = None
    ca_bundle: _Text | None = None
    keep_containers: bool | None = None
    debian_mirror: Annotated[str, Meta(pattern=r"^(https?|file)://\S+$")] | None = None
    idf_image: _Text | None = None
    micro_ros_repo: _Text | None = None
    micro_ros_commit: Annotated[str, Meta(pattern=r"^[0-9a-f]{7,40}$")] | None = None
    package_paths: Annotated[list[_Text], Meta(min_length=1)] | None = None
    colcon_root: _Text | None = None
    cache_registry: Annotated[str, Meta(pattern=r"^[A-Za-z0-9.-]+(:[0-9]+)?(/[a-z0-9._-]+)*$")] | None = None
    # A path component of an image reference, as Docker's grammar has it: `robot_-x` and
    # `robot..x` are none (every run and compose up failed on "invalid reference format").
    # At most 247: espdock/<name> within the 255 characters Docker allows a repository's name.
    name: Annotated[str, Meta(pattern=r"^[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*$", max_length=247)] | None = None
    prune_keep: Annotated[int, Meta(ge=0, le=1000)] | None = None
    prune_auto: bool | None = None
    build_cache_max_gb: Annotated[float, Meta(ge=0)] | None = None
    images_warn_gb: Annotated[float, Meta(ge=0)] | None = None
    runtime_image: bool | None = None
    workspace_mode: Literal["auto", "mount", "volume"] | None = None


_KEYS = {f.name for f in fields(Config)}
assert set(_Settings.__struct_fields__) == _KEYS, "Config and _Settings must name the same settings"
_ENV = {f"ESPDOCK_{key.upper()}": key for key in sorted(_KEYS)}
_EXPECTED = {
    "ros_distro": "one of: " + ", ".join(ROS_DISTROS),
    "ros_image": "one of: " + ", ".join(ROS_IMAGES),
    "target": 'a chip target string such as "esp32s3"',
    "base_image": "an image reference string",
    "ca_bundle": "a path string",
    "keep_containers": "true or false",
    "debian_mirror": "an http(s):// or file:// URL string",
    "idf_image": "an image reference string",
    "micro_ros_repo": "a git URL string",
    "micro_ros_commit": "a commit hash string (7 to 40 hex digits)",
    "package_paths": 'a non-empty list of directory strings, e.g. ["src"]',
    "colcon_root": 'a directory string, e.g. "."',
    "name": 'a lower-case image name string of at most 247 characters, e.g. "myrobot"',
    "prune_keep": "a whole number of generations, 0 or more",
    "prune_auto": "true or false",
    "build_cache_max_gb": "a number of gigabytes, 0 or more",
    "images_warn_gb": "a number of gigabytes, 0 or more",
    "runtime_image": "true or false",
    "workspace_mode": "one of: " + ", ".join(WORKSPACE_MODES),
    "cache_registry": 'a registry host[:port][/path] string, e.g. "registry.example.com/espdock" (no scheme)',
}


def load_config(root: Path, env: Mapping[str, str], overrides: Mapping[str, Any] | None = None) -> Config:
    """Merge defaults, ROOT/espdock.toml, ESPDOCK_* variables and CLI overrides, each checked
    against _Settings where it comes from, so an error names the file key or the variable."""
    values: dict[str, Any] = {}
    path = root / CONFIG_FILE
    if path.is_file():
        table = _read_toml(path)
        values.update(_checked(table, strict=True, where=lambda key: f"{path}: key '{key}' in [espdock]"))
    from_env: dict[str, Any] = {key: env[var] for var, key in _ENV.items() if env.get(var)}
    if "package_paths" in from_env:  # a list in one variable: PATH-style
        from_env["package_paths"] = from_env["package_paths"].split(os.pathsep)
    values.update(_checked(from_env, strict=False, where=lambda key: f"environment variable ESPDOCK_{key.upper()}"))
    if _cache_registry_emptied(env):
        values.pop("cache_registry", None)
    cli = {k: v for k, v in (overrides or {}).items() if v is not None}
    values.update(_checked(cli, strict=False, where=lambda key: f"option --{key.replace('_', '-')}"))
    # Where the chip came from, for its error: "unknown chip target 'esp33'" named no file or variable.
    chip = (
        "option --target"
        if "target" in cli
        else "environment variable ESPDOCK_TARGET"
        if "target" in from_env
        else f"{path}: key 'target' in [espdock]"
    )
    return _validate(values, root, chip)


def _cache_registry_emptied(env: Mapping[str, str]) -> bool:
    """Whether ENV sets ESPDOCK_CACHE_REGISTRY empty, which turns the cache off: CI empties it for a job
    without the registry's credentials (a fork's pull request), and with the registry in espdock.toml
    such jobs failed on its login."""
    return env.get("ESPDOCK_CACHE_REGISTRY") == ""


def no_cache_registry(env: Mapping[str, str]) -> ConfigError:
    """--push-cache's error where no cache registry is set (ENV: an empty ESPDOCK_CACHE_REGISTRY turns
    espdock.toml's off, which the hint said to set)."""
    if _cache_registry_emptied(env):
        return ConfigError(
            "--push-cache needs a cache registry: ESPDOCK_CACHE_REGISTRY is set empty, which turns it off",
            "Set ESPDOCK_CACHE_REGISTRY to the registry, or unset it for espdock.toml's cache_registry.",
        )
    return ConfigError("--push-cache needs a cache registry", "Set cache_registry or ESPDOCK_CACHE_REGISTRY.")


def misspelt_variables(env: Mapping[str, str]) -> list[str]:
    """A warning for each ESPDOCK_ variable in ENV that is no setting but close to one
    (ESPDOCK_KEEP_CONTAINER): a CI variable's typo was ignored without a word. Others of the
    prefix, espdock's own (ESPDOCK_STATE_DIR) or nothing like a setting, are not said."""
    said = []
    for var in sorted(env):
        if var.startswith("ESPDOCK_") and var not in _ENV:
            close = difflib.get_close_matches(var.removeprefix("ESPDOCK_").lower(), _KEYS, n=1, cutoff=0.8)
            if close:
                said.append(f"warning: {var} is no espdock setting (ignored): did you mean ESPDOCK_{close[0].upper()}?")
    return said


def _checked(raw: Mapping[str, Any], strict: bool, where: Callable[[str], str]) -> dict[str, Any]:
    """RAW's settings, type-checked (STRICT: TOML's own types, no coercion from strings)."""
    try:
        settings = msgspec.convert(dict(raw), _Settings, strict=strict)
    except msgspec.ValidationError as exc:
        # msgspec names the field as `$.key` or `$.key[i]`.
        match = re.search(r"\$\.(\w+)", str(exc))
        key = match.group(1) if match else "?"
        value = raw.get(key)
        shown = f"{type(value).__name__} {value!r}" if strict else repr(value)
        raise ConfigError(
            f"{where(key)} must be {_EXPECTED.get(key, 'valid')}, got {shown}", "Fix the value and run again."
        ) from None
    return {key: value for key, value in msgspec.structs.asdict(settings).items() if value is not None}


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # past a Windows editor's byte order mark
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:  # TOML is UTF-8: a Latin-1 editor's ü
        raise ConfigError(
            f"{path} is not UTF-8 (byte {exc.object[exc.start]:#04x} at offset {exc.start})",
            "Save it as UTF-8, as TOML files are, and run again.",
        ) from None
    unknown_tables = set(data) - {"espdock"}
    if keys := sorted(k for k in unknown_tables if not isinstance(data[k], dict)):
        # `name = "x"` above [espdock] is a key of no table, not a table called name.
        raise ConfigError(
            f"{path}: {keys[0]} is set outside the [espdock] table",
            f"espdock's settings go under the [espdock] line: move `{keys[0]} = ...` below it."
            if "espdock" in data
            else "espdock's settings go under an [espdock] line: put one above them.",
        )
    if unknown_tables:
        raise ConfigError(f"{path}: unknown table [{min(unknown_tables)}]", "espdock.toml has one table, [espdock].")
    table = data.get("espdock", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: 'espdock' must be a table ([espdock]), got {type(table).__name__}")
    for key in table:
        if key not in _KEYS:
            close = difflib.get_close_matches(key, _KEYS, n=1)
            hint = f"Did you mean '{close[0]}'?" if close else f"Known keys: {', '.join(sorted(_KEYS))}."
            raise ConfigError(f"{path}: unknown key '{key}' in [espdock]", hint)
    return dict(table)


def in_ci(env: Mapping[str, str]) -> bool:
    """Whether ENV is a CI job's: CI set, as every CI service sets it (true, 1, the service's name),
    and not turned off (false, 0, no)."""
    return env.get("CI", "").strip().lower() not in ("", "0", "false", "no", "off")


def check_target(target: str, where: str = "chip target") -> str:
    """TARGET, when it is a chip ESP-IDF 5.3 knows; a ConfigError naming WHERE otherwise."""
    if target not in CHIP_TARGETS:
        # IDF's names are lower case and unhyphenated: `ESP32C3`, `esp32-s3` are one of them miswritten.
        close = difflib.get_close_matches(re.sub(r"[-_ ]", "", target.lower()), CHIP_TARGETS, n=1)
        raise ConfigError(
            f"unknown {where} '{target}'",
            f"Did you mean '{close[0]}'?" if close else f"Targets: {', '.join(CHIP_TARGETS)}.",
        )
    return target


def _validate(values: dict[str, Any], root: Path, chip: str) -> Config:
    if values.get("package_paths") is not None:
        values["package_paths"] = tuple(values["package_paths"])
    config = replace(Config(), **values)
    if "target" in values:  # the default is a chip
        check_target(config.target, f"chip target in {chip}:")
    if config.ca_bundle is not None:
        ca = Path(config.ca_bundle).expanduser()
        ca = ca if ca.is_absolute() else root / ca
        if not ca.is_file():
            raise ConfigError(f"CA bundle {ca} does not exist", "Set ca_bundle (or ESPDOCK_CA_BUNDLE) to a PEM file.")
        _check_certificates(ca)
        config = replace(config, ca_bundle=ca)
    return config


def _check_certificates(ca: Path) -> None:
    """A ConfigError unless CA holds PEM certificates and no private key. The bundle goes into
    build containers, and an espdock.toml is the workspace's: a cloned one naming
    `~/.ssh/id_ed25519` had the key mounted where the workspace's own code runs."""
    try:
        data = ca.read_bytes()
    except OSError as exc:
        raise ConfigError(f"CA bundle {ca} cannot be read: {exc.strerror}") from exc
    if b"PRIVATE KEY" in data:
        raise ConfigError(
            f"CA bundle {ca} holds a private key",
            "espdock passes the CA bundle into its build containers: name a file of the proxy's CA certificates only.",
        )
    if b"-----BEGIN CERTIFICATE-----" not in data and b"-----BEGIN TRUSTED CERTIFICATE-----" not in data:
        raise ConfigError(
            f"CA bundle {ca} holds no PEM certificate (no -----BEGIN CERTIFICATE----- line)",
            "Set ca_bundle (or ESPDOCK_CA_BUNDLE) to the PEM file of the proxy's CA certificates.",
        )


def pip_configured_cert(env: Mapping[str, str]) -> Path | None:
    """The CA bundle pip on this machine is told to trust (PIP_CERT or pip.conf `cert`), if any."""
    if env.get("PIP_CERT"):
        return Path(env["PIP_CERT"])
    home = home_dir(env)
    xdg = xdg_dir(env, "XDG_CONFIG_HOME", ".config")
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
