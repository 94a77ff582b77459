"""The micro-ROS pins file: parsing, and pinning rows that follow a branch head."""

import os

import pytest

from espdock.defaults import defaults_root
from espdock.errors import WorkspaceError
from espdock.firmware.pins import (
    IdfPin,
    Source,
    parse_resolved,
    parse_sources,
    pin_heads,
    pin_idf_image,
    pin_image_digest,
    read_sources,
    write_pins,
)
from tests.conftest import REPO

A, B = "a" * 40, "b" * 40
ME = (os.getuid(), os.getgid())
TEXT = f"""# header comment
https://github.com/ros2/rcl jazzy {A}  # pinned
https://github.com/ros2/rclc jazzy -
https://github.com/ros2/rmw jazzy -
"""


def test_rows_parse_and_comments_are_skipped():
    assert parse_sources(TEXT) == [
        Source("https://github.com/ros2/rcl", "jazzy", A),
        Source("https://github.com/ros2/rclc", "jazzy", "-"),
        Source("https://github.com/ros2/rmw", "jazzy", "-"),
    ]


def test_the_shipped_file_pins_every_repository_it_names():
    sources = parse_sources((REPO / "docker/idf/micro_ros_sources.txt").read_text())
    assert len({s.key for s in sources}) == len(sources) >= 29


@pytest.mark.parametrize("row", ["https://x jazzy abc", "https://x jazzy", f"https://x jazzy {A} extra"])
def test_a_bad_row_names_its_line(row):
    with pytest.raises(WorkspaceError, match=r"micro_ros_sources.txt:2:"):
        parse_sources(f"# c\n{row}\n")


def test_heads_get_pinned_to_what_the_image_was_built_from_and_the_rest_is_kept():
    banner = [
        "Activating ESP-IDF 5.3",
        f"https://github.com/ros2/rclc.git jazzy {B}",
        f"https://github.com/ros2/rcl jazzy {B}",
    ]
    text, pinned = pin_heads(TEXT, parse_resolved(banner))
    assert pinned == [Source("https://github.com/ros2/rclc", "jazzy", B)]
    assert text == TEXT.replace("rclc jazzy -", f"rclc jazzy {B}")  # rcl keeps its pin; rmw was not built


def test_a_head_of_another_branch_is_not_taken():
    text, pinned = pin_heads(TEXT, parse_resolved([f"https://github.com/ros2/rclc rolling {B}"]))
    assert pinned == [] and text == TEXT


DOCKERFILE = "# c\nARG IDF_IMAGE=espressif/idf:v5.3.5\nFROM ${IDF_IMAGE} AS idf\n"
DIGEST = "sha256:" + "c" * 64


def test_the_idf_image_is_pinned_to_the_digest_of_its_own_repository():
    digests = ["mirror.example/idf@sha256:" + "d" * 64, f"espressif/idf@{DIGEST}"]
    pinned = pin_image_digest(DOCKERFILE, "IDF_IMAGE", "espressif/idf:v5.3.5", digests)
    assert pinned == DOCKERFILE.replace("v5.3.5", f"v5.3.5@{DIGEST}")


def test_an_image_built_or_imported_here_has_no_digest_to_pin():
    assert pin_image_digest(DOCKERFILE, "IDF_IMAGE", "espressif/idf:v5.3.5", []) is None


def test_a_registry_with_a_port_is_not_mistaken_for_a_tag():
    text = "ARG IDF_IMAGE=127.0.0.1:5000/idf\n"
    pinned = pin_image_digest(text, "IDF_IMAGE", "127.0.0.1:5000/idf", [f"127.0.0.1:5000/idf@{DIGEST}"])
    assert pinned == f"ARG IDF_IMAGE=127.0.0.1:5000/idf@{DIGEST}\n"


def _workspace(tmp_path, sources: str = TEXT):
    (tmp_path / "docker/idf").mkdir(parents=True)
    (tmp_path / "docker/idf/micro_ros_sources.txt").write_text(sources)
    (tmp_path / "Dockerfile.idf").write_text(DOCKERFILE)
    return tmp_path


def test_pinning_writes_the_heads_back_and_a_second_run_finds_nothing_to_pin(tmp_path):
    root = _workspace(tmp_path)
    resolved = {s.key: s for s in [Source("https://github.com/ros2/rclc", "jazzy", B)]}
    assert write_pins(root, resolved, ME) == [Source("https://github.com/ros2/rclc", "jazzy", B)]
    assert f"https://github.com/ros2/rclc jazzy {B}\n" in read_sources(root)
    assert write_pins(root, resolved, ME) == []


def test_the_idf_image_digest_goes_into_the_dockerfile_unless_espdock_toml_names_the_image(tmp_path):
    root = _workspace(tmp_path)
    digests = [f"espressif/idf@{DIGEST}"]
    assert pin_idf_image(root, "espressif/idf:v5.3.5", digests, from_config=True, owner=ME) == IdfPin(
        "espressif/idf:v5.3.5", DIGEST, False
    )
    assert (root / "Dockerfile.idf").read_text() == DOCKERFILE
    assert pin_idf_image(root, "espressif/idf:v5.3.5", digests, from_config=False, owner=ME).written
    assert f"espressif/idf:v5.3.5@{DIGEST}" in (root / "Dockerfile.idf").read_text()
    assert pin_idf_image(root, f"espressif/idf:v5.3.5@{DIGEST}", digests, from_config=False, owner=ME) is None
    assert pin_idf_image(root, "espressif/idf:v5.3.5", [], from_config=False, owner=ME) == IdfPin(
        "espressif/idf:v5.3.5", None, False
    )


def test_a_workspace_on_espdock_s_default_files_reads_them_and_pinning_gives_it_its_own(tmp_path):
    """`espdock init` makes no docker/idf/ nor Dockerfile.idf: builds take espdock's default of
    each. `micro-ros status` said the sources file was missing (exit 2), and `pin` crashed on
    the Dockerfile (exit 70)."""
    default = (defaults_root() / "docker/idf/micro_ros_sources.txt").read_text()
    assert read_sources(tmp_path) == default
    heads = [s for s in parse_sources(default) if s.commit == "-"]
    assert heads, "the default follows some branch heads"
    resolved = {s.key: Source(s.url, s.branch, B) for s in heads}
    assert write_pins(tmp_path, resolved, ME) == [resolved[s.key] for s in heads]
    assert read_sources(tmp_path) == (tmp_path / "docker/idf/micro_ros_sources.txt").read_text() != default
    reference = "espressif/idf:v5.3.5"
    assert pin_idf_image(tmp_path, reference, [f"espressif/idf@{DIGEST}"], from_config=False, owner=ME).written
    assert f"ARG IDF_IMAGE={reference}@{DIGEST}" in (tmp_path / "Dockerfile.idf").read_text()
    assert not list(tmp_path.rglob(".*espdock-tmp"))
