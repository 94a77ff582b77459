"""Measurement: what a command leaves on the engine (images, containers, volumes, networks).

Run: .venv/bin/python tests/bench/engine_leftovers.py -- .venv/bin/python -m pytest tests/integration/test_x.py
     .venv/bin/python tests/bench/engine_leftovers.py            (lists what is on the engine now)

Lists the engine's objects before and after the command and prints what came and what went,
images with their size (the image's own, and the engine's total from `docker system df`). The
engine may be shared: whatever another user made while the command ran shows up too, so run it
when the engine is quiet, or read the names.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time


def docker(*args: str) -> str:
    return subprocess.run(["docker", *args], capture_output=True, text=True, check=True, timeout=300).stdout


def rows(*args: str) -> list[dict]:
    return [json.loads(line) for line in docker(*args, "--format", "{{json .}}").splitlines() if line.strip()]


def snapshot() -> dict[str, dict[str, str]]:
    """Each kind of object by a key that stays while the object does, with what to print of it."""
    ids = docker("image", "ls", "-q", "--no-trunc").split()
    images = {}
    for image in json.loads(docker("image", "inspect", *sorted(set(ids)))) if ids else ():
        names = ", ".join(image.get("RepoTags") or ["<untagged>"])
        images[image["Id"]] = f"{names} ({image['Size'] / 1e6:.0f} MB)"
    containers = {c["ID"]: f"{c['Names']} from {c['Image']} ({c['State']})" for c in rows("ps", "-a")}
    volumes = {v["Name"]: f"{v['Name']} ({v['Driver']})" for v in rows("volume", "ls")}
    networks = {n["ID"]: f"{n['Name']} ({n['Driver']})" for n in rows("network", "ls")}
    return {"images": images, "containers": containers, "volumes": volumes, "networks": networks}


def images_total() -> str:
    """The engine's disk use for images as `docker system df` counts it (shared layers once)."""
    for row in rows("system", "df"):
        if row.get("Type") == "Images":
            return f"{row['TotalCount']} images, {row['Size']}"
    return "?"


def main(argv: list[str]) -> int:
    command = argv[argv.index("--") + 1 :] if "--" in argv else []
    before, total_before = snapshot(), images_total()
    if not command:
        for kind, found in before.items():
            print(f"{kind}: {len(found)}")
            for text in sorted(found.values()):
                print(f"  {text}")
        print(f"engine images: {total_before}")
        return 0
    started = time.monotonic()
    code = subprocess.run(command, check=False).returncode
    took = time.monotonic() - started
    after, total_after = snapshot(), images_total()
    print(f"\n{' '.join(command)}: exit {code} in {took:.0f} s")
    for kind in before:
        came = [after[kind][k] for k in after[kind].keys() - before[kind].keys()]
        went = [before[kind][k] for k in before[kind].keys() - after[kind].keys()]
        print(f"{kind}: {len(before[kind])} before, {len(after[kind])} after; {len(came)} new, {len(went)} gone")
        for text in sorted(came):
            print(f"  + {text}")
        for text in sorted(went):
            print(f"  - {text}")
    print(f"engine images: {total_before} before, {total_after} after")
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
