"""SolveOptions and the Python API's arguments: each checked once, the error naming it.

Issue 29 (one checked Bed, one SolveOptions) and issue 31's API items: an
argument of the wrong type is refused with an error that names it, never taken
for something else (``accept_unconverged="no"`` was True; ``petsc_args`` as one
string was ignored).
"""
import dataclasses

import numpy as np
import pytest
from helpers import cubic_lattice

import amfe
from amfe.errors import AmfeError
from amfe.model.bed import Bed
from amfe.model.options import SolveOptions


@pytest.fixture(scope="module")
def bed():
    return Bed(*cubic_lattice(3))


@pytest.mark.parametrize("kwargs,name", [
    ({"accept_unconverged": "no"}, "accept_unconverged"),
    ({"accept_unconverged": 0}, "accept_unconverged"),
    ({"diagnose": "yes"}, "diagnose"),
    ({"fields": 1}, "fields"),
    ({"petsc_options": ["-ksp_monitor"]}, "petsc_options"),
    ({"petsc_options": "-ksp_monitor"}, "petsc_options"),
    ({"petsc_options": {1: 2}}, "petsc_options"),
    ({"petsc_options": {"ksp_type": ["cg"]}}, "petsc_options"),
    ({"max_memory": "lots"}, "max_memory"),
    ({"max_memory": -5}, "max_memory"),
    ({"max_memory": [1]}, "max_memory"),
    ({"rtol": "tight"}, "rtol"),
    ({"max_it": 2.5}, "max_it"),
    ({"solver": "lu"}, "solver"),
    ({"bc": "KUBC"}, "bc"),
    ({"a_star_cap": "0.5"}, "a_star_cap"),
    ({"progress": "no"}, "progress"),
    ({"vtu_dir": 3}, "vtu_dir"),
    ({"material_source": 3}, "material_source"),
    ({"comm": "world"}, "comm"),
])
def test_homogenize_names_the_bad_argument(bed, kwargs, name):
    with pytest.raises(AmfeError, match=name):
        amfe.homogenize(bed, **kwargs)


@pytest.mark.parametrize("kwargs,name", [
    ({"petsc_args": "-ksp_max_it 1"}, "petsc_args"),
    ({"petsc_args": ["-ksp_max_it", 1]}, "petsc_args"),
    ({"ksp_options": [1, 2]}, "ksp_options"),
    ({"ksp_options": "-ksp_monitor"}, "ksp_options"),
    ({"accept_unconverged": "no"}, "accept_unconverged"),
    ({"max_memory": "lots"}, "max_memory"),
    ({"nondimensional": None}, "nondimensional"),
    ({"material": {"E": 1e9}}, "material"),
])
def test_solve_options_name_the_bad_field(kwargs, name):
    with pytest.raises(AmfeError, match=name):
        SolveOptions(**kwargs)


def test_solve_options_are_frozen_and_normalised():
    o = SolveOptions(max_memory="1G", petsc_args=["-ksp_monitor"], max_it=np.int64(5),
                     accept_unconverged=np.bool_(True))
    assert o.max_memory == 2.0**30 and o.petsc_args == ("-ksp_monitor",)
    assert o.max_it == 5 and type(o.max_it) is int and o.accept_unconverged is True
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.rtol = 1e-3
    with pytest.raises(AmfeError, match="rtol"):   # replace checks again
        dataclasses.replace(o, rtol=2.0)


@pytest.mark.parametrize("attrs", [[1, 2], "steel", {1: 2}])
def test_bed_attrs_must_be_a_dict(attrs):
    x, r = cubic_lattice(2)
    with pytest.raises(AmfeError, match="attrs"):
        Bed(x, r, attrs=attrs)


def test_homogenize_bed_takes_a_bed_and_options_and_returns_a_result(bed):
    from amfe.solvers.driver import homogenize_bed

    result = homogenize_bed(bed, SolveOptions(solver="gamg", rtol=1e-10))
    api = amfe.homogenize(bed, solver="gamg", rtol=1e-10)
    assert isinstance(result, amfe.Result)
    assert result.C.tolist() == api.C.tolist()   # the API adds nothing to the numbers
    with pytest.raises(AmfeError, match="bed must be an amfe.Bed"):
        homogenize_bed((bed.centers, bed.radii), SolveOptions())
    with pytest.raises(AmfeError, match="SolveOptions"):
        homogenize_bed(bed, {"rtol": 1e-5})


@pytest.mark.parametrize("kwargs,name", [
    ({"max_memory": "lots"}, "max_memory"),
    ({"periodic": "yes"}, "periodic"),
    ({"periodic": True, "offset": "x"}, "offset"),
    ({"periodic": True, "offset": [0.0, 1e-6]}, "offset"),
    ({"seed": 1.5}, "seed"),
    ({"jitter": "a lot"}, "jitter"),
])
def test_generate_bed_names_the_bad_argument(kwargs, name):
    with pytest.raises(AmfeError, match=name):
        amfe.generate_bed(size=(0.1e-3, 0.1e-3, 0.06e-3), **kwargs)
