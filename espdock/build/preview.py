"""What a build would do now (`espdock build --dry-run`): each step's state, read from the stamps
and images the build itself decides by, changing nothing. Without an engine to ask, what its
images decide is named as unknown, never guessed."""

from __future__ import annotations

from typing import assert_never

from espdock.build.steps import EnsureBaseImage, EnsureImage, Plan, built_from
from espdock.errors import EspdockError
from espdock.firmware.plan import IdfBuild, InstallFirmware
from espdock.firmware.steps import firmware_state, install_up_to_date
from espdock.images.engine import Engine
from espdock.images.keyed import is_current
from espdock.layout import ROS_BUILD_BASE
from espdock.ros.colcon import left_out
from espdock.ros.plan import ColconBuild, RuntimeImage
from espdock.ros.runtime_tree import runtime_spec
from espdock.ros.staleness import colcon_rebuild
from espdock.workspace import Workspace

UNKNOWN = "not known (no engine answered, and the images decide it)"


def preview(workspace: Workspace, plan: Plan, engine: Engine | None, registry: bool) -> list[str]:
    """Each of PLAN's steps' state, in order: up to date, or what it would do. ENGINE: where the images are
    looked up (None: none answered). REGISTRY: a cache registry is set, which missing images are
    pulled from first."""
    states: list[str] = []
    made: set[str] = set()  # images this build would make or pull
    ros_built = False
    firmware_built: set[str] = set()
    for step in plan.steps:
        match step:
            case EnsureBaseImage():
                present = None if engine is None else engine.image(step.image) is not None
                made_so = "pulled, else built with debootstrap" if step.debootstrap else "pulled (nothing builds it)"
                states.append(_image_state(present, pulled=made_so))
            case EnsureImage():
                present = None if engine is None else is_current(step.spec, engine.image(step.spec.tag))
                present = present and not step.force
                states.append(
                    _image_state(present, pulled="pulled from the cache registry or built" if registry else "built")
                )
                if present is False:
                    made.add(step.spec.tag)
            case ColconBuild():
                found = colcon_rebuild(workspace, step)
                stamps, rebuild = found.stamps, found.rebuild
                out = left_out(step.colcon_args, dict(step.depends), workspace.ws_dir / ROS_BUILD_BASE)
                building = [name for name in rebuild if name not in out]
                if rebuild:
                    ros_built = ros_built or bool(building)
                    state = f"would build {len(building)} of {len(stamps)} package(s)"
                    state += f": {', '.join(building)}" if building else ""
                    if skipped := [name for name in rebuild if name in out]:
                        state += f"; the options after `--` leave out {', '.join(skipped)}"
                    states.append(state)
                else:
                    states.append(f"up to date ({len(stamps)} package(s))")
            case IdfBuild():
                image = None if engine is None else engine.image(step.image)
                stamp_file, _, current = firmware_state(workspace, step, image.id if image else "")
                if step.force or step.image in made or step.package not in stamp_file.read():
                    current = False  # whatever the engine holds
                elif engine is None:
                    current = None
                if current is None:
                    states.append(UNKNOWN)
                elif current:
                    states.append(f"up to date ({step.target})")
                else:
                    firmware_built.add(step.package)
                    states.append(f"would build ({step.target})")
            case InstallFirmware():
                current = step.package not in firmware_built and install_up_to_date(workspace, step)
                states.append("up to date" if current else "would install the firmware its build leaves")
            case RuntimeImage():
                states.append(_runtime_state(workspace, step, engine, ros_built))
            case _:
                assert_never(step)
    return [_base_state(step, state, plan, made) for step, state in zip(plan.steps, states, strict=True)]


def _base_state(step: object, state: str, plan: Plan, made: set[str]) -> str:
    """A missing base is made only before an image is built from it (espdock.images.keyed)."""
    if not isinstance(step, EnsureBaseImage) or not state.startswith("would be"):
        return state
    if any(image.spec.tag in made for image in built_from(plan.steps, step.image)):
        return state
    return "not here, and not needed: the images built from it are present"


def _image_state(present: bool | None, pulled: str) -> str:
    if present is None:
        return UNKNOWN
    return "present" if present else f"would be {pulled}"


def _runtime_state(workspace: Workspace, step: RuntimeImage, engine: Engine | None, ros_built: bool) -> str:
    if ros_built:
        return "would be made of what the build installs"
    if engine is None:
        return UNKNOWN
    try:
        spec = runtime_spec(workspace, step)
    except EspdockError:
        return "would be made of what the build installs"
    keyed = engine.image(spec.tag)
    if keyed is None or not is_current(spec, keyed):
        return f"would be made ({spec.tag})"
    stable = engine.image(step.stable_tag)
    if stable is None or stable.id != keyed.id:
        return f"present; {step.stable_tag} would be tagged to it"
    return "up to date"
