from setuptools import find_packages, setup

package_name = "rosdeps_serial_gps"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="espdock tests",
    maintainer_email="tests@espdock.example.org",
    description="Reads NMEA GGA sentences from a serial GPS receiver and publishes NavSatFix.",
    license="BSD",
    tests_require=["pytest"],
    entry_points={"console_scripts": ["serial_gps = rosdeps_serial_gps.serial_gps:main"]},
)
