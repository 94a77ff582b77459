"""The debootstrapped base image records its Debian package set, so drift shows."""

from espdock.images.bootstrap import PACKAGES_LABEL, package_labels, package_set

STATUS = """Package: libc6
Status: install ok installed
Architecture: amd64
Version: 2.36-9+deb12u14
Description: GNU C Library
 continued line: with a colon

Package: removed-one
Status: deinstall ok config-files
Version: 1.0

Package: apt
Status: install ok installed
Version: 2.6.1
"""


def test_only_installed_packages_are_listed_sorted_with_versions():
    assert package_set(STATUS) == ["apt=2.6.1", "libc6=2.36-9+deb12u14"]


def test_a_changed_version_changes_the_recorded_hash():
    before = package_labels(package_set(STATUS))
    after = package_labels(package_set(STATUS.replace("2.6.1", "2.6.2")))
    assert before[PACKAGES_LABEL] == "apt=2.6.1 libc6=2.36-9+deb12u14"
    assert before[f"{PACKAGES_LABEL}.sha256"] != after[f"{PACKAGES_LABEL}.sha256"]
