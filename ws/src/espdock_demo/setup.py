from setuptools import find_packages, setup

PACKAGE = "espdock_demo"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    # The camera UI's page, stylesheet and script.
    package_data={PACKAGE: ["assets/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="espdock maintainers",
    maintainer_email="maintainers@espdock.dev",
    description="QR-driven LED demo nodes and ESP32 simulators.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"camera_sim = {PACKAGE}.camera_sim:main",
            f"qr_detector = {PACKAGE}.qr_detector:main",
            f"led_strip_sim = {PACKAGE}.led_strip_sim:main",
            f"camera_ui = {PACKAGE}.camera_ui:main",
            f"demo_monitor = {PACKAGE}.monitor:main",
            f"demo_watchdog = {PACKAGE}.watchdog:main",
        ],
    },
)
