from setuptools import setup

package_name = "rosdeps_py_table"

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
    maintainer="espdock tests",
    maintainer_email="tests@espdock.example.org",
    description="Logs running statistics of /count as a table.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["table = rosdeps_py_table.table:main"]},
)
