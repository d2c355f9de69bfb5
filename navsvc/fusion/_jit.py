"""The one compiled-kernel helper of the fusion package: ``jit`` and the array type.

Both filters step at 100-200 Hz per vehicle on 8x8 to 21x21 matrices, where NumPy's per-call
overhead costs more than the arithmetic: their kernels are compiled with numba (cached on
disk, no fast-math so that results are reproducible). ``NUMBA_DISABLE_JIT=1`` runs every
kernel as the readable Python it is written in.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

jit = numba.njit(cache=True, fastmath=False, nogil=True)
