"""jaxtyping aliases used across vehsim."""

import numpy as np
from jaxtyping import Array, ArrayLike, Float


Scalar = Float[Array, ""]
ScalarLike = float | int | Float[ArrayLike, ""]
RealLike = float | int | np.ndarray | Array

__all__ = ["Array", "ArrayLike", "Float", "RealLike", "Scalar", "ScalarLike"]
