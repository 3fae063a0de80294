from __future__ import annotations

import copy

import pytest

from camplace.instance import builtin_toml


@pytest.fixture
def valid_data() -> dict:
    """A valid instance dict (the built-in comet bunker, with a cheap comet and three frames)."""
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["target"]["subdivisions"] = 2
    data["frames"] = [
        {"weight": 1.0, "time_s": 0.0, "position_m": [12.0, 1.5, 1.5]},
        {"weight": 0.5, "position_m": [13.0, 1.5, 1.5], "rotation_deg": [0.0, 0.0, 30.0]},
        {"position_m": [14.0, 1.5, 1.5]},
    ]
    return data
