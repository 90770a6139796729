"""Validation of output times, shared by every integrator."""

from __future__ import annotations

import numpy as np

from .precision import to_fraction

__all__ = ["parse_times"]


def parse_times(t, t0=0, argname: str = "t"):
    """Validate output times.

    A scalar ``t`` asks for the state at ``t`` (before ``t0`` integrates backward); the outputs are then
    ``[t0, t]`` (just ``[t0]`` when t equals t0). A sequence is a grid of output times: strictly increasing and not before ``t0`` (forward), or
    strictly decreasing and not after ``t0`` (backward).

    Returns
    -------
    grid : list of Fraction
        Output times (exact).
    direction : int
        +1 forward, -1 backward, 0 when nothing is to be integrated.
    t0 : Fraction
    """
    t0 = to_fraction(t0, "t0")
    if isinstance(t, (str, bytes)) or np.ndim(t) == 0:
        tf = to_fraction(t.item() if isinstance(t, np.ndarray) else t, argname)
        if tf == t0:
            return [t0], 0, t0
        return [t0, tf], (tf > t0) - (tf < t0), t0
    arr = np.asarray(t, dtype=object)
    if arr.ndim != 1:
        raise ValueError(f"`{argname}` must be a final time or a 1-d sequence of output times; got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"`{argname}` must not be an empty sequence of output times")
    grid = [to_fraction(v, f"{argname}[{i}]") for i, v in enumerate(arr)]
    if len(grid) == 1:
        return grid, (grid[0] > t0) - (grid[0] < t0), t0
    inc = all(b > a for a, b in zip(grid, grid[1:]))
    dec = all(b < a for a, b in zip(grid, grid[1:]))
    if not (inc or dec):
        i = next(i for i, (a, b) in enumerate(zip(grid, grid[1:])) if (b - a) * (grid[1] - grid[0]) <= 0)
        raise ValueError(
            f"`{argname}` must be strictly increasing (or strictly decreasing, for backward integration); "
            f"t[{i}] = {float(grid[i])} is followed by t[{i + 1}] = {float(grid[i + 1])}"
        )
    if inc and grid[0] < t0:
        raise ValueError(
            f"`{argname}` is an increasing grid but starts before t0 = {float(t0)} (t[0] = {float(grid[0])}); "
            "output times must not cross t0: give a decreasing grid for backward integration, or set `t0`"
        )
    if dec and grid[0] > t0:
        raise ValueError(
            f"`{argname}` is a decreasing grid (backward integration) but starts after t0 = {float(t0)} "
            f"(t[0] = {float(grid[0])}); output times must not cross t0"
        )
    return grid, (1 if inc else -1), t0

