"""contract double of espressif/idf:v5.3.5 and micro_ros_espidf_component (see README.md)."""
