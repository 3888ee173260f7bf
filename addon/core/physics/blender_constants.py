"""float32 constants, lane-parameter columns and result codes of the Blender cloth kernels
(``blender_kernels.py``, ``blender_springs.py``).
"""

from __future__ import annotations

import numpy as np

F32 = np.float32
ZERO = F32(0.0)
ONE = F32(1.0)
HALF = F32(0.5)
TENTH = F32(0.1)
TWENTY = F32(20.0)
FLT_EPS = F32(1.1920928955078125e-07)  # FLT_EPSILON, also Blender's ALMOST_ZERO
NORM_EPS = F32(1.0e-35)  # normalize_v3's threshold
CG_EPS = F32(0.01)
SNAP = F32(0.999)  # SOFTGOALSNAP
C4 = (F32(-11.541), F32(34.193), F32(-39.083), F32(23.116), F32(-9.713))  # Choi & Ko's fb
D3 = (F32(-46.164), F32(102.579), F32(-78.166), F32(23.116))  # and its derivative
CG_MAX = 100

# lane parameters (columns of the float32 parameter table)
P_MASS, P_DRAG, P_KT, P_KC, P_KS, P_DT, P_DC, P_DS, P_BEND, P_BDAMP, P_KGOAL, P_KB, P_CB, P_AVG = range(14)
N_LANE_PARAMS = 14
# codes
OK, NONFINITE, FLEW, STRETCHED = 0, 1, 2, 3
REASONS = ["", "non-finite state", "flew away", "spring overstretched"]
KIND_STRUCT, KIND_SHEAR, KIND_BEND = 0, 1, 2
