"""The firmware side: ESP-IDF and micro-ROS builds, pins, install, flash, provision, the agent, `espdock new`."""
