from setuptools import setup

package_name = "beacon_nodes"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="espdock developers",
    maintainer_email="espdock@example.org",
    description="A beacon that publishes a counter, and a log that prints what it hears.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "beacon = beacon_nodes.beacon:main",
            "beacon_log = beacon_nodes.beacon_log:main",
        ],
    },
)
