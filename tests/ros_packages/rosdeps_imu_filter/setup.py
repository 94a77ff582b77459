from setuptools import find_packages, setup

package_name = "rosdeps_imu_filter"

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
    description="Fuses gyroscope and accelerometer readings into an orientation (Madgwick).",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": ["imu_filter = rosdeps_imu_filter.imu_filter:main"]},
)
