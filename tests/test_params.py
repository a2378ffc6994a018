"""The preset registry: every named preset found through `vehsim.preset`, its kind, its page."""

import re
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
import pytest

import vehsim as vs


ROOT = Path(__file__).parent.parent

KIND_TYPES = {
    "tire_params": (vs.LuGreParams, vs.LuGre2DParams, vs.MagicFormula1987Params, tuple),
    "tire": (vs.FrictionEllipseTire, vs.IsotropicLumpedLuGre),
    "vehicle_params": (vs.HalfCarParams,),
    "surface": (vs.Surface,),
    "brake_hardware": (vs.BrakeHardware,),
    "robot_plant": (vs.KheperaPlant,),
    "robot_mission": (vs.Mission,),
}


def _same(a, b) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(x, y) for x, y in zip(la, lb))


def test_every_preset_has_a_kind_and_builds_what_its_kind_says():
    assert set(vs.PRESETS) == set(vs.PRESET_KINDS)
    for name, kind in vs.PRESET_KINDS.items():
        assert isinstance(vs.preset(name), KIND_TYPES[kind]), (name, kind)


@pytest.mark.parametrize("name, direct", [
    ("table3", vs.params.table3), ("rally_gravel", vs.rally_gravel),
    ("rally_gravel_tire", vs.rally_gravel_tire), ("matched_lugre_tire", vs.matched_lugre_tire),
    ("realistic_hardware", vs.realistic_hardware), ("ideal_hardware", vs.ideal_hardware),
    ("realistic_plant", vs.realistic_plant), ("ideal_plant", vs.ideal_plant),
])
def test_a_preset_is_what_its_own_function_builds(name, direct):
    assert _same(vs.preset(name), direct())


def test_the_presets_defined_beside_their_models_are_all_registered():
    for name in vs.SURFACES:
        assert vs.PRESET_KINDS[name] == "surface"
        assert _same(vs.preset(name).params, vs.surface(name).params)
    missions = [vs.preset(n) for n, k in vs.PRESET_KINDS.items() if k == "robot_mission"]
    assert missions == list(vs.ROBOT_MISSIONS)
    assert vs.preset("mission_long_distance") is vs.ROBOT_MISSIONS[3]
    # built fresh: a changed copy leaves the registry's next one as it was
    changed = eqx.tree_at(lambda p: p.sigma0, vs.preset("table3"), 1.0)
    assert float(changed.sigma0) == 1.0 and float(vs.preset("table3").sigma0) == 181.54


def test_docs_parameters_lists_every_preset():
    text = (ROOT / "docs" / "parameters.md").read_text()
    table = text.split("| name | kind", 1)[1].split("\n\n", 1)[0]
    rows = [line.split("|")[1:3] for line in table.splitlines()[2:]]
    listed = {name: kind.strip().strip("`") for names, kind in rows
              for name in re.findall(r"`([\w.]+)`", names.split("(")[0])}
    assert listed == vs.PRESET_KINDS


def test_unknown_preset_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown preset 'dry'.*dry_asphalt"):
        vs.preset("dry")
