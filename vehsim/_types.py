"""jaxtyping aliases used across vehsim."""

from typing import Union

import numpy as np
from jaxtyping import Array, ArrayLike, Float


Scalar = Float[Array, ""]
ScalarLike = Union[float, int, Float[ArrayLike, ""]]
RealLike = Union[float, int, np.ndarray, Array]

__all__ = ["Array", "ArrayLike", "Float", "RealLike", "Scalar", "ScalarLike"]
