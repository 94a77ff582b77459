"""Range readings from a time-of-flight sensor's text protocol ("R<millimetres>\\r\\n")."""


def parse_range(line: str) -> float | None:
    """Metres from one line of the sensor; None for anything else."""
    line = line.strip()
    if not line.startswith("R") or not line[1:].isdigit():
        return None
    return int(line[1:]) / 1000.0
