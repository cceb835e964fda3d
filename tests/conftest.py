from importlib import resources
from pathlib import Path

import pytest

from greybox.airframe import airframe_from_dict, load_airframe

AIRFRAMES = Path(str(resources.files("greybox") / "data" / "airframes"))


def make_airframe(layout="plus", rotor_inertia=0.0, params=None, **kw):
    a = {"mass": 1.0, "inertia": [0.0082, 0.0082, 0.0149], "arm_length": 0.17, "layout": layout,
         "rotor_inertia": rotor_inertia}
    a.update(kw)
    return airframe_from_dict({"airframe": a, "parameters": params or {"K_T": 2e-5, "b": 5e-7,
                                                                       "Kd": [0.1, 0.1, 0.15]}})


@pytest.fixture
def plus_airframe():
    return make_airframe("plus")


@pytest.fixture
def x_airframe():
    return make_airframe("x")


@pytest.fixture
def paper_airframe_path():
    return AIRFRAMES / "paper.toml"


@pytest.fixture
def paper_airframe(paper_airframe_path):
    return load_airframe(paper_airframe_path)
