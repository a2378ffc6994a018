"""How a command ends: exit status 0 where its solves succeeded, else 1, with each failing
`vehsim.RESULTS` case and its message on stderr (the result files name the same case)."""

from __future__ import annotations

import sys


def exit_status(command: str, result, message: str | None = None,
                options: dict[str, str] | None = None) -> int:
    """0 where every member of `result` (a `vehsim.RESULTS` item, batched or not) is
    successful; else 1, after one line on stderr per failing case: the case's name, how many
    members it stopped (for a batch), and its message (`message` in place of it, for one
    result), with the library's settings it names replaced by the command's options
    (`options`, e.g. ``{"`IPOptions.max_iter`": "--max-iter"}``)."""
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
        text = as_options(text, options)
        print(f"vehsim {command}: {name}{count}: {text}", file=sys.stderr)
    return 1


def as_options(text: str, options: dict[str, str] | None) -> str:
    """`text` with each library setting it names (a key of `options`) replaced by the
    command's option for it (its value)."""
    for setting, option in (options or {}).items():
        text = text.replace(setting, option)
    return text


def unconverged_note(record: dict) -> str:
    """For the status line of a solve recorded by `solution_record`: nothing if it
    succeeded, else its final residuals and that the figures are the last iterate's."""
    if record["status"] == "successful":
        return ""
    r = record["residuals"]
    return (f"; NOT CONVERGED: final residuals inf_pr {r['inf_pr']:.2e}, inf_du "
            f"{r['inf_du']:.2e}, compl {r['compl']:.2e}, and the figures are those of the last "
            "iterate, not of a solution")


def waiting_line(cache_dir, what: str, program_prefix: str, first_time: str) -> str:
    """What a command says before its first compiled call: compiling `what` (`first_time`
    the first time, cached in `cache_dir` for the next run) when no program named
    `program_prefix`* is in the cache yet, else loading it from there; compiling afresh when
    the cache is off (`cache_dir` None)."""
    from pathlib import Path

    if cache_dir is None:
        return f"compiling {what} ({first_time}; the compilation cache is off)"
    folder = Path(cache_dir)
    if folder.is_dir() and any(folder.glob(f"{program_prefix}*")):
        return (f"loading the compiled {what} from the cache in {folder} (a size not run "
                f"before compiles anew)")
    return (f"compiling {what} ({first_time}, this once: the next run loads it from the cache "
            f"in {folder})")
