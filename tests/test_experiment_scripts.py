"""Every script under experiments/ answers ``--help`` without running: it imports (every
name it takes from vehsim still exists) and builds its command line. The scripts are the
benchmarks' and the docs' measurements; nothing else in the suite imports most of them."""

import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for p in (ROOT / "experiments").rglob("*.py")
                 if not p.name.startswith("_"))

# each script as `python SCRIPT --help` runs it (its folder first on the path), one after
# another in one process; per script: its exit code and whether it printed a usage line
RUNNER = """
import contextlib, io, runpy, sys
for path in sys.argv[1:]:
    sys.argv = [path, "--help"]
    sys.path.insert(0, path.rsplit("/", 1)[0])
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_path(path, run_name="__main__")
        code = "ran without exiting"
    except SystemExit as exit:
        code = exit.code
    except BaseException as err:
        code = repr(err)
    sys.path.pop(0)
    print(path, code, out.getvalue().startswith("usage:"), sep="\\t", flush=True)
"""


def test_every_experiment_script_answers_help_without_running():
    assert len(SCRIPTS) >= 20  # the scripts are found
    run = subprocess.run([sys.executable, "-c", RUNNER, *map(str, SCRIPTS)], cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    rows = [line.split("\t") for line in run.stdout.splitlines() if line.count("\t") == 2]
    assert [Path(r[0]) for r in rows] == SCRIPTS, run.stderr[-3000:]
    bad = [(Path(path).relative_to(ROOT), code, usage) for path, code, usage in rows
           if (code, usage) != ("0", "True")]
    assert not bad, bad
