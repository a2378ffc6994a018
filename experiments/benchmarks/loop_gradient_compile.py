r"""Benchmark: what it costs to build the closed braking loop's programs, plain, forward mode
and reverse mode (docs/differentiating.md).

The example of docs/differentiating.md: the stopping distance of a braking from 30 m/s on dry
asphalt (540 samples of 5 ms; `--speed`, `--samples`), `realistic_hardware(encoder=False)`,
`PeakSlipTracking`, the `FrictionObserver`, hand-back at 0.5 m/s, as a function of
$\log K_p$; three programs: the plain run, ``jax.jvp`` (forward mode) and
``jax.value_and_grad`` (reverse mode). For each: the size of its lowered HLO text, the time
to trace and lower it, to compile it (wall, and CPU seconds of this process: XLA compiles in
it, on several threads), to run it once, and its values. XLA's backend optimisation level is
the test suite's (0) unless ``--xla-default`` is given.

Prints one JSON line.
Usage: PYTHONPATH=. python experiments/benchmarks/loop_gradient_compile.py [--programs plain jvp grad]
[--speed 30] [--samples 540] [--estimator observer|none] [--xla-default]  (tests/test_control_gradients.py's braking:
--speed 3 --samples 80)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def _pass_through(belief):
    import equinox as eqx
    import jax.numpy as jnp

    from vehsim.control.estimation.base import AbstractFrictionEstimator

    class State(eqx.Module):
        v: jnp.ndarray

    class PassThrough(AbstractFrictionEstimator):
        """No estimate: the belief fixed, the measured speed as the filtered one."""

        fixed: object

        def init(self, omega0, v0):
            return State(jnp.asarray(v0, dtype=float))

        def update(self, state, car, hardware, substeps, v, omega, stamp, fresh, torque0,
                   target, t0):
            return State(v)

        def belief(self, state):
            return self.fixed

        def signals(self, state):
            return {}

    return PassThrough(belief)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--programs", nargs="+", default=["plain", "jvp", "grad"],
                    choices=["plain", "jvp", "grad"])
    ap.add_argument("--speed", type=float, default=30.0, help="initial speed [m/s]")
    ap.add_argument("--samples", type=int, default=540,
                    help="samples of 5 ms (the scan's length: the programs are the same)")
    ap.add_argument("--estimator", choices=["observer", "none"], default="observer",
                    help="none: a stand-in that passes the measured speed through (the "
                         "plant's and the controller's share of the cost)")
    ap.add_argument("--xla-default", action="store_true",
                    help="keep XLA's default backend optimisation level")
    args = ap.parse_args(argv)
    if not args.xla_default:
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_backend_optimization_level=0".strip()

    import equinox as eqx
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import vehsim as vs

    scenario, observer = vs.braking_scenario("dry_asphalt", args.speed)
    if args.estimator == "none":
        observer = _pass_through(observer.belief(observer.init(1.0, args.speed)))
    hardware = vs.realistic_hardware(encoder=False)
    n_steps = args.samples

    def distance(log_kp, hardware):
        controller = vs.PeakSlipTracking(kp=jnp.exp(log_kp))
        return vs.closed_loop(scenario, controller, observer, hardware, jax.random.PRNGKey(0),
                              n_steps, save=False, handback_speed=0.5).stopping_distance

    programs = {"plain": distance,
                "jvp": lambda g, h: jax.jvp(lambda x: distance(x, h), (g,), (jnp.ones(()),)),
                "grad": jax.value_and_grad(distance)}
    g = jnp.log(60.0)
    out = {"benchmark": "loop_gradient_compile", "speed": args.speed, "samples": n_steps,
           "estimator": args.estimator,
           "xla_backend_optimization_level": "default" if args.xla_default else 0}
    for name in args.programs:
        w0 = time.perf_counter()
        lowered = eqx.filter_jit(programs[name]).lower(g, hardware)
        chars = len(lowered.as_text())
        w1, c1 = time.perf_counter(), time.process_time()
        compiled = lowered.compile()
        w2, c2 = time.perf_counter(), time.process_time()
        values = jax.block_until_ready(compiled(g, hardware))
        w3 = time.perf_counter()
        out[name] = {"hlo_chars": chars, "trace_lower_s": round(w1 - w0, 1),
                     "compile_wall_s": round(w2 - w1, 1), "compile_cpu_s": round(c2 - c1, 1),
                     "run_s": round(w3 - w2, 2),
                     "values": [float(v) for v in jax.tree_util.tree_leaves(values)]}
        print(f"  {name}: {out[name]}", file=sys.stderr, flush=True)
    out |= {"load_average_1min": round(os.getloadavg()[0], 2), "cpu_count": os.cpu_count(),
            "jax": jax.__version__, "device": str(jax.devices()[0])}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
