"""The caller's RMW_IMPLEMENTATION against what a ROS image has: `espdock run`, `shell` and `test`
pass it on, as `ros2 run` sees it, where the image has that RMW."""

from __future__ import annotations

from collections.abc import Mapping

from espdock.config import Config
from espdock.images.engine import Engine

# The RMW every ROS image espdock builds has, and where each flavour's image keeps ament's index
# of those it has.
DEFAULT_RMW = "rmw_fastrtps_cpp"
RMW_INDEX = "share/ament_index/resource_index/rmw_typesupport"


def for_image(
    engine: Engine, image: str, config: Config, env: Mapping[str, str], labels: Mapping[str, str]
) -> tuple[Mapping[str, str], str | None]:
    """ENV for a container of IMAGE, and what to say of it: without the caller's
    RMW_IMPLEMENTATION where IMAGE has no such RMW but its index is there to say so
    (RMW_IMPLEMENTATION=rmw_cyclonedds_cpp in a ROS developer's ~/.bashrc failed every node with
    rcl's exit code 102, and lost `espdock test`'s results); ENV as it is, and None, otherwise."""
    wanted = env.get("RMW_IMPLEMENTATION", "")
    if not wanted or wanted == DEFAULT_RMW:
        return env, None
    prefix = "/opt/espdock/venv" if config.ros_image == "wheels" else f"/opt/ros/{config.ros_distro}"

    def has(name: str) -> bool:
        return engine.read_file(image, f"{prefix}/{RMW_INDEX}/{name}", labels) is not None

    if has(wanted) or not has(DEFAULT_RMW):
        return env, None
    said = (
        f"warning: RMW_IMPLEMENTATION={wanted} (from your environment) is not in {image}, which has {DEFAULT_RMW}: "
        f"this runs on {DEFAULT_RMW}, which talks DDS with {wanted} elsewhere. To run on {wanted}, a package's "
        f'<exec_depend>{wanted}</exec_depend> that rosdep serves puts it in the image (ros_image = "official" has it)'
    )
    return {key: value for key, value in env.items() if key != "RMW_IMPLEMENTATION"}, said
