# ROS 1 only (catkin_python_setup); ROS 2 installs the module with ament_cmake_python.
from distutils.core import setup

from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["rosdeps_dual_driver"], package_dir={"": "src"}))
