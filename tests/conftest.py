import os

# one BLAS thread per test process: the tests run one worker per CPU (pyproject's addopts),
# and a worker's BLAS threads on top of them would only fight over the same cores
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from importlib import resources  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from greybox.airframe import airframe_from_dict, load_airframe  # noqa: E402

AIRFRAMES = Path(str(resources.files("greybox") / "data" / "airframes"))


def without_gyro(log):
    """``log`` with its p, q, r columns left out (the contract makes them optional)."""
    from dataclasses import replace
    keep = [i for i, n in enumerate(log.output_names) if n not in ("p", "q", "r")]
    return replace(log, outputs=log.outputs[:, keep], output_names=[log.output_names[i] for i in keep])


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
