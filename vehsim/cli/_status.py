"""How a command ends: exit status 0 where its solves succeeded, else 1, with each failing
`vehsim.RESULTS` case and its message on stderr (the result files name the same case)."""

from __future__ import annotations

import sys


def exit_status(command: str, result, message: str | None = None) -> int:
    """0 where every member of `result` (a `vehsim.RESULTS` item, batched or not) is
    successful; else 1, after one line on stderr per failing case: the case's name, how many
    members it stopped (for a batch), and its message (`message` in place of it, for one
    result)."""
    import numpy as np

    from .._results import is_successful, result_message_of_name, result_name

    ok = np.asarray(is_successful(result))
    if ok.all():
        return 0
    names = np.asarray(result_name(result), dtype=object)
    failed = names[~ok]
    for name in dict.fromkeys(failed.tolist()):
        count = "" if ok.ndim == 0 else f" ({int(np.sum(failed == name))} of {ok.size})"
        text = message if message is not None and ok.ndim == 0 else result_message_of_name(name)
        print(f"vehsim {command}: {name}{count}: {text}", file=sys.stderr)
    return 1
