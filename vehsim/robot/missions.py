r"""The four missions of report Table 2 and their Monte-Carlo perturbations.

A mission is an initial pose $(x, y, \gamma)$ [m, m, rad] to be driven to the origin with
heading 0. The report names the missions but not their poses; these are chosen to match
the names on a 55 mm robot (documented in each preset):

- **Easy**: goal 15 cm ahead, 3 cm to the side, heading 0.
- **Normal**: a generic parking pose, 10 cm past the goal and 15 cm to the side, facing
  away at -60 deg.
- **Singular**: a pure side-step of 10 cm, $(0, 0.10, 0)$, which lies on the singular set
  $x_1 = x_2 = 0$ of the discontinuous laws in both systems ($x_3 \ne 0$).
- **Long-distance**: 60 cm behind and 40 cm to the side, heading 0.

Monte-Carlo runs perturb the pose by Gaussian noise of standard deviation `spread`
(Singular only along $y$, so every run stays on the singular set); seed 0 is the nominal pose.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._checks import check_finite, check_nonnegative
from .._fields import host_array_field


def check_poses(owner: str, name: str, poses, shape, *, sep: str = ": ") -> None:
    """Refuse poses that are not finite (x, y, gamma) rows of `shape` (-1: any length)."""
    got = jnp.shape(poses)
    if len(got) != len(shape) or any(s not in (-1, g) for s, g in zip(shape, got)):
        want = "(3,)" if len(shape) == 1 else "(P, 3)"
        raise ValueError(f"{owner}{sep}{name} must have shape {want}, (x [m], y [m], gamma "
                         f"[rad]), got {got}")
    check_finite(owner, name, poses)


class Mission(eqx.Module):
    """An initial pose `pose0` [m, m, rad] and its Monte-Carlo `spread` (std per component)."""

    name: str = eqx.field(static=True)
    pose0: Float[Array, 3] = host_array_field()  # presets are built at import
    spread: Float[Array, 3] = host_array_field()

    def __check_init__(self):
        for name in ("pose0", "spread"):
            check_poses("Mission", name, getattr(self, name), (3,), sep=".")
        check_nonnegative("Mission", "spread", self.spread)

    def initial_poses(self, key: PRNGKeyArray, n: int) -> Float[Array, "n 3"]:
        """`n` initial poses: the nominal one, then `n - 1` perturbed ones."""
        noise = jax.random.normal(key, (n, 3)) * self.spread
        noise = noise.at[0].set(0.0)
        return self.pose0 + noise


_SPREAD = (0.005, 0.005, 0.035)

EASY = Mission("Easy", (-0.15, 0.03, 0.0), _SPREAD)
NORMAL = Mission("Normal", (0.10, 0.15, -jnp.pi / 3), _SPREAD)
SINGULAR = Mission("Singular", (0.0, 0.10, 0.0), (0.0, 0.005, 0.0))
LONG_DISTANCE = Mission("Long-distance", (-0.60, 0.40, 0.0), _SPREAD)

ROBOT_MISSIONS: tuple[Mission, ...] = (EASY, NORMAL, SINGULAR, LONG_DISTANCE)
"""The missions of Table 2, in its column order (E, N, S, L)."""
