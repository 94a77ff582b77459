from setuptools import find_packages, setup

PACKAGE = "espdock_demo_testing"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="espdock maintainers",
    maintainer_email="maintainers@espdock.dev",
    description="Test tools for the espdock demo (demo_probe).",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"demo_probe = {PACKAGE}.probe:main"]},
)
