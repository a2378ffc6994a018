r"""`AbstractSolution`: what every simulation in vehsim returns.

A simulation saves the model's named signals at times `ts`; its `result` (a
`vehsim.RESULTS` item) says whether the solve worked and its `stats` how many steps it
took. `Trajectory` (`simulate`), `TireSolution` (`simulate_tire`, the moment closures),
`QuarterCarSolution` (`simulate_quarter_car`), `BrakingRun` (`simulate_braking`) and
`TurnRun` (`simulate_turn`) are its final subclasses: ``sol["name"]`` is a signal,
``sol.ok`` where the solve succeeded.
"""

# no `from __future__ import annotations`: equinox reads `AbstractVar` annotations as types

import equinox as eqx
from equinox import AbstractVar
from jaxtyping import Array, Bool, Float

from ._results import RESULTS, is_successful


class AbstractSolution(eqx.Module):
    """The result of a simulation.

    - `ts`: the save times [s] (`None` where nothing was saved).
    - `signals`: the model's named signals over `ts` (a dict of arrays; ``sol[name]``).
    - `result`: a `vehsim.RESULTS` item (batched where the simulation was).
    - `stats`: step counts, at least ``num_steps`` (the integration steps taken).
    """

    ts: AbstractVar[Float[Array, " T"] | None]
    signals: AbstractVar[dict | None]
    result: AbstractVar[RESULTS]
    stats: AbstractVar[dict]

    def __getitem__(self, name: str) -> Array:
        if self.signals is None:
            raise KeyError(f"{type(self).__name__} saved no signals (asked for {name!r})")
        return self.signals[name]

    @property
    def ok(self) -> Bool[Array, "..."]:
        """True where the simulation succeeded."""
        return is_successful(self.result)

    @property
    def num_steps(self) -> Array:
        """The integration steps taken (``stats["num_steps"]``)."""
        return self.stats["num_steps"]
