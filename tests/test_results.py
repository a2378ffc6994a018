"""`vehsim.RESULTS`, the one result enumeration: the names of its cases, read from the
enumerations (lineax's, optimistix's, diffrax's and ours), and the records result files
carry."""

import diffrax as dfx
import equinox as eqx
import lineax as lx
import optimistix as optx
import pytest

from vehsim import RESULTS, is_successful, result_name, result_record
from vehsim._results import result_names, result_of_record


def test_case_names_are_read_from_the_enumerations():
    names = result_names()
    for parent in (lx.RESULTS, optx.RESULTS, dfx.RESULTS):
        assert set(result_names(parent)) <= set(names)
    assert names[-6:] == ("ip_max_iterations", "ip_locally_infeasible", "ip_line_search_failed",
                          "ip_newton_system_failed", "not_identifiable", "step_size_collapsed")
    assert len(set(names)) == len(names) == len(RESULTS)
    for name in names:
        assert result_name(getattr(RESULTS, name)) == name
    # a case that a parent enumeration gains (a newer release) appears in its children's
    # names without being spelled out anywhere else
    class Parent(eqx.Enumeration):
        successful = ""
        new_case = "a case of a newer release"

    class Child(Parent):
        own = "ours"

    assert result_names(Child) == ("successful", "new_case", "own")

    class Extended(RESULTS):
        extra = "an extension's case"

    assert result_names(Extended) == names + ("extra",)


def test_result_records_name_the_case_and_read_back():
    for name in result_names():
        item = getattr(RESULTS, name)
        record = result_record(item)
        assert record["status"] == name and isinstance(record["message"], str)
        assert bool(result_of_record(record) == item)
    assert result_record(optx.RESULTS.nonfinite) == result_record(RESULTS.nonfinite)  # promoted
    assert bool(is_successful(result_of_record({"status": "successful"})))
    with pytest.raises(ValueError, match="no_such_case"):
        result_of_record({"status": "no_such_case", "message": ""})
