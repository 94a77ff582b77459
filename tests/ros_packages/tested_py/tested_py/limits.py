"""Speed limits for a wheeled base."""


def clamp_speed(speed: float, limit: float) -> float:
    """Return SPEED limited to [-LIMIT, LIMIT]."""
    if limit < 0:
        raise ValueError('limit must not be negative')
    return max(-limit, min(limit, speed))


def wheel_speeds(linear: float, angular: float, track: float) -> tuple[float, float]:
    """Return the left and right wheel speeds of a differential drive."""
    return linear - angular * track / 2, linear + angular * track / 2
