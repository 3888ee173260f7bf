"""Optional numba kernels (placeholder until implemented)."""


def available():
    return False
